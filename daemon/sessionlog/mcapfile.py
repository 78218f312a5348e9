"""A chunked MCAP writer with every index, built on the format's specification.

:class:`McapFileWriter` writes what the ``mcap`` package's ``Writer`` writes with all indexes
(``IndexType.ALL``, the defaults): the same records in the same order, byte for byte
(``tests/test_mcap_file.py`` compares whole files), with three differences that are why it
exists:

* it depends on the published MCAP format only (:mod:`.mcapwire`), never on a library's private
  attributes (the session log used to reach into ``mcap``'s name-mangled internals to make
  writing cheap: a patch release could have broken it);
* a message costs about what it cost before with message indexes switched off (one packed
  header, two buffer appends, one index entry; docs/mcap.md, "The writer's cost per message"), while
  ``Writer.add_message`` with message indexes costs ~5× more;
* the Chunk Index records wait on disk (:class:`.summary.ChunkIndexSpool`) and the summary is
  streamed from there (:func:`.summary.write_summary`): memory does not grow with the file.

Message Index records are written after every chunk: ``@mcap/core``'s ``McapIndexedReader``
(what Foxglove and Lichtblick use for local files) refuses a chunk index without them.

Layout: Header; then, in call order, Metadata and Attachment records (written at once) and
Chunks (each followed by its Message Index records; Schema and Channel records go into the
chunk in progress and reach the file with its first message); Data End; the summary (schemas,
channels, statistics, chunk indexes, attachment indexes, metadata indexes, summary offsets);
Footer. A chunk is written when its uncompressed records exceed ``chunk_size`` or at
:meth:`McapFileWriter.flush`: a process killed between two flushes loses the chunk in progress
and nothing before it.
"""

from __future__ import annotations

import zlib
from collections.abc import Callable, Mapping
from pathlib import Path
from typing import IO

from mcap.writer import CompressionType

from . import mcapwire
from .mcapwire import MAGIC, MESSAGE_FIXED, MESSAGE_HEAD, Op
from .summary import ChunkIndexSpool, write_summary

_pack_message_head = MESSAGE_HEAD.pack
_OP_MESSAGE = Op.MESSAGE


Compress = Callable[[bytearray], bytes | bytearray]
"""Compresses one chunk's records (a buffer) into the bytes the Chunk record holds."""


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
        return "", _as_is
    raise ValueError(f"compression {compression!r}; allowed: ZSTD, LZ4, NONE")


def _as_is(data: bytearray) -> bytearray:
    return data


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
        self._counts: dict[int, int] = {}
        self._message_count = 0
        self._start_ns = 0
        self._end_ns = 0
        self._chunk_count = 0
        self._attachment_indexes: list[bytes] = []
        self._metadata_indexes: list[bytes] = []
        self._spool = ChunkIndexSpool(spool_dir)
        self._state = "new"

    # ------------------------------------------------------------------ records

    def start(self, profile: str = "", library: str = "") -> None:
        """Write the magic and the Header record."""
        if self._state != "new":
            raise ValueError("MCAP writer already started")
        self._state = "open"
        self._write(MAGIC)
        self._write(mcapwire.header(profile, library))

    def register_schema(self, name: str, encoding: str, data: bytes) -> int:
        """Add a Schema record (to the chunk in progress); returns its id (1, 2, …)."""
        self._check_open()
        schema_id = len(self._schemas) + 1
        self._to_chunk(mcapwire.schema(schema_id, name, encoding, data), self._schemas, schema_id)
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
        rec = mcapwire.channel(channel_id, schema_id, topic, message_encoding, metadata or {})
        self._to_chunk(rec, self._channels, channel_id)
        return channel_id

    def add_message(
        self, channel_id: int, log_time: int, data: bytes, publish_time: int, sequence: int = 0
    ) -> None:
        """Add one Message record to the chunk in progress (times: int ns, uint64); write the
        chunk when it exceeds ``chunk_size``. The hot path of the session log."""
        size = len(data)
        head = _pack_message_head(
            _OP_MESSAGE, MESSAGE_FIXED + size, channel_id, sequence, log_time, publish_time
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
        offset = self._pos
        rec = mcapwire.metadata(name, values)
        self._write(rec)
        self._metadata_indexes.append(mcapwire.metadata_index(offset, len(rec), name))

    def add_attachment(
        self, create_time: int, log_time: int, name: str, media_type: str, data: bytes
    ) -> None:
        """Write an Attachment record now (outside chunks) and index it."""
        self._check_open()
        offset = self._pos
        rec = mcapwire.attachment(log_time, create_time, name, media_type, data)
        self._write(rec)
        self._attachment_indexes.append(
            mcapwire.attachment_index(
                offset, len(rec), log_time, create_time, len(data), name, media_type
            )
        )

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
        self._write(mcapwire.data_end())
        stats = mcapwire.statistics(
            self._message_count,
            len(self._schemas),
            len(self._channels),
            len(self._attachment_indexes),
            len(self._metadata_indexes),
            self._chunk_count,
            self._start_ns,
            self._end_ns,
            self._counts,
        )
        groups = [
            (Op.SCHEMA, self._schemas.values()),
            (Op.CHANNEL, self._channels.values()),
            (Op.STATISTICS, [stats]),
            (Op.CHUNK_INDEX, self._spool.blocks()),
            (Op.ATTACHMENT_INDEX, self._attachment_indexes),
            (Op.METADATA_INDEX, self._metadata_indexes),
        ]
        self._write(write_summary(self._write, self._pos, groups))
        self._write(MAGIC)
        self._stream.flush()

    def release(self) -> None:
        """Delete the chunk index spool (after :meth:`finish`, or when the file is abandoned
        after an error); idempotent. The stream is the caller's to close."""
        self._spool.close()
        if self._state == "open":
            self._state = "abandoned"

    # ------------------------------------------------------------------ counters

    @property
    def message_count(self) -> int:
        """Messages written so far, including those in the chunk in progress."""
        return self._message_count + sum(len(v) for v in self._index.values()) // 2

    @property
    def chunk_count(self) -> int:
        """Chunks written so far."""
        return self._chunk_count

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
        self._write(
            mcapwire.chunk_head(
                start_ns, end_ns, len(raw), zlib.crc32(raw), self._compression, len(data)
            )
        )
        self._write(data)
        chunk_length = self._pos - chunk_start
        index_start = self._pos
        offsets: dict[int, int] = {}
        n = 0
        for channel_id, times_offsets in index.items():
            offsets[channel_id] = self._pos
            self._write(mcapwire.message_index(channel_id, times_offsets))
            k = len(times_offsets) // 2
            self._counts[channel_id] = self._counts.get(channel_id, 0) + k
            n += k
        self._spool.append(
            mcapwire.chunk_index(
                start_ns,
                end_ns,
                chunk_start,
                chunk_length,
                offsets,
                self._pos - index_start,
                self._compression,
                len(data),
                len(raw),
            )
        )
        self._start_ns = start_ns if self._message_count == 0 else min(self._start_ns, start_ns)
        self._end_ns = max(self._end_ns, end_ns)
        self._message_count += n
        self._chunk_count += 1
        self._chunk = bytearray()
        self._index = {}
