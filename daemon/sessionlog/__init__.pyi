"""Public API of ``sessionlog`` (read by lazy_loader: names load on first use)."""

from .encoding import ERROR_TOPIC
from .logger import LOW_PRIORITY_TOPICS, LoggerStats, LogSettings, SessionLogger
from .mcapfile import McapFileWriter
from .process_writer import McapProcessLogger, McapWriterProcessError
from .schemas import (
    RECORD_FIELDS,
    TOPIC_SCHEMAS,
    TOPIC_TYPES,
    TopicSchema,
    check_message,
    ns_from_can_timestamp,
    ns_from_stamp,
    stamp_from_ns,
)
from .writer import SessionWriter

__all__ = [
    "ERROR_TOPIC",
    "LOW_PRIORITY_TOPICS",
    "RECORD_FIELDS",
    "TOPIC_SCHEMAS",
    "TOPIC_TYPES",
    "LogSettings",
    "LoggerStats",
    "McapFileWriter",
    "McapProcessLogger",
    "McapWriterProcessError",
    "SessionLogger",
    "SessionWriter",
    "TopicSchema",
    "check_message",
    "ns_from_can_timestamp",
    "ns_from_stamp",
    "stamp_from_ns",
]
