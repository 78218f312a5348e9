"""What the session log's writers share: the :class:`SessionLogger` protocol the daemon types
against, the :class:`LogSettings` of a log (one definition, validated once), the
:class:`LoggerStats` snapshot, and :class:`LoggerBase`: the topic checks, the drop counts per
topic, the error reporting and the lifecycle.

:class:`~cmm_comp.daemon.sessionlog.process_writer.McapProcessLogger` is the daemon's log (the
writing in a child process); :class:`~cmm_comp.daemon.sessionlog.writer.SessionWriter` writes
the files in the calling thread (in that child, or in any program that may wait for its disk).
"""

from __future__ import annotations

import logging
import os
import threading
from collections.abc import Callable, Iterable, Mapping, Sequence
from dataclasses import dataclass, field, fields
from pathlib import Path
from typing import Any, Protocol, Self, TypedDict, cast

from mcap.writer import CompressionType

from cmm_comp.protocol.session_topics import RECORD_FIELDS, TOPIC_SCHEMAS

_log = logging.getLogger(__name__)

Payload = dict[str, Any] | tuple[Any, ...]
"""A logged payload: the JSON object, or a compact record tuple (``session_topics.RECORD_FIELDS``)."""


LOW_PRIORITY_TOPICS: frozenset[str] = frozenset({"/cmm/can_rx", "/cmm/can_tx", "/cmm/modbus"})
"""Topics dropped first under overload: once the queue is half full only the other topics
(answers, readings, temperatures, status, grid, counters, error records) are still taken."""


def topic_counter_name(prefix: str, topic: str) -> str:
    """Counter name of a per-topic count: ``mcap_dropped`` + ``/cmm/can_rx`` →
    ``mcap_dropped_can_rx``."""
    return f"{prefix}_{topic.removeprefix('/cmm/').strip('/').replace('/', '_')}"


@dataclass(frozen=True)
class LoggerStats:
    """Counters since start. ``dropped`` counts messages that did not reach their topic for any
    reason (queue full, logged after stop, writer failed, could not be encoded);
    ``encode_errors`` those that could not be encoded (each written as an error record
    instead). ``*_by_topic`` split them per topic (exact: they sum to the totals).
    ``flushed``: messages written before the last flush to the OS (what a crash keeps)."""

    enqueued: int
    written: int
    dropped: int
    encode_errors: int
    files: tuple[Path, ...]
    queue_len: int
    dropped_by_topic: Mapping[str, int] = field(default_factory=dict)
    encode_errors_by_topic: Mapping[str, int] = field(default_factory=dict)
    written_by_topic: Mapping[str, int] = field(default_factory=dict)
    flushed: int = 0

    def counters(self) -> dict[str, int]:
        """The counters the writers add to every ``/cmm/counters`` record (and the daemon may
        publish): ``mcap_written``, ``mcap_dropped``, ``mcap_encode_errors``, and per topic
        ``mcap_dropped_<topic>`` / ``mcap_encode_errors_<topic>`` (``<topic>`` without
        ``/cmm/``, e.g. ``mcap_dropped_corrected``)."""
        out = {
            "mcap_written": self.written,
            "mcap_dropped": self.dropped,
            "mcap_encode_errors": self.encode_errors,
        }
        for topic, n in self.dropped_by_topic.items():
            out[topic_counter_name("mcap_dropped", topic)] = n
        for topic, n in self.encode_errors_by_topic.items():
            out[topic_counter_name("mcap_encode_errors", topic)] = n
        return out


