"""What both session-log writers share: the :class:`SessionLogger` protocol the daemon types
against, the :class:`LogSettings` of a log (one definition, validated once), the
:class:`LoggerStats` snapshot and :class:`HotPathQueue`, the never-blocking front half.

Two writers implement the protocol: :class:`~cmm_comp.daemon.sessionlog.thread_writer.McapLogger`
(a writer thread in the daemon's process) and
:class:`~cmm_comp.daemon.sessionlog.process_writer.McapProcessLogger` (a child process).
"""

from __future__ import annotations

import collections
import logging
import threading
import time
from collections.abc import Callable, Iterable, Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Protocol, Self

from mcap.writer import CompressionType

from .records import RECORD_BUILDERS
from .schemas import TOPIC_SCHEMAS, TopicSchema

_log = logging.getLogger(__name__)

Payload = dict[str, Any] | tuple[Any, ...]
"""A logged payload: the JSON object, or a compact record tuple (see ``records``)."""
QueuedMessage = tuple[str, Payload, int]
"""``(topic, payload, log_time_ns)`` as it waits in a queue."""


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
    :param schemas: topic to schema; defaults to :data:`.schemas.TOPIC_SCHEMAS`.
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
    schemas: Mapping[str, TopicSchema] = field(default_factory=lambda: dict(TOPIC_SCHEMAS))

    def __post_init__(self) -> None:
        target = Path(self.target)
        object.__setattr__(self, "target", target)
        object.__setattr__(self, "metadata", dict(self.metadata))
        object.__setattr__(self, "schemas", dict(self.schemas))
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


