"""Public API of ``sessionlog`` (read by lazy_loader: names load on first use)."""

from .encoding import ERROR_TOPIC
from .logger import LOW_PRIORITY_TOPICS, LoggerStats, LogSettings, SessionLogger
from .mcapfile import McapFileWriter
from .process_writer import McapProcessLogger, McapWriterProcessError
from .reader import LoggedMessage, Session, load_session, read_messages, session_files
from .records import CorrectedRecord, FrameRecord, RawRecord
from .recover import RecoverReport, recover
from .replay import BusReplayReport, ReplayError, ReplayReport, replay_offline, replay_to_bus
from .schemas import (
    TOPIC_SCHEMAS,
    TopicSchema,
    check_message,
    ns_from_can_timestamp,
    ns_from_stamp,
    stamp_from_ns,
)
from .thread_writer import McapLogger

__all__ = [
    "ERROR_TOPIC",
    "LOW_PRIORITY_TOPICS",
    "TOPIC_SCHEMAS",
    "BusReplayReport",
    "CorrectedRecord",
    "FrameRecord",
    "LogSettings",
    "LoggedMessage",
    "LoggerStats",
    "McapFileWriter",
    "McapLogger",
    "McapProcessLogger",
    "McapWriterProcessError",
    "RawRecord",
    "RecoverReport",
    "ReplayError",
    "ReplayReport",
    "Session",
    "SessionLogger",
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
