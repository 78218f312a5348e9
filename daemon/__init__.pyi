"""Public API of ``daemon`` (read by lazy_loader: names load on first use)."""

from .config import ConfigError, DaemonConfig
from .engine import Answer, CorrectionEngine, Reading
from .grid_slot import GridLoadError, GridReloader, GridSlot, load_grid
from .grid_trust import GridTrust, GridTrustError
from .metrics import LatencyHistogram, Metrics
from .service import DaemonService
from .sessionlog import (
    LoggerStats,
    McapProcessLogger,
    SessionLogger,
    SessionWriter,
)

__all__ = [
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
    "LatencyHistogram",
    "LoggerStats",
    "McapProcessLogger",
    "Metrics",
    "Reading",
    "SessionLogger",
    "SessionWriter",
    "load_grid",
]
