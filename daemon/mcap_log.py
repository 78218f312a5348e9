"""Non-blocking MCAP session logger: the hot path enqueues, one writer thread writes.

``McapLogger.log(topic, payload)`` only appends ``(topic, payload, log_time_ns)`` to a bounded
deque (a fraction of a microsecond); when the deque is full the message is dropped and counted,
the caller is never blocked. The writer thread serialises JSON, adds the ``stamp`` when the
payload has none, writes chunked MCAP, cuts a chunk every ``flush_period_s`` (so a SIGKILL loses
at most about that much), rolls files by size and/or age, and on ``stop()`` drains the queue and
finishes the file (summary and indexes). Errors in the writer thread reach ``on_error`` and
``McapLogger.error``; they are never silent.
"""

from __future__ import annotations

import collections
import io
import json
import logging
import os
import re
import socket
import threading
import time
from collections.abc import Callable, Mapping
from dataclasses import dataclass
from datetime import UTC, datetime
from pathlib import Path
from typing import IO, Any

from mcap.writer import CompressionType, Writer

from cmm_comp.daemon.mcap_records import RECORD_BUILDERS, expand
from cmm_comp.daemon.mcap_schemas import (
    MESSAGE_ENCODING,
    SCHEMA_ENCODING,
    TOPIC_SCHEMAS,
    TopicSchema,
    stamp_from_ns,
)
from cmm_comp.daemon.osthread import name_os_thread

_log = logging.getLogger(__name__)

PROFILE = ""  # no well-known MCAP profile applies to JSON messages
SESSION_FILE_RE = re.compile(r"^session-(\d{8}T\d{6})-(\d{3,})\.mcap$")


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


WRITE_SLICE = 16 * 1024
"""Largest single ``write`` system call, bytes (see :class:`SlicedFileIO`)."""


class SlicedFileIO(io.FileIO):
    """A raw file whose ``write`` writes at most :data:`WRITE_SLICE` bytes per system call
    (``io.BufferedWriter`` on top loops over partial writes, so callers see whole writes).

    Why: on a kernel without kernel preemption (``PREEMPT_NONE``, common on servers and VMs) a
    task inside a ``write`` of a 100-kB chunk keeps its CPU until the call returns, even at
    the lowest priority, so a reply thread woken onto that CPU waits for it. Short calls
    return to user space, where the low-priority writer is preempted at once."""

    def write(self, b: Any) -> int:  # type: ignore[override]
        view = memoryview(b).cast("B")
        n = super().write(view[:WRITE_SLICE])
        return 0 if n is None else n


def _open_exclusive(path: Path) -> IO[bytes]:
    """Default opener: create ``path`` (refuse to overwrite an existing file) for writing in
    slices; the logger buffers it and owns and closes it."""
    return SlicedFileIO(path, "xb")  # type: ignore[return-value]


_BATCH = 32  # messages per writer batch before yielding the GIL (bounds roll overshoot too)


