"""Writing a session's MCAP files: naming, opening (schemas, channels, ``session`` metadata),
finishing (``session_end`` metadata, summary, indexes), and :class:`SessionWriter`, which writes
messages into them in the calling thread: JSON encoding (a bad payload becomes an error record),
a chunk cut and flush every ``flush_period_s`` (so a SIGKILL loses at most about that much),
files rolled by size and/or age. Each file is written by :class:`.mcapfile.McapFileWriter` with
every index (message, chunk, attachment, metadata).

No threads, no queue: the child of :class:`~.process_writer.McapProcessLogger` (the daemon's
log) drives a :class:`SessionWriter` straight from its shared-memory ring; a program that may
wait for its disk can use one directly.
"""

from __future__ import annotations

import io
import json
import logging
import os
import re
import socket
import time
from collections.abc import Callable, Mapping, Sequence
from datetime import UTC, datetime
from pathlib import Path
from typing import IO, Any, Unpack

from mcap.writer import CompressionType

from cmm_comp.protocol.session_topics import (
    MESSAGE_ENCODING,
    SCHEMA_ENCODING,
    TOPIC_SCHEMAS,
    TopicSchema,
    stamp_from_ns,
)

from ..events import Throttle
from .encoding import ERROR_TOPIC, encode_error, encode_message, error_payload, safe_str
from .logger import LoggerBase, LoggerStats, LogOptions, LogSettings, Payload
from .mcapfile import McapFileWriter

_log = logging.getLogger(__name__)

PROFILE = ""  # no well-known MCAP profile applies to JSON messages
LIBRARY = "cmm-comp mcap 1.x"
SESSION_FILE_RE = re.compile(r"^session-(\d{8}T\d{6})-(\d{3,})\.mcap$")

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


def open_exclusive(path: Path) -> IO[bytes]:
    """Default opener: create ``path`` (refuse to overwrite an existing file) for writing in
    slices; the logger buffers it and owns and closes it."""
    return SlicedFileIO(path, "xb")  # type: ignore[return-value]


def free_path(path: Path) -> Path:
    """``path`` if no file of that name exists, else the first free ``<stem>.<n>.mcap``
    (n = 1, 2, …): an explicit log path is rotated, never refused and never overwritten."""
    if not path.exists():
        return path
    n = 1
    while True:
        candidate = path.with_name(f"{path.stem}.{n}{path.suffix}")
        if not candidate.exists():
            return candidate
        n += 1


def session_file_name(session_tag: str, index: int) -> str:
    """``session-<UTC start YYYYmmddTHHMMSS>-<NNN>.mcap`` (matches :data:`SESSION_FILE_RE`)."""
    return f"session-{session_tag}-{index:03d}.mcap"


def open_session_file(
    path: Path,
    opener: Callable[[Path], IO[bytes]],
    *,
    chunk_size: int,
    compression: CompressionType,
    schemas: Mapping[str, TopicSchema],
    metadata: Mapping[str, str],
) -> tuple[IO[bytes], McapFileWriter, dict[str, int]]:
    """Create ``path``, start the MCAP file: one schema per schema name, one channel per topic,
    the ``session`` metadata record; flushed. Returns the stream, the writer and the channel
    id of each topic."""
    stream = opener(path)
    if isinstance(stream, io.RawIOBase):  # a raw write may write part: buffer it
        stream = io.BufferedWriter(stream)
    writer = McapFileWriter(
        stream, chunk_size=chunk_size, compression=compression, spool_dir=path.parent
    )
    writer.start(profile=PROFILE, library=LIBRARY)
    ids: dict[str, int] = {}
    channels: dict[str, int] = {}
    for topic, sch in schemas.items():
        if sch.name not in ids:
            ids[sch.name] = writer.register_schema(sch.name, SCHEMA_ENCODING, sch.as_bytes())
        channels[topic] = writer.register_channel(topic, MESSAGE_ENCODING, ids[sch.name])
    writer.add_metadata("session", dict(metadata))
    writer.flush()
    return stream, writer, channels


def finish_session_file(
    writer: McapFileWriter, stream: IO[bytes], session_end: Mapping[str, str], fsync: bool
) -> None:
    """Add the ``session_end`` metadata record, write summary and indexes (the chunk index
    streamed from its spool), flush (and fsync), close the stream and delete the spool (also
    when finishing fails)."""
    try:
        writer.add_metadata("session_end", dict(session_end))
        writer.finish()
        if fsync:
            os.fsync(stream.fileno())
    finally:
        try:
            stream.close()
        finally:
            writer.release()


WRITER_NAME = "cmm-comp daemon.sessionlog.writer"
"""The ``writer`` key of the files' ``session`` metadata (unless the caller names another)."""
CHECK_EVERY = 32
"""Messages between two checks of the flush period and the roll limits (bounds roll overshoot)."""
CHECK_S = 0.01
"""Longest time between two such checks while messages come, s."""
_ERROR_REPORTS_PER_S = 10
"""Encode errors passed to ``on_error`` per second at most (all are counted and recorded)."""
_MAX_T_NS = 2**64 - 1


