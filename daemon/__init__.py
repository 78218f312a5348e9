"""daemon: the compensation daemon that runs beside a CMM controller.

Loads a correction grid, receives raw scale readings over CAN (any python-can interface) or
Modbus TCP together with temperatures, answers corrected coordinates with a status at once, and
logs every message to MCAP off the hot path. ``cmm-comp daemon --config daemon.toml``.
"""

from __future__ import annotations

from .config import ConfigError, DaemonConfig
from .engine import Answer, CorrectionEngine, Reading
from .grid_slot import GridLoadError, GridSlot, load_grid
from .mcap_log import LoggerStats, McapLogger
from .mcap_read import Session, load_session, read_messages
from .mcap_schemas import TOPIC_SCHEMAS, ns_from_can_timestamp, ns_from_stamp, stamp_from_ns
from .metrics import LatencyHistogram, Metrics
from .replay import ReplayError, ReplayReport, replay_offline, replay_to_bus
from .service import DaemonService

__all__ = [
    "TOPIC_SCHEMAS",
    "Answer",
    "ConfigError",
    "CorrectionEngine",
    "DaemonConfig",
    "DaemonService",
    "GridLoadError",
    "GridSlot",
    "LatencyHistogram",
    "LoggerStats",
    "McapLogger",
    "Metrics",
    "Reading",
    "ReplayError",
    "ReplayReport",
    "Session",
    "load_grid",
    "load_session",
    "ns_from_can_timestamp",
    "ns_from_stamp",
    "read_messages",
    "replay_offline",
    "replay_to_bus",
    "stamp_from_ns",
]
