"""Public API of ``daemon`` (read by lazy_loader: names load on first use)."""

from .config import ConfigError, DaemonConfig
from .engine import Answer, CorrectionEngine, Reading
from .grid_slot import GridLoadError, GridReloader, GridSlot, load_grid
from .grid_trust import GridTrust, GridTrustError
from .init_dir import InitError, InitReport, init_daemon_dir
from .metrics import LatencyHistogram, Metrics
from .preflight import Preflight, preflight
from .service import DaemonService
from .sessionlog import (
    TOPIC_SCHEMAS,
    LoggerStats,
    McapProcessLogger,
    ReplayError,
    ReplayReport,
    Session,
    SessionLogger,
    SessionWriter,
    load_session,
    ns_from_can_timestamp,
    ns_from_stamp,
    read_messages,
    replay_offline,
    replay_to_bus,
    stamp_from_ns,
)

__all__ = [
    "TOPIC_SCHEMAS",
    "Answer",
    "ConfigError",
    "CorrectionEngine",
    "DaemonConfig",
    "DaemonService",
    "GridLoadError",
    "GridReloader",
    "GridSlot",
    "GridTrust",
    "GridTrustError",
    "InitError",
    "InitReport",
    "LatencyHistogram",
    "LoggerStats",
    "McapProcessLogger",
    "Metrics",
    "Preflight",
    "Reading",
    "ReplayError",
    "ReplayReport",
    "Session",
    "SessionLogger",
    "SessionWriter",
    "init_daemon_dir",
    "load_grid",
    "load_session",
    "ns_from_can_timestamp",
    "ns_from_stamp",
    "preflight",
    "read_messages",
    "replay_offline",
    "replay_to_bus",
    "stamp_from_ns",
]
