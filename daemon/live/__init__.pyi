"""Public API of ``live`` (read by lazy_loader: names load on first use)."""

from .fanout import LiveFanOut
from .process import LiveChildError, LiveDownError, LiveProcessSink, live_sink
from .server import SUBPROTOCOL, LiveServer, LiveStartError, open_live_server
from .settings import (
    SENDERS,
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
    "SENDERS",
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
    "live_sink",
    "open_live_server",
]
