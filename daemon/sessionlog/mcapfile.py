"""A chunked MCAP file with every index: :class:`McapFileWriter`.

It writes what the ``mcap`` package's ``Writer`` writes with all indexes (``IndexType.ALL``,
its defaults): the same records in the same order, byte for byte (``tests/test_mcap_file.py``
compares whole files). Every record but the per-message ones is built by that package's public
record classes (``mcap.records``: ``.write(RecordBuilder)``). What is ours, and why it exists:

* a message costs one packed header, two buffer appends and one index entry (docs/mcap.md,
  "The writer's cost per message"); ``Writer.add_message`` with message indexes costs ~5× more;
* the Chunk Index records wait on disk, in an anonymous temporary file next to the log (nothing
  is left behind by a crash; ``cmm-comp mcap recover`` rebuilds them from the chunks), and the
  summary is streamed from there: memory does not grow with the file (the ``mcap`` writer keeps
  ~1.4 KiB per chunk until it finishes: ~40 MiB an hour for a file that never rolls at 1 kHz).

Message Index records are written after every chunk: ``@mcap/core``'s ``McapIndexedReader``
(what Foxglove and Lichtblick use for local files) refuses a chunk index without them.

Layout: Header; then, in call order, Metadata and Attachment records (written at once) and
Chunks (each followed by its Message Index records; Schema and Channel records go into the
chunk in progress and reach the file with its first message); Data End; the summary (schemas,
channels, statistics, chunk indexes, attachment indexes, metadata indexes, one summary offset
per group); Footer. A chunk is written when its uncompressed records exceed ``chunk_size`` or at
:meth:`McapFileWriter.flush`: a process killed between two flushes loses the chunk in progress
and nothing before it.
"""

from __future__ import annotations

import struct
import sys
import tempfile
import zlib
from array import array
from collections.abc import Callable, Iterable, Iterator, Mapping
from pathlib import Path
from typing import IO

from mcap.data_stream import RecordBuilder
from mcap.opcode import Opcode
from mcap.records import (
    Attachment,
    AttachmentIndex,
    Channel,
    Chunk,
    ChunkIndex,
    DataEnd,
    Footer,
    Header,
    McapRecord,
    Metadata,
    MetadataIndex,
    Schema,
    Statistics,
    SummaryOffset,
)
from mcap.writer import CompressionType

MAGIC = b"\x89MCAP0\r\n"
"""Starts and ends every MCAP file."""
MESSAGE_HEAD = struct.Struct("<BQHIQQ")
"""A whole Message record up to its data: opcode, length (22 + data), channel id, sequence,
log time, publish time (ns)."""
_MESSAGE_FIXED = 22
_OP_MESSAGE = int(Opcode.MESSAGE)
_pack_message_head = MESSAGE_HEAD.pack
_MESSAGE_INDEX_HEAD = struct.Struct("<BQHI")
_SWAP = sys.byteorder != "little"
COPY_BLOCK = 64 * 1024
"""Bytes read from the chunk index spool at a time when it is copied into the summary."""

Compress = Callable[[bytearray], bytes]
"""Compresses one chunk's records (a buffer) into the bytes the Chunk record holds."""


def record_bytes(*records: McapRecord) -> bytes:
    """``records`` as the file holds them (``mcap``'s own serialization)."""
    builder = RecordBuilder()
    for rec in records:
        rec.write(builder)
    return builder.end()


def compressor(compression: CompressionType) -> tuple[str, Compress]:
    """The Chunk record's compression name and the function that compresses a chunk (what
    the ``mcap`` package does: zstd at level 3, an LZ4 frame; the zstd context is kept)."""
    if compression == CompressionType.ZSTD:
        import zstandard

        return "zstd", zstandard.ZstdCompressor(level=3).compress
    if compression == CompressionType.LZ4:
        import lz4.frame

        return "lz4", lz4.frame.compress
    if compression == CompressionType.NONE:
        return "", bytes
    raise ValueError(f"compression {compression!r}; allowed: ZSTD, LZ4, NONE")


def message_index(channel_id: int, times_offsets: list[int]) -> bytes:
    """Message Index record of one channel in one chunk; ``times_offsets`` holds the
    ``(log time, offset in the uncompressed chunk)`` pairs flattened: ``[t0, o0, t1, o1, …]``."""
    packed = array("Q", times_offsets)  # OverflowError if one is not a uint64
    if _SWAP:
        packed.byteswap()
    n = 8 * len(times_offsets)
    head = _MESSAGE_INDEX_HEAD.pack(Opcode.MESSAGE_INDEX, 6 + n, channel_id, n)
    return head + packed.tobytes()