class HotPathQueue:
    """The never-blocking front half both writers share: :meth:`log` only appends to a bounded
    deque (or counts a drop); a writer thread (or a forwarder to a child process) drains it.
    Also the shared error reporting (first error kept, ``on_error`` called) and lifecycle."""

    def __init__(
        self,
        settings: LogSettings,
        on_error: Callable[[BaseException], None] | None,
        what: str,
    ) -> None:
        self._settings = settings
        self._schemas: Mapping[str, TopicSchema] = settings.schemas
        self._queue: collections.deque[QueuedMessage] = collections.deque()
        self._queue_size = settings.queue_size
        self._soft_size = max(1, settings.queue_size // 2)  # LOW_PRIORITY_TOPICS stop here
        self._on_error = on_error
        self._what = what
        self._drop_lock = threading.Lock()
        self._dropped = 0
        self._dropped_by: dict[str, int] = {}
        self._enqueued = 0  # approximate under concurrency, exact from one thread
        self._error: BaseException | None = None
        self._closed = False
        self._stopping = threading.Event()
        self._wake = threading.Event()

    def log(self, topic: str, payload: Payload, log_time_ns: int | None = None) -> bool:
        """Enqueue one message; never blocks. Returns False when it was dropped.

        :param topic: one of the configured topics (KeyError otherwise: a programming error).
        :param payload: the JSON object, or for the topics of
            :data:`.records.RECORD_BUILDERS` a compact record tuple that the writer
            turns into that object (cheaper on the hot path). Ownership passes to the logger
            (do not mutate it afterwards). ``stamp`` is added from ``log_time_ns`` when absent.
        :param log_time_ns: MCAP log time, integer ns since the Unix epoch; now if None.
        """
        if topic not in self._schemas:
            raise KeyError(f"unknown MCAP topic {topic!r}; known: {sorted(self._schemas)}")
        if type(payload) is tuple and topic not in RECORD_BUILDERS:
            raise KeyError(f"MCAP topic {topic!r} takes a dict payload, not a record tuple")
        if log_time_ns is None:
            log_time_ns = time.time_ns()
        queue = self._queue
        n = len(queue)
        if (n >= self._soft_size or self._closed) and (  # overload policy (docs/mcap.md)
            self._closed or n >= self._queue_size or topic in LOW_PRIORITY_TOPICS
        ):
            self._count_drop(topic)
            return False
        queue.append((topic, payload, log_time_ns))
        self._enqueued += 1
        return True

    def log_many(
        self, topic: str, payloads: Sequence[Payload], log_time_ns: int | None = None
    ) -> int:
        """Enqueue ``payloads`` on ``topic``, all with one log time (now if None), under the
        same rules as :meth:`log` each (overload policy, drops counted per topic) at one call's
        cost: what the CAN endpoint uses for the frames and answers of one wake-up. Returns how
        many were taken; the rest (the last ones) were dropped and counted."""
        if topic not in self._schemas:
            raise KeyError(f"unknown MCAP topic {topic!r}; known: {sorted(self._schemas)}")
        if topic not in RECORD_BUILDERS and any(type(p) is tuple for p in payloads):
            raise KeyError(f"MCAP topic {topic!r} takes a dict payload, not a record tuple")
        if not payloads:
            return 0
        if log_time_ns is None:
            log_time_ns = time.time_ns()
        queue = self._queue
        limit = self._soft_size if topic in LOW_PRIORITY_TOPICS else self._queue_size
        room = 0 if self._closed else max(0, limit - len(queue))
        if len(payloads) <= room:
            take = len(payloads)
            queue.extend([(topic, p, log_time_ns) for p in payloads])
        else:
            take = room
            queue.extend([(topic, p, log_time_ns) for p in payloads[:room]])
            self._count_drop(topic, len(payloads) - room)
        self._enqueued += take
        return take

    def enqueue(self, messages: list[QueuedMessage]) -> None:
        """Take ``(topic, payload, log_time_ns)`` messages already checked by another
        logger's :meth:`log` (the process writer's child gets them so): one ``extend`` while
        the queue is below half full, else :meth:`log` each (overload policy, drops
        counted). A topic without a channel or a bad time becomes an error record."""
        queue = self._queue
        if not self._closed and len(queue) + len(messages) < self._soft_size:
            queue.extend(messages)
            self._enqueued += len(messages)
            return
        for topic, payload, t_ns in messages:
            try:
                self.log(topic, payload, t_ns)
            except KeyError:  # not a topic of this log: never silent, never fatal
                queue.append((topic, payload, t_ns))
                self._enqueued += 1

    def _count_drop(self, topic: str, n: int = 1) -> None:
        with self._drop_lock:
            self._dropped += n
            self._dropped_by[topic] = self._dropped_by.get(topic, 0) + n

    def _count_drops(self, messages: Iterable[QueuedMessage]) -> None:
        """Count every message of ``messages`` as dropped, per topic."""
        for topic, _, _ in messages:
            self._count_drop(topic)

    def _drop_queue(self) -> None:
        """Count everything still queued as dropped and empty the queue."""
        while True:
            try:
                topic, _, _ = self._queue.popleft()
            except IndexError:
                return
            self._count_drop(topic)

    def _dropped_snapshot(self) -> dict[str, int]:
        with self._drop_lock:
            return dict(self._dropped_by)

    def kick(self) -> None:
        """Tell the writer (or forwarder) to work now rather than at its next poll: called by a
        producer when it goes idle (the CAN endpoint after its bookkeeping), so the logging
        work lands in the gap between readings, not on top of the next one."""
        self._wake.set()

    @property
    def error(self) -> BaseException | None:
        """The first error the writer met, or None."""
        return self._error

    def _report(self, exc: BaseException) -> None:
        """Keep the first error, log it, pass it to ``on_error`` (whose own failure is logged)."""
        if self._error is None:
            self._error = exc
        _log.error("%s: %r", self._what, exc)
        if self._on_error is not None:
            try:
                self._on_error(exc)
            except Exception:  # the handler's own failure is logged, never raised here
                _log.exception("MCAP on_error handler raised")

    def _report_quietly(self, exc: BaseException) -> None:
        """Pass a problem that does not stop the log (a message that could not be encoded)
        to ``on_error`` and the Python log, without making the logger unhealthy."""
        _log.warning("%s: %s", self._what, exc)
        if self._on_error is not None:
            try:
                self._on_error(exc)
            except Exception:  # the handler's own failure is logged, never raised here
                _log.exception("MCAP on_error handler raised")

    def stop(self, timeout_s: float = 5.0) -> bool:  # pragma: no cover - both writers override
        """Drain, finish the file, end the writer; True if done within ``timeout_s`` (s)."""
        raise NotImplementedError

    def close(self) -> None:
        """Stop with the default timeout (the SIGTERM path)."""
        self.stop()

    def __enter__(self) -> Self:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()
