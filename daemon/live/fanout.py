""":class:`LiveFanOut`: the session log and the live view behind one ``SessionLogger``.

The daemon's parts (engine, CAN and Modbus endpoints, service) log through one
:class:`~cmm_comp.daemon.sessionlog.SessionLogger`. With the live view on, the service wraps its
MCAP logger (or nothing, when ``mcap.path`` is empty) and the :class:`.sink.LiveSink` in a
fan-out, so every record batch reaches both with one log time and no part changes. The MCAP
logger is called first and keeps its contract (return values, ``KeyError`` for an unknown
topic, statistics, health); the live view's own counters are :meth:`LiveSink.counters`.
"""

from __future__ import annotations

import time
from collections.abc import Sequence
from pathlib import Path

from ..sessionlog.logger import LogConsumer, LoggerStats, Payload, SessionLogger
from .sink import LiveSink

_EMPTY = LoggerStats(0, 0, 0, 0, (), 0)


class LiveFanOut(LogConsumer):
    """A :class:`SessionLogger` that hands every message to ``primary`` (the MCAP logger, or
    None) and to ``live``. ``stop`` stops both (the MCAP file first)."""

    def __init__(self, primary: SessionLogger | None, live: LiveSink) -> None:
        self.primary = primary
        self.live = live

    def log_many(
        self, topic: str, payloads: Sequence[Payload], log_time_ns: int | None = None
    ) -> int:
        """``primary.log_many`` (its result), then the live view, with one log time (ns)."""
        if log_time_ns is None:
            log_time_ns = time.time_ns()
        taken = (
            self.primary.log_many(topic, payloads, log_time_ns)
            if self.primary is not None
            else len(payloads)
        )
        self.live.log_many(topic, payloads, log_time_ns)
        return taken

    def kick(self) -> None:
        """Let both writers work now."""
        if self.primary is not None:
            self.primary.kick()
        self.live.kick()

    def stats(self) -> LoggerStats:
        """The MCAP logger's statistics (zeros without one)."""
        return self.primary.stats() if self.primary is not None else _EMPTY

    @property
    def error(self) -> BaseException | None:
        """The MCAP logger's first error (the live view's are reported to its ``on_error``)."""
        return self.primary.error if self.primary is not None else None

    @property
    def healthy(self) -> bool:
        """The MCAP logger's health (True without one)."""
        return self.primary.healthy if self.primary is not None else True

    @property
    def files(self) -> tuple[Path, ...]:
        """The MCAP files written so far."""
        return self.primary.files if self.primary is not None else ()

    def stop(self, timeout_s: float = 5.0) -> bool:
        """Finish the MCAP file, then stop the live view; True if both did within
        ``timeout_s`` (s) in total (the live view gets at least 0.5 s)."""
        deadline = time.monotonic() + timeout_s
        ok = self.primary.stop(timeout_s) if self.primary is not None else True
        ok &= self.live.stop(max(0.5, deadline - time.monotonic()))
        return ok