class HotPathQueue:
    """The never-blocking front half both loggers share: :meth:`log` only appends to a bounded
    deque (or counts a drop); a writer thread (or a forwarder to a child process) drains it."""

    _schemas: Mapping[str, Any]
    _queue: collections.deque[tuple[str, dict[str, Any] | tuple[Any, ...], int]]
    _queue_size: int
    _closed: bool
    _enqueued: int
    _dropped: int
    _drop_lock: threading.Lock
    _wake: threading.Event

    def log(
        self,
        topic: str,
        payload: dict[str, Any] | tuple[Any, ...],
        log_time_ns: int | None = None,
    ) -> bool:
        """Enqueue one message; never blocks. Returns False when it was dropped.

        :param topic: one of the configured topics (KeyError otherwise: a programming error).
        :param payload: the JSON object, or for the topics of
            :data:`daemon.mcap_records.RECORD_BUILDERS` a compact record tuple that the writer
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


class McapLogger(HotPathQueue):
    """Log JSON messages to MCAP from a hot path without blocking it.

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
    :param on_error: called from the writer thread with every exception it meets.
    :param schemas: topic to schema; defaults to :data:`daemon.mcap_schemas.TOPIC_SCHEMAS`.
    :param opener: creates a file's byte stream (tests use it to inject slow or failing sinks).
    :param writer_setup: called first in the writer thread (e.g. to lower that thread's CPU
        priority); an exception from it is logged and the thread runs on.
    """

    def __init__(
        self,
        target: str | os.PathLike[str],
        *,
        roll_bytes: int | None = None,
        roll_s: float | None = None,
        flush_period_s: float = 1.0,
        chunk_size: int = 256 * 1024,
        queue_size: int = 100_000,
        compression: CompressionType = CompressionType.ZSTD,
        fsync: bool = False,
        metadata: Mapping[str, str] | None = None,
        on_error: Callable[[BaseException], None] | None = None,
        schemas: Mapping[str, TopicSchema] = TOPIC_SCHEMAS,
        opener: Callable[[Path], IO[bytes]] = _open_exclusive,
        writer_setup: Callable[[], object] | None = None,
    ) -> None:
        target = Path(target)
        self._single = target.suffix == ".mcap"
        if self._single and (roll_bytes is not None or roll_s is not None):
            raise ValueError(f"{target}: rolling needs a directory target, not a .mcap file")
        if flush_period_s <= 0:
            raise ValueError(f"flush_period_s={flush_period_s!r} must be > 0 s")
        if queue_size < 1:
            raise ValueError(f"queue_size={queue_size!r} must be >= 1")
        for name, val in (("roll_bytes", roll_bytes), ("roll_s", roll_s)):
            if val is not None and val <= 0:
                raise ValueError(f"{name}={val!r} must be > 0 or None")
        self._target = target
        self._roll_bytes = roll_bytes
        self._roll_s = roll_s
        self._flush_period_s = float(flush_period_s)
        self._chunk_size = int(chunk_size)
        self._compression = compression
        self._fsync = fsync
        self._on_error = on_error
        self._schemas = dict(schemas)
        self._opener = opener
        self._writer_setup = writer_setup
        # file work (batches, flushes, rolls, finishing) happens under this lock: the writer
        # thread does it, and drain_to() lets another thread help
        self._io_lock = threading.RLock()
        self._last_flush = time.monotonic()
        self._dirty = False
        self._queue: collections.deque[tuple[str, dict[str, Any] | tuple[Any, ...], int]] = (
            collections.deque()
        )
        self._queue_size = int(queue_size)
        self._drop_lock = threading.Lock()
        self._dropped = 0
        self._enqueued = 0  # approximate under concurrency, exact from one thread
        self._written = 0
        self._encode_errors = 0
        self._files: list[Path] = []
        self._error: BaseException | None = None
        self._stopping = threading.Event()
        self._wake = threading.Event()
        self._closed = False
        self._started_utc = datetime.now(UTC)
        self._session_tag = self._started_utc.strftime("%Y%m%dT%H%M%S")
        self._next_index = 0
        self._metadata = {
            "session_start_utc": self._started_utc.isoformat(),
            "host": socket.gethostname(),
            "pid": str(os.getpid()),
            "writer": "cmm-comp daemon.mcap_log",
            **dict(metadata or {}),
        }
        if not self._single:
            target.mkdir(parents=True, exist_ok=True)
        # open the first file here so a bad target fails loudly in the caller's thread
        self._stream: IO[bytes] | None = None
        self._writer: Writer | None = None
        self._channels: dict[str, int] = {}
        self._opened_at = 0.0
        self._open_next()
        self._thread = threading.Thread(target=self._run, name="mcap-writer", daemon=True)
        self._thread.start()

    # ------------------------------------------------------------------ status (log(): HotPathQueue)

    @property
    def error(self) -> BaseException | None:
        """The first exception the writer thread met, or None."""
        return self._error

    @property
    def healthy(self) -> bool:
        """True while the writer thread runs without error."""
        return self._error is None and self._thread.is_alive()

    @property
    def files(self) -> tuple[Path, ...]:
        """Files written so far, in order."""
        return tuple(self._files)

    def stats(self) -> LoggerStats:
        """A snapshot of the counters."""
        return LoggerStats(
            enqueued=self._enqueued,
            written=self._written,
            dropped=self._dropped,
            encode_errors=self._encode_errors,
            files=tuple(self._files),
            queue_len=len(self._queue),
        )

    # ------------------------------------------------------------------ lifecycle

    def stop(self, timeout_s: float = 5.0) -> bool:
        """Drain the queue, finish the current file and join the writer thread.

        Safe from a signal handler in the main thread. Messages logged afterwards are dropped
        and counted. Returns True when the thread finished within ``timeout_s`` (s).
        """
        self._closed = True
        self._stopping.set()
        self._wake.set()
        if threading.current_thread() is not self._thread:
            self._thread.join(timeout_s)
        return not self._thread.is_alive()

    def close(self) -> None:
        """Stop with the default timeout (the SIGTERM path)."""
        self.stop()

    def __enter__(self) -> McapLogger:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    # ------------------------------------------------------------------ writer thread

    def _next_path(self) -> Path:
        if self._single:
            return self._target
        while True:
            name = f"session-{self._session_tag}-{self._next_index:03d}.mcap"
            self._next_index += 1
            path = self._target / name
            if not path.exists():
                return path

    def _open_next(self) -> None:
        path = self._next_path()
        stream = self._opener(path)
        if isinstance(stream, io.RawIOBase):  # else mcap wraps it in a buffer we cannot flush
            stream = io.BufferedWriter(stream)
        writer = Writer(stream, chunk_size=self._chunk_size, compression=self._compression)
        writer.start(profile=PROFILE, library="cmm-comp mcap 1.x")
        ids: dict[str, int] = {}
        channels: dict[str, int] = {}
        for topic, sch in self._schemas.items():
            if sch.name not in ids:
                ids[sch.name] = writer.register_schema(sch.name, SCHEMA_ENCODING, sch.as_bytes())
            channels[topic] = writer.register_channel(topic, MESSAGE_ENCODING, ids[sch.name])
        meta = {**self._metadata, "file_index": str(len(self._files)), "file": path.name}
        writer.add_metadata("session", meta)
        writer.flush()
        self._stream, self._writer, self._channels = stream, writer, channels
        self._opened_at = time.monotonic()
        self._files.append(path)

    def _finish_current(self) -> None:
        writer, stream = self._writer, self._stream
        self._writer = self._stream = None
        if writer is None or stream is None:
            return
        try:
            stats = self.stats()
            writer.add_metadata(
                "session_end",
                {
                    "written": str(stats.written),
                    "dropped": str(stats.dropped),
                    "encode_errors": str(stats.encode_errors),
                    "error": repr(self._error) if self._error else "",
                },
            )
            writer.finish()
            stream.flush()
            if self._fsync:
                os.fsync(stream.fileno())
        finally:
            stream.close()

    def _report(self, exc: BaseException) -> None:
        if self._error is None:
            self._error = exc
        _log.error("MCAP writer: %r", exc)
        if self._on_error is not None:
            try:
                self._on_error(exc)
            except Exception:  # the handler's own failure is logged, never raised here
                _log.exception("MCAP on_error handler raised")

    def _write_batch(self) -> int:
        n = 0
        writer = self._writer
        assert writer is not None
        queue = self._queue
        channels = self._channels
        dumps = json.JSONEncoder(separators=(",", ":"), allow_nan=False).encode
        while n < _BATCH:  # short batches (GIL yielded between them); bounds roll overshoot
            try:
                topic, payload, t_ns = queue.popleft()
            except IndexError:
                break
            n += 1
            try:
                obj = expand(topic, payload)
                if "stamp" not in obj:
                    obj = {**obj, "stamp": stamp_from_ns(t_ns)}
                data = dumps(obj).encode()
            except (TypeError, ValueError, KeyError, IndexError, OverflowError) as exc:
                self._encode_errors += 1
                self._count_drop()
                self._report(ValueError(f"{topic}: payload not JSON-encodable: {exc}"))
                continue
            writer.add_message(channels[topic], t_ns, data, t_ns)
            self._written += 1
        return n

    def _flush(self) -> None:
        assert self._writer is not None and self._stream is not None
        self._writer.flush()
        if self._fsync:
            os.fsync(self._stream.fileno())

    def _should_roll(self) -> bool:
        if self._single:
            return False
        if self._roll_s is not None and time.monotonic() - self._opened_at >= self._roll_s:
            return True
        return self._roll_bytes is not None and self._stream_size() >= self._roll_bytes

    def _stream_size(self) -> int:
        assert self._stream is not None
        return self._stream.tell()

    @property
    def backlog(self) -> int:
        """Messages waiting to be written."""
        return len(self._queue)

    def drain_to(self, max_len: int) -> int:
        """Write queued messages from the calling thread until at most ``max_len`` wait;
        returns how many were written. For a caller with more CPU priority than the writer
        thread: the process writer's child runs its writer thread at ``SCHED_IDLE`` and its
        normal-priority main thread helps here when the backlog grows (a fully loaded machine
        would otherwise starve the writer and drop messages)."""
        written = 0
        try:
            while len(self._queue) > max_len:
                with self._io_lock:
                    if self._writer is None:
                        break
                    n = self._step()
                if n == 0:
                    break
                written += n
        except BaseException as exc:
            self._fail(exc)
        return written

    def _step(self) -> int:
        """One batch, then the periodic flush and the roll when due (under ``_io_lock``)."""
        n = self._write_batch()
        self._dirty = self._dirty or n > 0
        now = time.monotonic()
        if self._dirty and now - self._last_flush >= self._flush_period_s:
            self._flush()
            self._last_flush, self._dirty = now, False
        if n and self._should_roll():
            self._finish_current()
            self._open_next()
            self._last_flush, self._dirty = time.monotonic(), False
        return n

    def _fail(self, exc: BaseException) -> None:
        """The file can no longer be written: report, drop everything queued or coming."""
        self._report(exc)
        # keep the hot path cheap and honest: everything still queued or coming is dropped
        self._closed = True
        self._count_drop(len(self._queue))
        self._queue.clear()
        with self._io_lock:
            try:
                self._finish_current()
            except BaseException as exc2:
                _log.error("MCAP writer: could not finish file after error: %r", exc2)

    def _run(self) -> None:
        name_os_thread()
        if self._writer_setup is not None:
            try:
                self._writer_setup()
            except Exception:
                _log.exception("MCAP writer: writer_setup failed (running on without it)")
        poll_s = min(0.01, self._flush_period_s / 4)
        try:
            while True:
                stopping = self._stopping.is_set()
                with self._io_lock:
                    if self._writer is None:  # a helper met an error and closed the file
                        break
                    n = self._step()
                if n:
                    time.sleep(0)  # yield the GIL between short batches: the reply path comes first
                if stopping and not self._queue:
                    break
                if n == 0:
                    self._wake.wait(poll_s)
                    self._wake.clear()
            with self._io_lock:
                self._finish_current()
            self._count_drop(len(self._queue))  # raced past stop(): counted, never lost silently
        except BaseException as exc:
            self._fail(exc)