class SessionLogger(Protocol):
    """The session log as the daemon sees it (engine, endpoints, service): log without
    blocking, kick the writer when idle, watch its health, stop it."""

    def log(self, topic: str, payload: Payload, log_time_ns: int | None = None) -> bool:
        """Enqueue one message; never blocks; False when it was dropped."""
        ...

    def log_many(
        self, topic: str, payloads: Sequence[Payload], log_time_ns: int | None = None
    ) -> int:
        """Enqueue several messages of one topic with one log time, as ``log`` each would;
        never blocks; returns how many were taken (the rest are dropped and counted)."""
        ...

    def kick(self) -> None:
        """Let the writer work now (the producer is idle)."""
        ...

    def stats(self) -> LoggerStats:
        """A snapshot of the counters."""
        ...

    @property
    def error(self) -> BaseException | None:
        """The first error the writer met, or None."""
        ...

    @property
    def healthy(self) -> bool:
        """True while the writer runs without error."""
        ...

    @property
    def files(self) -> tuple[Path, ...]:
        """Files written so far, in order."""
        ...

    def stop(self, timeout_s: float = 5.0) -> bool:
        """Drain, finish the file, end the writer; True if done within ``timeout_s`` (s)."""
        ...

    def close(self) -> None:
        """Stop with the default timeout."""
        ...


@dataclass(frozen=True)
class LogSettings:
    """Where and how a session log is written (both writers; validated on construction).

    :param target: a directory (files ``session-YYYYmmddTHHMMSS-NNN.mcap``, UTC session start,
        NNN from 000) or an explicit ``*.mcap`` file path (a single file, no rolling).
    :param roll_bytes: start a new file once the current one reaches this size, bytes
        (checked after each written batch, so a file may exceed it by about one chunk).
    :param roll_s: start a new file once the current one is this old, s.
    :param flush_period_s: cut the chunk in progress and flush at least this often, s.
    :param chunk_size: uncompressed chunk size that also cuts a chunk, bytes.
    :param queue_size: messages the queue holds before ``log`` drops.
    :param compression: chunk compression (zstd by default).
    :param fsync: also ``os.fsync`` on every flush (power-loss safety, costs latency).
    :param metadata: extra key/values for the ``session`` metadata record of every file.
    """

    target: Path
    roll_bytes: int | None = None
    roll_s: float | None = None
    flush_period_s: float = 1.0
    chunk_size: int = 256 * 1024
    queue_size: int = 100_000
    compression: CompressionType = CompressionType.ZSTD
    fsync: bool = False
    metadata: Mapping[str, str] = field(default_factory=dict)

    @classmethod
    def of(cls, target: str | os.PathLike[str], options: LogOptions) -> LogSettings:
        """The checked settings of a log at ``target`` (the writers' keyword arguments)."""
        return cls(Path(target), **options)

    def options(self) -> LogOptions:
        """Every field but the first, ``target``: the writers' keyword arguments."""
        return cast(LogOptions, {f.name: getattr(self, f.name) for f in fields(self)[1:]})

    def __post_init__(self) -> None:
        target = Path(self.target)
        object.__setattr__(self, "target", target)
        object.__setattr__(self, "metadata", dict(self.metadata))
        if self.single and (self.roll_bytes is not None or self.roll_s is not None):
            raise ValueError(f"{target}: rolling needs a directory target, not a .mcap file")
        if self.flush_period_s <= 0:
            raise ValueError(f"flush_period_s={self.flush_period_s!r} must be > 0 s")
        if self.queue_size < 1:
            raise ValueError(f"queue_size={self.queue_size!r} must be >= 1")
        for name, val in (("roll_bytes", self.roll_bytes), ("roll_s", self.roll_s)):
            if val is not None and val <= 0:
                raise ValueError(f"{name}={val!r} must be > 0 or None")

    @property
    def single(self) -> bool:
        """True for one explicit ``*.mcap`` file (no rolling)."""
        return self.target.suffix == ".mcap"


class LogOptions(TypedDict, total=False):
    """The keyword arguments of both writers: the fields of :class:`LogSettings` (documented
    there) but ``target``."""

    roll_bytes: int | None
    roll_s: float | None
    flush_period_s: float
    chunk_size: int
    queue_size: int
    compression: CompressionType
    fsync: bool
    metadata: Mapping[str, str]


