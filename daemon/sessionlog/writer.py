"""Writing one MCAP session file: naming, opening (schemas, channels, ``session`` metadata),
finishing (``session_end`` metadata, summary, indexes).

Pure file work, no threads: :class:`~.thread_writer.McapLogger` drives it (in the daemon's
process, or in the child of :class:`~.process_writer.McapProcessLogger`).
"""

from __future__ import annotations

import io
import os
import re
import struct
from collections.abc import Callable, Mapping
from pathlib import Path
from typing import IO, Any

from mcap.writer import CompressionType, IndexType, Writer

from .schemas import MESSAGE_ENCODING, SCHEMA_ENCODING, TopicSchema
from .summary import close_spool, finish_writer, spool_chunk_index

PROFILE = ""  # no well-known MCAP profile applies to JSON messages
LIBRARY = "cmm-comp mcap 1.x"
SESSION_FILE_RE = re.compile(r"^session-(\d{8}T\d{6})-(\d{3,})\.mcap$")

INDEX_TYPES = IndexType.CHUNK | IndexType.ATTACHMENT | IndexType.METADATA
"""Summary indexes written: chunk, attachment and metadata indexes, no per-chunk message index
records. Readers (the ``mcap`` package, Foxglove) find every message through the chunk index
(message indexes are optional in MCAP; files are smaller without). The chunk index waits on
disk until the file is finished (:mod:`.summary`)."""

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


_MESSAGE_HEAD = struct.Struct("<BQHIQQ")
"""Opcode, record length, channel id, sequence, log time, publish time of an MCAP Message."""
_OP_MESSAGE = 0x05


class MessageAppender:
    """``writer.add_message(channel, t, data, t)`` for chunked writers without message index
    records (:data:`INDEX_TYPES`), ~4× cheaper: one ``struct`` header and two buffer writes
    instead of a ``Message`` object, a per-channel index entry and five small writes. It keeps
    the writer's statistics and chunk bookkeeping exactly as ``add_message`` does (``mcap``
    1.6, pinned), so the file is byte-identical (``tests/test_mcap_fastjson.py`` compares
    whole files); with another layout of the writer's internals it calls ``add_message``."""

    def __init__(self, writer: Writer) -> None:
        self._writer = writer
        stats = getattr(writer, "_Writer__statistics", None)
        builder = getattr(writer, "_Writer__chunk_builder", None)
        index_types = getattr(writer, "_Writer__index_types", None)
        finalize = getattr(writer, "_Writer__maybe_finalize_chunk", None)
        buf = getattr(getattr(builder, "record_writer", None), "_buffer", None)
        self._fast = (
            stats is not None
            and builder is not None
            and finalize is not None
            and isinstance(buf, io.BytesIO)
            and isinstance(getattr(builder, "num_messages", None), int)
            and isinstance(getattr(stats, "message_count", None), int)
            and hasattr(stats, "channel_message_counts")
            and index_types is not None
            and not index_types & IndexType.MESSAGE
        )
        self._stats: Any = stats
        self._builder: Any = builder
        self._finalize: Any = finalize
        self._chunk_size = getattr(writer, "_Writer__chunk_size", 0)

    def __call__(self, channel_id: int, t_ns: int, data: bytes) -> None:
        """Add one message with log time = publish time = ``t_ns`` (int ns, checked)."""
        if not self._fast:
            self._writer.add_message(channel_id, t_ns, data, t_ns)
            return
        stats, cb = self._stats, self._builder
        if stats.message_count == 0 or t_ns < stats.message_start_time:
            stats.message_start_time = t_ns
        if t_ns > stats.message_end_time:
            stats.message_end_time = t_ns
        stats.channel_message_counts[channel_id] += 1
        stats.message_count += 1
        if cb.num_messages == 0 or t_ns < cb.message_start_time:
            cb.message_start_time = t_ns
        if t_ns > cb.message_end_time:
            cb.message_end_time = t_ns
        cb.num_messages += 1
        buf = cb.record_writer._buffer  # replaced at every chunk end
        buf.write(_MESSAGE_HEAD.pack(_OP_MESSAGE, 22 + len(data), channel_id, 0, t_ns, t_ns))
        buf.write(data)
        if buf.tell() > self._chunk_size:
            self._finalize()


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
) -> tuple[IO[bytes], Writer, dict[str, int]]:
    """Create ``path``, start the MCAP file: one schema per schema name, one channel per topic,
    the ``session`` metadata record; flushed. Returns the stream, the writer and the channel
    id of each topic."""
    stream = opener(path)
    if isinstance(stream, io.RawIOBase):  # else mcap wraps it in a buffer we cannot flush
        stream = io.BufferedWriter(stream)
    writer = Writer(stream, chunk_size=chunk_size, compression=compression, index_types=INDEX_TYPES)
    spool_chunk_index(writer, path.parent)
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
    writer: Writer, stream: IO[bytes], session_end: Mapping[str, str], fsync: bool
) -> None:
    """Add the ``session_end`` metadata record, write summary and indexes (the chunk index
    streamed from its spool: :func:`.summary.finish_writer`), flush (and fsync), close the
    stream and delete the spool (also when finishing fails)."""
    try:
        writer.add_metadata("session_end", dict(session_end))
        finish_writer(writer)
        stream.flush()
        if fsync:
            os.fsync(stream.fileno())
    finally:
        try:
            stream.close()
        finally:
            close_spool(writer)