class SessionWriter(LoggerBase):
    """Write a session's messages to MCAP in the calling thread.

    Arguments: see :class:`~.logger.LogSettings` (``queue_size`` is not used: nothing is
    queued), and

    :param on_error: called with every error met (the first one that stops writing is also
        :attr:`error`) and with every message that could not be encoded (at most 10 a second;
        all are counted and written as ``/cmm/log_error`` records).
    :param opener: creates a file's byte stream (tests use it to inject slow or failing sinks).
    :raises: in the caller's thread, ValueError for bad settings, OSError when the first file
        cannot be created.
    """

    def __init__(
        self,
        target: str | os.PathLike[str],
        *,
        on_error: Callable[[BaseException], None] | None = None,
        opener: Callable[[Path], IO[bytes]] = open_exclusive,
        **options: Unpack[LogOptions],
    ) -> None:
        settings = LogSettings.of(target, options)
        super().__init__(settings, on_error, "MCAP writer")
        self._single = settings.single
        self._opener = opener
        self._last_flush = self._next_check = time.monotonic()
        self._since_check = 0
        self._dirty = False
        self._written = 0
        self._written_by: dict[str, int] = {}
        self._flushed = 0
        self._encode_errors = 0
        self._encode_errors_by: dict[str, int] = {}
        self._upstream_dropped: dict[str, int] = {}
        self._error_reports = Throttle(1.0 / _ERROR_REPORTS_PER_S)
        self._files: list[Path] = []
        started = datetime.now(UTC)
        self._session_tag = started.strftime("%Y%m%dT%H%M%S")
        self._next_index = 0
        self._metadata = {
            "session_start_utc": started.isoformat(),
            "host": socket.gethostname(),
            "pid": str(os.getpid()),
            "writer": WRITER_NAME,
            **settings.metadata,
        }
        if not self._single:
            settings.target.mkdir(parents=True, exist_ok=True)
        self._stream: IO[bytes] | None = None
        self._writer: McapFileWriter | None = None
        self._channels: dict[str, int] = {}
        self._opened_at = 0.0
        self._open_next()

    @classmethod
    def from_settings(
        cls, settings: LogSettings, on_error: Callable[[BaseException], None] | None = None
    ) -> SessionWriter:
        """A writer for ``settings`` (what the writer child runs)."""
        return cls(settings.target, on_error=on_error, **settings.options())

    # ------------------------------------------------------------------ messages
    def log_many(
        self, topic: str, payloads: Sequence[Payload], log_time_ns: int | None = None
    ) -> int:
        """Write ``payloads`` of ``topic`` now, with one log time (integer ns; now if None).
        Returns how many were taken: a message is dropped (counted) once the writer stopped
        or failed; one that cannot be encoded is taken: its error record is written."""
        self._check(topic, payloads)
        t_ns = time.time_ns() if log_time_ns is None else log_time_ns
        return sum(self.write(topic, p, t_ns) for p in payloads)

    def write(self, topic: str, payload: Payload, t_ns: int) -> bool:
        """Write one message already checked by a logger's ``log`` (the child's ring records);
        a topic without a channel or a bad time becomes an error record. Never raises: an
        I/O error is reported (:attr:`error`) and ends the writing."""
        if self._writer is None:
            self._count_drop(topic)
            return False
        self._enqueued += 1
        try:
            if type(t_ns) is not int or not 0 <= t_ns <= _MAX_T_NS:
                raise ValueError(f"log_time_ns {t_ns!r:.40} is not an integer ns >= 0")
            channel = self._channels[topic]  # KeyError: not a topic of this file
            if topic == "/cmm/counters" and type(payload) is dict:
                payload = self._with_log_counters(payload)
            data = encode_message(topic, payload, t_ns)
        except Exception as exc:  # any bad payload: an error record, never a stop
            return self._guarded(self._encode_error, topic, payload, t_ns, exc)
        ok = self._guarded(self._writer.add_message, channel, t_ns, data, t_ns)
        if ok:
            self._written += 1
            self._written_by[topic] = self._written_by.get(topic, 0) + 1
            self._dirty = True
            self._since_check += 1
            if self._since_check >= CHECK_EVERY or time.monotonic() >= self._next_check:
                self.tick()
        else:
            self._count_drop(topic)
        return ok

    def kick(self) -> None:
        """Nothing to wake: :meth:`log` writes at once."""

    def tick(self) -> None:
        """Flush when ``flush_period_s`` has passed since the last flush, roll when a limit is
        reached (every :data:`CHECK_EVERY` messages; the writer child also calls it when idle)."""
        now = time.monotonic()
        self._since_check, self._next_check = 0, now + CHECK_S
        if self._writer is None:
            return
        if self._dirty and now - self._last_flush >= self._settings.flush_period_s:
            if not self._guarded(self._flush):
                return
            self._last_flush, self._dirty = now, False
        if self._should_roll() and self._guarded(self._roll):
            self._last_flush, self._dirty = time.monotonic(), False

    def _guarded(self, work: Callable[..., object], *args: object) -> bool:
        """``work(*args)``; False after reporting its exception and ending the writing."""
        try:
            work(*args)
        except BaseException as exc:
            self._fail(exc)
            return False
        return True

    # ------------------------------------------------------------------ status
    @property
    def healthy(self) -> bool:
        """True while the current file is written without error."""
        return self._error is None and self._writer is not None

    @property
    def files(self) -> tuple[Path, ...]:
        """Files written so far, in order."""
        return tuple(self._files)

    def stats(self, upstream: bool = True) -> LoggerStats:
        """A snapshot of the counters; the drops include those reported by
        :meth:`set_upstream_drops` unless ``upstream`` is False (what the writer child reports
        to the daemon, which adds its own)."""
        dropped_by = self._dropped_snapshot()
        for topic, n in self._upstream_dropped.items() if upstream else ():
            dropped_by[topic] = dropped_by.get(topic, 0) + n
        return LoggerStats(
            enqueued=self._enqueued,
            written=self._written,
            dropped=sum(dropped_by.values()),
            encode_errors=self._encode_errors,
            files=tuple(self._files),
            queue_len=0,
            dropped_by_topic=dropped_by,
            encode_errors_by_topic=dict(self._encode_errors_by),
            written_by_topic=dict(self._written_by),
            flushed=self._flushed,
        )

    def set_upstream_drops(self, dropped_by_topic: dict[str, int]) -> None:
        """Messages dropped before they reached this writer (the daemon's side of the process
        writer), per topic, since the start: counted in :meth:`stats`, ``/cmm/counters`` and
        ``session_end``, so the file tells the whole story."""
        self._upstream_dropped = dict(dropped_by_topic)

    # ------------------------------------------------------------------ lifecycle
    def stop(self, timeout_s: float = 5.0) -> bool:
        """Finish the current file (``session_end``, summary, indexes); an error doing so is
        reported (:attr:`error`). Messages logged afterwards are dropped and counted. Returns
        True: nothing is left running (``timeout_s``: the interface's; nothing waits)."""
        self._closed = True
        if self._writer is not None:
            self._guarded(self._finish_current)
        return True

    # ------------------------------------------------------------------ files
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
                    schemas=TOPIC_SCHEMAS,
                    metadata=meta,
                )
                break
            except FileExistsError:  # created between our check and our open: next name
                if attempt == 99:
                    raise
        self._opened_at = time.monotonic()
        self._files.append(path)

    def _roll(self) -> None:
        self._finish_current()
        self._open_next()

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

    def _with_log_counters(self, payload: dict[str, object]) -> dict[str, object]:
        """A ``/cmm/counters`` payload with the log's own counters added (exact drops per
        topic, including the daemon's side of the process writer)."""
        counters = payload.get("counters")
        if type(counters) is not dict:
            return payload  # refused by the schema check
        return {**payload, "counters": {**counters, **self.stats().counters()}}

    def _encode_error(self, topic: str, payload: object, t_ns: object, exc: Exception) -> None:
        """Count a message that could not be encoded, write its error record, report it."""
        self._encode_errors += 1
        self._encode_errors_by[topic] = self._encode_errors_by.get(topic, 0) + 1
        self._count_drop(topic)
        channel = self._channels.get(ERROR_TOPIC)
        if channel is not None and self._writer is not None:
            now_ns = time.time_ns()
            record = {**error_payload(topic, payload, t_ns, exc), "stamp": stamp_from_ns(now_ns)}
            self._writer.add_message(channel, now_ns, encode_error(record), now_ns)
            self._written_by[ERROR_TOPIC] = self._written_by.get(ERROR_TOPIC, 0) + 1
        if self._error_reports.passes() is not None:
            self._report_quietly(
                ValueError(f"{topic}: payload not JSON-encodable: {safe_str(exc)}")
            )

    def _flush(self) -> None:
        assert self._writer is not None and self._stream is not None
        self._writer.flush()
        if self._settings.fsync:
            os.fsync(self._stream.fileno())
        self._flushed = self._written

    def _should_roll(self) -> bool:
        if self._single or self._stream is None:
            return False
        roll_s, roll_bytes = self._settings.roll_s, self._settings.roll_bytes
        if roll_s is not None and time.monotonic() - self._opened_at >= roll_s:
            return True
        return roll_bytes is not None and self._stream.tell() >= roll_bytes

    def _fail(self, exc: BaseException) -> None:
        """The file can no longer be written: report, finish what can be, drop from now on."""
        self._report(exc)
        self._closed = True
        try:
            self._finish_current()
        except BaseException as exc2:
            _log.error("MCAP writer: could not finish file after error: %r", exc2)