class LogConsumer:
    """What every taker of the session log's messages shares (the writers, the live view, their
    fan-out): ``log`` as ``log_many`` of one message, ``close()`` and ``with`` from ``stop``."""

    def log_many(
        self, topic: str, payloads: Sequence[Payload], log_time_ns: int | None = None
    ) -> int:  # pragma: no cover - the classes override
        """Take ``payloads`` of ``topic`` with one log time (integer ns since the Unix epoch;
        now if None); returns how many were taken."""
        raise NotImplementedError

    def log(self, topic: str, payload: Payload, log_time_ns: int | None = None) -> bool:
        """:meth:`log_many` of one message: False when it was dropped (counted).

        :param topic: one of the logged topics (KeyError for the writers otherwise: a
            programming error).
        :param payload: the JSON object, or for the topics of :data:`.session_topics.RECORD_FIELDS`
            a compact record tuple. ``stamp`` is added from ``log_time_ns`` when absent.
        :param log_time_ns: MCAP log time, integer ns since the Unix epoch; now if None.
        """
        return self.log_many(topic, (payload,), log_time_ns) == 1

    def stop(self, timeout_s: float = 5.0) -> bool:  # pragma: no cover - the classes override
        """End the work (drain, finish); True if done within ``timeout_s`` (s)."""
        raise NotImplementedError

    def close(self) -> None:
        """Stop with the default timeout (the SIGTERM path)."""
        self.stop()

    def __enter__(self) -> Self:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


class ReportingConsumer(LogConsumer):
    """A taker that reports its problems (the writers, the live view): the first error kept
    (:attr:`error`), each one logged and passed to ``on_error``, whose own failure is logged,
    never raised into the producer.

    :param what: names the taker in the Python log lines.
    """

    _report_level = logging.ERROR
    """The Python log level of :meth:`_report`."""

    def __init__(self, on_error: Callable[[BaseException], None] | None, what: str) -> None:
        self._on_error = on_error
        self._what = what
        self._error: BaseException | None = None

    @property
    def error(self) -> BaseException | None:
        """The first error met, or None."""
        return self._error

    def _report(self, exc: BaseException) -> None:
        """Keep the first error, log it, pass it to ``on_error``."""
        if self._error is None:
            self._error = exc
        _log.log(self._report_level, "%s: %s", self._what, exc)
        self._tell(exc)

    def _report_quietly(self, exc: BaseException) -> None:
        """Pass a problem that does not stop the work (a message that could not be encoded)
        to ``on_error`` and the Python log, without keeping it as :attr:`error`."""
        _log.warning("%s: %s", self._what, exc)
        self._tell(exc)

    def _tell(self, exc: BaseException) -> None:
        if self._on_error is not None:
            try:
                self._on_error(exc)
            except Exception:  # the handler's own failure is logged, never raised here
                _log.exception("%s: its on_error handler raised", self._what)


class LoggerBase(ReportingConsumer):
    """The part every writer shares: topic checks, drop counts per topic, error reporting
    (:class:`ReportingConsumer`) and the lifecycle."""

    def __init__(
        self, settings: LogSettings, on_error: Callable[[BaseException], None] | None, what: str
    ) -> None:
        super().__init__(on_error, what)
        self._settings = settings
        self._drop_lock = threading.Lock()
        self._dropped = 0
        self._dropped_by: dict[str, int] = {}
        self._enqueued = 0
        self._closed = False

    @staticmethod
    def _check(topic: str, payloads: Iterable[Payload]) -> None:
        """KeyError for a topic that is not logged, or a record tuple on a topic that takes
        dicts: a programming error of the caller."""
        if topic not in TOPIC_SCHEMAS:
            raise KeyError(f"unknown MCAP topic {topic!r}; known: {sorted(TOPIC_SCHEMAS)}")
        if topic not in RECORD_FIELDS and any(type(p) is tuple for p in payloads):
            raise KeyError(f"MCAP topic {topic!r} takes a dict payload, not a record tuple")

    def _count_drop(self, topic: str, n: int = 1) -> None:
        with self._drop_lock:
            self._dropped += n
            self._dropped_by[topic] = self._dropped_by.get(topic, 0) + n

    def _dropped_snapshot(self) -> dict[str, int]:
        with self._drop_lock:
            return dict(self._dropped_by)
