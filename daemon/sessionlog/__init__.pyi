"""Public API of ``sessionlog`` (read by lazy_loader: names load on first use)."""

from .encoding import ERROR_TOPIC
from .logger import LOW_PRIORITY_TOPICS, LoggerStats, LogSettings, SessionLogger
from .mcapfile import McapFileWriter
from .process_writer import McapProcessLogger, McapWriterProcessError
from .reader import LoggedMessage, Session, load_session, read_messages, session_files
from .recover import RecoverReport, recover
from .replay import BusReplayReport, ReplayError, ReplayReport, replay_offline, replay_to_bus
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
    "BusReplayReport",
    "LogSettings",
    "LoggedMessage",
    "LoggerStats",
    "McapFileWriter",
    "McapProcessLogger",
    "McapWriterProcessError",
    "RecoverReport",
    "ReplayError",
    "ReplayReport",
    "Session",
    "SessionLogger",
    "SessionWriter",
    "TopicSchema",
    "check_message",
    "load_session",
    "ns_from_can_timestamp",
    "ns_from_stamp",
    "read_messages",
    "recover",
    "replay_offline",
    "replay_to_bus",
    "session_files",
    "stamp_from_ns",
]