class McapFileWriter:
    """Write one chunked MCAP file with all indexes to ``stream`` (module docstring).

    :param stream: a binary stream whose ``write`` writes everything (a buffered file,
        ``io.BytesIO``, a pipe), positioned where the file starts; it is flushed, never closed
        (the writer never seeks: it counts the bytes it wrote).
    :param chunk_size: a chunk is written once its uncompressed records exceed this, bytes.
    :param compression: chunk compression.
    :param spool_dir: directory of the chunk index spool's anonymous file (default: the
        system's temporary directory).

    Call :meth:`start` first, :meth:`finish` last, and :meth:`release` in any case (it deletes
    the spool). Not thread-safe: one thread writes.
    """

    def __init__(
        self,
        stream: IO[bytes],
        *,
        chunk_size: int = 1024 * 1024,
        compression: CompressionType = CompressionType.ZSTD,
        spool_dir: str | Path | None = None,
    ) -> None:
        self._stream = stream
        try:
            self._pos = stream.tell()  # offsets in the file are from its start
        except (OSError, ValueError):  # io.UnsupportedOperation: a pipe, written from its start
            self._pos = 0
        self._chunk_size = int(chunk_size)
        self._room = self._chunk_size - MESSAGE_HEAD.size
        """A message whose data ends past this (offset + size) makes the chunk exceed
        ``chunk_size``: the chunk is written."""
        self._compression, self._compress = compressor(compression)
        self._chunk = bytearray()
        self._index: dict[int, list[int]] = {}
        """Per channel of the chunk in progress, ``[log time, offset, log time, offset, …]``."""
        self._schemas: dict[int, bytes] = {}
        self._channels: dict[int, bytes] = {}
        self._stats = Statistics(0, 0, {}, 0, 0, 0, 0, 0, 0)
        self._attachment_indexes: list[bytes] = []
        self._metadata_indexes: list[bytes] = []
        self._spool_dir = None if spool_dir is None else str(spool_dir)
        self._spool: IO[bytes] | None = None
        self._spooled = 0
        self._state = "new"

    # ------------------------------------------------------------------ records

    def start(self, profile: str = "", library: str = "") -> None:
        """Write the magic and the Header record."""
        if self._state != "new":
            raise ValueError("MCAP writer already started")
        self._state = "open"
        self._write(MAGIC + record_bytes(Header(profile, library)))

    def register_schema(self, name: str, encoding: str, data: bytes) -> int:
        """Add a Schema record (to the chunk in progress); returns its id (1, 2, …)."""
        self._check_open()
        schema_id = len(self._schemas) + 1
        rec = record_bytes(Schema(id=schema_id, data=data, encoding=encoding, name=name))
        self._to_chunk(rec, self._schemas, schema_id)
        return schema_id

    def register_channel(
        self,
        topic: str,
        message_encoding: str,
        schema_id: int,
        metadata: Mapping[str, str] | None = None,
    ) -> int:
        """Add a Channel record (to the chunk in progress); returns its id (1, 2, …).
        ``schema_id`` 0 means no schema."""
        self._check_open()
        if schema_id and schema_id not in self._schemas:
            raise ValueError(f"channel {topic!r}: schema id {schema_id} is not registered")
        channel_id = len(self._channels) + 1
        rec = Channel(channel_id, topic, message_encoding, dict(metadata or {}), schema_id)
        self._to_chunk(record_bytes(rec), self._channels, channel_id)
        return channel_id

    def add_message(
        self, channel_id: int, log_time: int, data: bytes, publish_time: int, sequence: int = 0
    ) -> None:
        """Add one Message record to the chunk in progress (times: int ns, uint64); write the
        chunk when it exceeds ``chunk_size``. The hot path of the session log."""
        size = len(data)
        head = _pack_message_head(
            _OP_MESSAGE, _MESSAGE_FIXED + size, channel_id, sequence, log_time, publish_time
        )  # raises (struct.error) before anything changes on a value out of range
        chunk = self._chunk
        pos = len(chunk)
        index = self._index.get(channel_id)
        if index is None:
            if channel_id not in self._channels:
                raise ValueError(f"channel id {channel_id} is not registered")
            self._check_open()
            index = self._index[channel_id] = []
        index.append(log_time)
        index.append(pos)
        chunk += head
        chunk += data
        if pos + size > self._room:
            self._finish_chunk()

    def add_metadata(self, name: str, values: Mapping[str, str]) -> None:
        """Write a Metadata record now (outside chunks) and index it."""
        self._check_open()
        offset, rec = self._pos, record_bytes(Metadata(name, dict(values)))
        self._write(rec)
        self._metadata_indexes.append(record_bytes(MetadataIndex(offset, len(rec), name)))

    def add_attachment(
        self, create_time: int, log_time: int, name: str, media_type: str, data: bytes
    ) -> None:
        """Write an Attachment record now (outside chunks) and index it."""
        self._check_open()
        offset = self._pos
        rec = record_bytes(Attachment(create_time, log_time, name, media_type, data))
        self._write(rec)
        index = AttachmentIndex(
            offset, len(rec), log_time, create_time, len(data), name, media_type
        )
        self._attachment_indexes.append(record_bytes(index))

    # ------------------------------------------------------------------ flushing and finishing

    def flush(self) -> None:
        """Write the chunk in progress (if it holds a message) and flush the stream."""
        self._check_open()
        self._finish_chunk()
        self._stream.flush()

    def finish(self) -> None:
        """Write the last chunk, Data End, the summary (chunk indexes streamed from the spool),
        the Footer and the closing magic; flush the stream (it stays open)."""
        self._check_open()
        self._finish_chunk()
        self._state = "finished"
        self._write(record_bytes(DataEnd(0)))
        st = self._stats
        st.schema_count, st.channel_count = len(self._schemas), len(self._channels)
        st.attachment_count = len(self._attachment_indexes)
        st.metadata_count = len(self._metadata_indexes)
        groups: list[tuple[Opcode, Iterable[bytes]]] = [
            (Opcode.SCHEMA, self._schemas.values()),
            (Opcode.CHANNEL, self._channels.values()),
            (Opcode.STATISTICS, [record_bytes(st)]),
            (Opcode.CHUNK_INDEX, self._spooled_blocks()),
            (Opcode.ATTACHMENT_INDEX, self._attachment_indexes),
            (Opcode.METADATA_INDEX, self._metadata_indexes),
        ]
        summary_start = self._pos
        crc = 0
        offsets = []
        for opcode, blocks in groups:  # one summary offset per group, also an empty one
            start = self._pos
            for block in blocks:
                self._write(block)
                crc = zlib.crc32(block, crc)
            offsets.append(SummaryOffset(opcode, start, self._pos - start))
        tail = record_bytes(*offsets, Footer(summary_start, self._pos, 0))
        # the summary CRC covers the summary section and the footer up to the CRC itself
        crc = zlib.crc32(tail[:-4], crc)
        self._write(tail[:-4] + struct.pack("<I", crc) + MAGIC)
        self._stream.flush()

    def release(self) -> None:
        """Delete the chunk index spool (after :meth:`finish`, or when the file is abandoned
        after an error); idempotent. The stream is the caller's to close."""
        spool, self._spool = self._spool, None
        if spool is not None:
            spool.close()
        if self._state == "open":
            self._state = "abandoned"

    @property
    def chunk_count(self) -> int:
        """Chunks written so far."""
        return self._stats.chunk_count

    # ------------------------------------------------------------------ internals

    def _check_open(self) -> None:
        if self._state != "open":
            raise ValueError(f"MCAP writer is {self._state}: start() it, or it is done")

    def _write(self, data: bytes | bytearray) -> None:
        self._stream.write(data)
        self._pos += len(data)

    def _to_chunk(self, rec: bytes, registry: dict[int, bytes], key: int) -> None:
        registry[key] = rec
        self._chunk += rec
        if len(self._chunk) > self._chunk_size:
            self._finish_chunk()

    def _spooled_blocks(self) -> Iterator[bytes]:
        """The spooled Chunk Index records, :data:`COPY_BLOCK` bytes at a time."""
        if self._spool is None:
            return
        self._spool.flush()
        self._spool.seek(0)
        left = self._spooled
        while left > 0:
            block = self._spool.read(min(COPY_BLOCK, left))
            if not block:
                raise OSError(f"chunk index spool is short by {left} bytes")
            left -= len(block)
            yield block

    def _finish_chunk(self) -> None:
        """Write the chunk in progress and its Message Index records, spool its Chunk Index
        record, count its messages. Nothing without a message (schema and channel records
        wait for the next chunk)."""
        index = self._index
        if not index:
            return
        raw = self._chunk  # not copied: a new buffer replaces it below
        times = [v[0::2] for v in index.values()]
        start_ns, end_ns = min(map(min, times)), max(map(max, times))
        data = self._compress(raw)
        chunk_start = self._pos
        crc = zlib.crc32(raw)
        self._write(record_bytes(Chunk(self._compression, data, end_ns, start_ns, crc, len(raw))))
        chunk_length = self._pos - chunk_start
        offsets: dict[int, int] = {}
        counts = self._stats.channel_message_counts
        for channel_id, times_offsets in index.items():
            offsets[channel_id] = self._pos
            self._write(message_index(channel_id, times_offsets))
            counts[channel_id] = counts.get(channel_id, 0) + len(times_offsets) // 2
        rec = ChunkIndex(
            chunk_length=chunk_length,
            chunk_start_offset=chunk_start,
            compression=self._compression,
            compressed_size=len(data),
            message_end_time=end_ns,
            message_index_length=self._pos - chunk_start - chunk_length,
            message_index_offsets=offsets,
            message_start_time=start_ns,
            uncompressed_size=len(raw),
        )
        if self._spool is None:  # closed by release()
            self._spool = tempfile.TemporaryFile(dir=self._spool_dir, prefix=".mcap-chunk-index-")  # noqa: SIM115
        self._spooled += self._spool.write(record_bytes(rec))
        st = self._stats
        st.message_start_time = min(st.message_start_time, start_ns) if st.chunk_count else start_ns
        st.message_end_time = max(st.message_end_time, end_ns)
        st.message_count += sum(len(v) for v in index.values()) // 2
        st.chunk_count += 1
        self._chunk = bytearray()
        self._index = {}
