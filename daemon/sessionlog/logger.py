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
from collections.abc import Callable, Mapping
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


@dataclass(frozen=True)
class LoggerStats:
    """Counters since start. ``dropped`` counts messages lost for any reason (queue full,
    logged after stop, writer failed); ``encode_errors`` those that could not be serialised."""

    enqueued: int
    written: int
    dropped: int
    encode_errors: int
    files: tuple[Path, ...]
    queue_len: int


class SessionLogger(Protocol):
    """The session log as the daemon sees it (engine, endpoints, service): log without
    blocking, kick the writer when idle, watch its health, stop it."""

    def log(self, topic: str, payload: Payload, log_time_ns: int | None = None) -> bool:
        """Enqueue one message; never blocks; False when it was dropped."""
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
        self._on_error = on_error
        self._what = what
        self._drop_lock = threading.Lock()
        self._dropped = 0
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
        if len(self._queue) >= self._queue_size or self._closed:
            self._count_drop()
            return False
        self._queue.append((topic, payload, log_time_ns))
        self._enqueued += 1
        return True

    def _count_drop(self, n: int = 1) -> None:
        with self._drop_lock:
            self._dropped += n

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
