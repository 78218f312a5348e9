"""Public API of ``live`` (read by lazy_loader: names load on first use)."""

from .fanout import LiveFanOut
from .process import LiveChildError, LiveDownError, LiveProcessSink
from .server import SUBPROTOCOL, LiveServer, LiveStartError, open_live_server
from .settings import (
    LiveConfigError,
    LiveSection,
    host_problem,
    live_section_from_table,
)
from .sink import (
    LATCHED_TOPICS,
    SCENE_TOPIC,
    STREAMED_TOPICS,
    LiveSink,
    LiveStats,
)

__all__ = [
    "LATCHED_TOPICS",
    "SCENE_TOPIC",
    "STREAMED_TOPICS",
    "SUBPROTOCOL",
    "LiveChildError",
    "LiveConfigError",
    "LiveDownError",
    "LiveFanOut",
    "LiveProcessSink",
    "LiveSection",
    "LiveServer",
    "LiveSink",
    "LiveStartError",
    "LiveStats",
    "host_problem",
    "live_section_from_table",
    "open_live_server",
]
