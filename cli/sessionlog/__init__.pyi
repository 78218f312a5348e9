"""Public API of ``cli.sessionlog`` (read by lazy_loader: names load on first use)."""

from .reader import LoggedMessage, Session, load_session, read_messages, session_files
from .recover import RecoverReport, recover
from .replay import BusReplayReport, ReplayError, ReplayReport, replay_offline, replay_to_bus

__all__ = [
    "BusReplayReport",
    "LoggedMessage",
    "RecoverReport",
    "ReplayError",
    "ReplayReport",
    "Session",
    "load_session",
    "read_messages",
    "recover",
    "replay_offline",
    "replay_to_bus",
    "session_files",
]
