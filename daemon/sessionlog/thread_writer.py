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

import json
import logging
import os
import socket
import threading
import time
from collections.abc import Callable, Mapping
from datetime import UTC, datetime
from pathlib import Path
from typing import IO

from mcap.writer import CompressionType

from ..osthread import name_os_thread
from .encoding import ERROR_TOPIC, encode_message, error_payload, json_encoder, safe_str
from .fastjson import FAST_JSON
from .logger import HotPathQueue, LoggerStats, LogSettings
from .mcapfile import McapFileWriter
from .schemas import TOPIC_SCHEMAS, TopicSchema, stamp_from_ns
from .writer import (
    finish_session_file,
    free_path,
    open_exclusive,
    open_session_file,
    session_file_name,
)

_log = logging.getLogger(__name__)

WRITER_NAME = "cmm-comp daemon.sessionlog.thread_writer"
"""The ``writer`` key of the files' ``session`` metadata."""
_BATCH = 32  # messages per writer batch before yielding the GIL (bounds roll overshoot too)
_ERROR_REPORTS_PER_S = 10
"""Encode errors passed to ``on_error`` per second at most (all are counted and recorded)."""
_MAX_T_NS = 2**64 - 1


class McapLogger(HotPathQueue):
    """Log JSON messages to MCAP from a hot path without blocking it.

    Arguments: see :class:`~.logger.LogSettings` (``target`` … ``metadata``, ``schemas``), and

    :param on_error: called from the writer thread with every exception it meets.
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
        opener: Callable[[Path], IO[bytes]] = open_exclusive,
        writer_setup: Callable[[], object] | None = None,
    ) -> None:
        settings = LogSettings(
            Path(target),
            roll_bytes,
            roll_s,
            flush_period_s,
            chunk_size,
            queue_size,
            compression,
            fsync,
            metadata or {},
            schemas,
        )
        self._start(settings, on_error, opener, writer_setup)

    @classmethod
    def from_settings(
        cls,
        settings: LogSettings,
        on_error: Callable[[BaseException], None] | None = None,
        opener: Callable[[Path], IO[bytes]] = open_exclusive,
        writer_setup: Callable[[], object] | None = None,
    ) -> McapLogger:
        """A logger for ``settings`` (what the process writer's child runs)."""
        self = cls.__new__(cls)
        self._start(settings, on_error, opener, writer_setup)
        return self

    def _start(
        self,
        settings: LogSettings,
        on_error: Callable[[BaseException], None] | None,
        opener: Callable[[Path], IO[bytes]],
        writer_setup: Callable[[], object] | None,
    ) -> None:
        super().__init__(settings, on_error, "MCAP writer")
        self._single = settings.single
        self._flush_period_s = float(settings.flush_period_s)
        self._opener = opener
        self._writer_setup = writer_setup
        # file work (batches, flushes, rolls, finishing) happens under this lock: the writer
        # thread does it, and drain_to() lets another thread help
        self._io_lock = threading.RLock()
        self._last_flush = time.monotonic()
        self._dirty = False
        self._written = 0
        self._written_by: dict[str, int] = {}
        self._flushed = 0
        self._encode_errors = 0
        self._encode_errors_by: dict[str, int] = {}
        self._upstream_dropped: dict[str, int] = {}
        self._error_reports: list[float] = []
        self._files: list[Path] = []
        self._started_utc = datetime.now(UTC)
        self._session_tag = self._started_utc.strftime("%Y%m%dT%H%M%S")
        self._next_index = 0
        self._metadata = {
            "session_start_utc": self._started_utc.isoformat(),
            "host": socket.gethostname(),
            "pid": str(os.getpid()),
            "writer": WRITER_NAME,
            **settings.metadata,
        }
        if not self._single:
            settings.target.mkdir(parents=True, exist_ok=True)
        # open the first file here so a bad target fails loudly in the caller's thread
        self._stream: IO[bytes] | None = None
        self._writer: McapFileWriter | None = None
        self._channels: dict[str, int] = {}
        self._opened_at = 0.0
        self._open_next()
        self._thread = threading.Thread(target=self._run, name="mcap-writer", daemon=True)
        self._thread.start()

    # ------------------------------------------------------------------ status (log(), error: HotPathQueue)

    @property
    def healthy(self) -> bool:
        """True while the writer thread runs without error."""
        return self._error is None and self._thread.is_alive()

    @property
    def files(self) -> tuple[Path, ...]:
        """Files written so far, in order."""
        return tuple(self._files)

    def stats(self) -> LoggerStats:
        """A snapshot of the counters (drops include those reported by
        :meth:`set_upstream_drops`)."""
        dropped_by = self._dropped_snapshot()
        for topic, n in self._upstream_dropped.items():
            dropped_by[topic] = dropped_by.get(topic, 0) + n
        return LoggerStats(
            enqueued=self._enqueued,
            written=self._written,
            dropped=sum(dropped_by.values()),
            encode_errors=self._encode_errors,
            files=tuple(self._files),
            queue_len=len(self._queue),
            dropped_by_topic=dropped_by,
            encode_errors_by_topic=dict(self._encode_errors_by),
            written_by_topic=dict(self._written_by),
            flushed=self._flushed,
        )

    def own_stats(self) -> LoggerStats:
        """Like :meth:`stats` without the upstream drops (what the process writer's child
        reports to its parent, which adds its own)."""
        return LoggerStats(
            enqueued=self._enqueued,
            written=self._written,
            dropped=self._dropped,
            encode_errors=self._encode_errors,
            files=tuple(self._files),
            queue_len=len(self._queue),
            dropped_by_topic=self._dropped_snapshot(),
            encode_errors_by_topic=dict(self._encode_errors_by),
            written_by_topic=dict(self._written_by),
            flushed=self._flushed,
        )

    def set_upstream_drops(self, dropped_by_topic: dict[str, int]) -> None:
        """Messages dropped before they reached this logger (the process writer's parent
        queue), per topic, since the start: counted in :meth:`stats`, ``/cmm/counters`` and
        ``session_end``, so the file tells the whole story."""
        self._upstream_dropped = dict(dropped_by_topic)

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

    def finish_here(self, timeout_s: float = 1.0) -> bool:
        """Stop like :meth:`stop`, but drain the queue and finish the file in the calling
        thread, then give the writer thread ``timeout_s`` to end (it finds nothing left).
        For a caller with more CPU priority than the writer thread: the process writer's
        child runs its writer at ``SCHED_IDLE``, which a machine loaded to 100 % serves ~0.3 %
        of a core, so a stop left to it could take minutes. Returns True when the file was
        finished here (False: it had already failed or been finished)."""
        self._closed = True
        self._stopping.set()
        finished = False
        try:
            with self._io_lock:
                while self._writer is not None and self._queue:
                    self._step()
                if self._writer is not None:
                    self._finish_current()
                    finished = True
        except BaseException as exc:
            self._fail(exc)
        self._drop_queue()  # raced past: counted, never lost silently
        self._wake.set()
        if threading.current_thread() is not self._thread:
            self._thread.join(timeout_s)
        return finished

    # ------------------------------------------------------------------ writer thread

    def _next_path(self) -> Path:
        target = self._settings.target
        if self._single:
            path = free_path(target)
            if path != target:
                _log.warning("MCAP log %s exists: writing %s instead", target, path)
            return path
        while True:
            path = target / session_file_name(self._session_tag, self._next_index)
            self._next_index += 1
            if not path.exists():
                return path

    def _open_next(self) -> None:
        cfg = self._settings
        for attempt in range(100):
            path = self._next_path()
            meta = {**self._metadata, "file_index": str(len(self._files)), "file": path.name}
            if self._single and path != cfg.target:
                meta["requested_file"] = cfg.target.name
            try:
                self._stream, self._writer, self._channels = open_session_file(
                    path,
                    self._opener,
                    chunk_size=int(cfg.chunk_size),
                    compression=cfg.compression,
                    schemas=self._schemas,
                    metadata=meta,
                )
                break
            except FileExistsError:  # created between our check and our open: next name
                if attempt == 99:
                    raise
        self._opened_at = time.monotonic()
        self._files.append(path)

    def _finish_current(self) -> None:
        writer, stream = self._writer, self._stream
        self._writer = self._stream = None
        if writer is None or stream is None:
            return
        stats = self.stats()
        end = {
            "written": str(stats.written),
            "dropped": str(stats.dropped),
            "encode_errors": str(stats.encode_errors),
            "dropped_by_topic": json.dumps(dict(stats.dropped_by_topic), sort_keys=True),
            "encode_errors_by_topic": json.dumps(
                dict(stats.encode_errors_by_topic), sort_keys=True
            ),
            "written_by_topic": json.dumps(dict(stats.written_by_topic), sort_keys=True),
            "error": repr(self._error) if self._error else "",
        }
        finish_session_file(writer, stream, end, self._settings.fsync)
        self._flushed = self._written

    def _write_batch(self) -> int:
        n = 0
        assert self._writer is not None
        append = self._writer.add_message
        queue = self._queue
        channels = self._channels
        schemas = self._schemas
        written_by = self._written_by
        dumps = json_encoder()
        fast_json = FAST_JSON
        while n < _BATCH:  # short batches (GIL yielded between them); bounds roll overshoot
            try:
                topic, payload, t_ns = queue.popleft()
            except IndexError:
                break
            n += 1
            try:
                if type(t_ns) is not int or not 0 <= t_ns <= _MAX_T_NS:
                    raise ValueError(f"log_time_ns {t_ns!r:.40} is not an integer ns >= 0")
                channel = channels[topic]  # KeyError: not a topic of this file
                fast = fast_json.get(topic) if type(payload) is tuple else None
                data = fast(payload, t_ns) if fast is not None else None  # type: ignore[arg-type]
                if data is None:  # dicts, and records the fast path does not take
                    if topic == "/cmm/counters" and type(payload) is dict:
                        payload = self._with_log_counters(payload)
                    data = encode_message(topic, payload, t_ns, dumps, schemas.get(topic))
            except Exception as exc:  # any bad payload: an error record, never a stop
                self._encode_error(topic, payload, t_ns, exc, dumps)
                continue
            append(channel, t_ns, data, t_ns)
            self._written += 1
            written_by[topic] = written_by.get(topic, 0) + 1
        return n

    def _with_log_counters(self, payload: dict[str, object]) -> dict[str, object]:
        """A ``/cmm/counters`` payload with the log's own counters added (exact drops per
        topic, including the process writer's parent queue)."""
        counters = payload.get("counters")
        if type(counters) is not dict:
            return payload  # refused by the schema check
        return {**payload, "counters": {**counters, **self.stats().counters()}}

    def _encode_error(
        self, topic: str, payload: object, t_ns: object, exc: Exception, dumps: Callable
    ) -> None:
        """Count a message that could not be encoded, write its error record, report it."""
        self._encode_errors += 1
        self._encode_errors_by[topic] = self._encode_errors_by.get(topic, 0) + 1
        self._count_drop(topic)
        channel = self._channels.get(ERROR_TOPIC)
        if channel is not None:
            now_ns = time.time_ns()
            record = {**error_payload(topic, payload, t_ns, exc), "stamp": stamp_from_ns(now_ns)}
            assert self._writer is not None
            self._writer.add_message(channel, now_ns, dumps(record).encode(), now_ns)
            self._written_by[ERROR_TOPIC] = self._written_by.get(ERROR_TOPIC, 0) + 1
        now = time.monotonic()
        recent = [t for t in self._error_reports if now - t < 1.0]
        if len(recent) < _ERROR_REPORTS_PER_S:
            recent.append(now)
            self._report_quietly(
                ValueError(f"{topic}: payload not JSON-encodable: {safe_str(exc)}")
            )
        self._error_reports = recent

    def _flush(self) -> None:
        assert self._writer is not None and self._stream is not None
        self._writer.flush()
        if self._settings.fsync:
            os.fsync(self._stream.fileno())
        self._flushed = self._written

    def _should_roll(self) -> bool:
        if self._single:
            return False
        roll_s, roll_bytes = self._settings.roll_s, self._settings.roll_bytes
        if roll_s is not None and time.monotonic() - self._opened_at >= roll_s:
            return True
        return roll_bytes is not None and self._stream_size() >= roll_bytes

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
        self._drop_queue()
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
            self._drop_queue()  # raced past stop(): counted, never lost silently
        except BaseException as exc:
            self._fail(exc)
