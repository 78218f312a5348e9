"""Public API of ``sessionlog`` (read by lazy_loader: names load on first use)."""

from .encoding import ERROR_TOPIC
from .logger import LOW_PRIORITY_TOPICS, LoggerStats, LogSettings, SessionLogger
from .mcapfile import McapFileWriter
from .process_writer import McapProcessLogger, McapWriterProcessError
from .writer import SessionWriter

__all__ = [
    "ERROR_TOPIC",
    "LOW_PRIORITY_TOPICS",
    "LogSettings",
    "LoggerStats",
    "McapFileWriter",
    "McapProcessLogger",
    "McapWriterProcessError",
    "SessionLogger",
    "SessionWriter",
]
