"""The summary section of a long MCAP file without memory that grows with the file.

The ``mcap`` writer keeps one :class:`~mcap.records.ChunkIndex` per chunk in a list until
``finish()``, then builds the whole summary section in memory. A session file that never rolls
(an explicit ``*.mcap`` path) at 1 kHz cuts ~8 chunks a second: ~29k entries an hour, which
grew the writer's memory for as long as the daemon ran (a day: ~700k entries, and a summary of
~60 MB built at once when the file is finished).

Here the chunk index goes to disk instead: :class:`ChunkIndexSpool` replaces the writer's list
and writes each entry, serialised exactly as the summary holds it (a Chunk Index record), to an
anonymous temporary file next to the log (``O_TMPFILE``: nothing is left behind by a crash,
and the entries are in the log's chunks anyway: ``cmm-comp mcap recover`` rebuilds them).
:func:`finish_writer` then writes the summary section group by group, streaming the spooled
records into it, so finishing a file of any length needs a few KiB. The file is byte-identical
to what ``Writer.finish()`` writes from its list (``tests/test_mcap_summary.py`` compares whole
files against the stock ``mcap`` writer). Both rely on the ``mcap`` writer's internals (1.6,
pinned in pyproject.toml); with another layout :func:`spool_chunk_index` changes nothing and
:func:`finish_writer` calls ``Writer.finish()``.
"""

from __future__ import annotations

import io
import struct
import tempfile
import zlib
from collections.abc import Iterator
from pathlib import Path
from typing import IO, Any

from mcap.data_stream import ReadDataStream, RecordBuilder
from mcap.opcode import Opcode
from mcap.records import ChunkIndex, DataEnd, Footer, SummaryOffset
from mcap.writer import MCAP0_MAGIC, IndexType, Writer

_CHUNK_INDEXES = "_Writer__chunk_indices"
_DATA_CRC = "_Writer__data_section_crc"  # read after the last chunk is finalized
_RECORD_HEAD = struct.Struct("<BQ")
"""Opcode and length of an MCAP record."""
COPY_BLOCK = 64 * 1024
"""Bytes read from the spool at a time when it is copied into the summary."""


class ChunkIndexSpool:
    """A chunk index kept on disk: what the ``mcap`` writer does with its list (``append``,
    iterate, ``len``), with the entries written as Chunk Index records to an anonymous
    temporary file in ``directory`` (created at the first entry). Memory stays constant
    whatever the number of chunks. :meth:`close` deletes the file (idempotent)."""

    def __init__(self, directory: str | Path | None = None) -> None:
        self._dir = None if directory is None else str(directory)
        self._file: IO[bytes] | None = None
        self._n = 0
        self._bytes = 0
        self._closed = False

    def append(self, index: ChunkIndex) -> None:
        """Write ``index`` as its Chunk Index record (byte-identical to the summary's)."""
        if self._closed:
            raise ValueError("chunk index spool is closed")
        rb = RecordBuilder()
        index.write(rb)
        data = rb.end()
        if self._file is None:
            # closed by close() (the owner's finish, or its error path)
            self._file = tempfile.TemporaryFile(  # noqa: SIM115
                dir=self._dir, prefix=".mcap-chunk-index-"
            )
        self._file.write(data)
        self._n += 1
        self._bytes += len(data)

    def __len__(self) -> int:
        return self._n

    @property
    def nbytes(self) -> int:
        """Bytes of Chunk Index records spooled (the summary group's length)."""
        return self._bytes

    def blocks(self, size: int = COPY_BLOCK) -> Iterator[bytes]:
        """The spooled records as bytes, in blocks of at most ``size``, in order. Appending
        while a block iteration runs is not supported."""
        if self._file is None:
            return
        f = self._file
        f.flush()
        f.seek(0)
        try:
            left = self._bytes
            while left > 0:
                block = f.read(min(size, left))
                if not block:
                    raise OSError(f"chunk index spool is short by {left} bytes")
                left -= len(block)
                yield block
        finally:
            f.seek(0, io.SEEK_END)

    def __iter__(self) -> Iterator[ChunkIndex]:
        """The entries as :class:`ChunkIndex` objects (for ``Writer.finish()``)."""
        pending = b""
        for block in self.blocks():
            pending += block
            pos = 0
            while len(pending) - pos >= _RECORD_HEAD.size:
                opcode, length = _RECORD_HEAD.unpack_from(pending, pos)
                end = pos + _RECORD_HEAD.size + length
                if end > len(pending):
                    break
                if opcode != Opcode.CHUNK_INDEX:
                    raise OSError(f"chunk index spool holds opcode {opcode:#x}")
                body = pending[pos + _RECORD_HEAD.size : end]
                yield ChunkIndex.read(ReadDataStream(io.BytesIO(body)))
                pos = end
            pending = pending[pos:]
        if pending:
            raise OSError(f"chunk index spool ends inside a record ({len(pending)} bytes)")

    def close(self) -> None:
        """Delete the spool file (the entries are gone: call after the file is finished)."""
        self._closed = True
        if self._file is not None:
            f, self._file = self._file, None
            f.close()


def spool_chunk_index(writer: Writer, directory: str | Path | None = None) -> bool:
    """Give ``writer`` (before its first chunk) a :class:`ChunkIndexSpool` in ``directory``;
    False (and nothing changed) if this ``mcap`` version keeps its chunk index differently."""
    current = getattr(writer, _CHUNK_INDEXES, None)
    if not isinstance(current, list) or current:
        return False
    setattr(writer, _CHUNK_INDEXES, ChunkIndexSpool(directory))
    return True


def close_spool(writer: Writer) -> None:
    """Delete ``writer``'s chunk index spool file, if it has one (after finishing, or when
    the file is abandoned after an error)."""
    spool = getattr(writer, _CHUNK_INDEXES, None)
    if isinstance(spool, ChunkIndexSpool):
        spool.close()


_INTERNALS = (
    "stream",
    "record_builder",
    "schemas",
    "channels",
    "statistics",
    "chunk_indices",
    "attachment_indexes",
    "metadata_indexes",
    "index_types",
    "repeat_schemas",
    "repeat_channels",
    "use_statistics",
    "use_summary_offsets",
    "enable_crcs",
    "data_section_crc",
    "should_close",
)


def _internals(writer: Writer) -> dict[str, Any] | None:
    out: dict[str, Any] = {}
    for name in _INTERNALS:
        value = getattr(writer, f"_Writer__{name}", _INTERNALS)
        if value is _INTERNALS:
            return None
        out[name] = value
    for name in ("finalize_chunk", "flush"):
        method = getattr(writer, f"_Writer__{name}", None)
        if not callable(method):
            return None
        out[name] = method
    return out


def finish_writer(writer: Writer) -> None:
    """``writer.finish()`` writing the summary section group by group (the chunk index group
    streamed from a :class:`ChunkIndexSpool`) instead of building it in memory; the same bytes
    as ``Writer.finish()`` (``mcap`` 1.6), which is called instead with another layout."""
    w = _internals(writer)
    if w is None:
        writer.finish()
        return
    w["finalize_chunk"]()
    DataEnd(getattr(writer, _DATA_CRC)).write(w["record_builder"])
    w["flush"]()
    stream = w["stream"]
    summary_start = stream.tell()
    crcs = bool(w["enable_crcs"])
    written = 0
    crc = 0
    offsets: list[SummaryOffset] = []

    def emit(data: bytes) -> None:
        nonlocal written, crc
        if data:
            stream.write(data)
            written += len(data)
            if crcs:
                crc = zlib.crc32(data, crc)

    def encoded(records: Any) -> list[bytes]:
        rb = RecordBuilder()
        for record in records:
            record.write(rb)
        return [rb.end()]

    def group(opcode: int, blocks: Any) -> None:
        """One summary group from its encoded blocks, and its offset record."""
        start = written
        for block in blocks:
            emit(block)
        offsets.append(
            SummaryOffset(
                group_opcode=opcode,
                group_start=summary_start + start,
                group_length=written - start,
            )
        )

    index_types = w["index_types"]
    if w["repeat_schemas"]:
        group(Opcode.SCHEMA, encoded(w["schemas"].values()))
    if w["repeat_channels"]:
        group(Opcode.CHANNEL, encoded(w["channels"].values()))
    if w["use_statistics"]:
        group(Opcode.STATISTICS, encoded([w["statistics"]]))
    if index_types & IndexType.CHUNK:
        chunk_indices = w["chunk_indices"]
        spooled = isinstance(chunk_indices, ChunkIndexSpool)
        group(Opcode.CHUNK_INDEX, chunk_indices.blocks() if spooled else encoded(chunk_indices))
    if index_types & IndexType.ATTACHMENT:
        group(Opcode.ATTACHMENT_INDEX, encoded(w["attachment_indexes"]))
    if index_types & IndexType.METADATA:
        group(Opcode.METADATA_INDEX, encoded(w["metadata_indexes"]))
    summary_offset_start = summary_start + written if w["use_summary_offsets"] else 0
    if w["use_summary_offsets"]:
        emit(encoded(offsets)[0])
    summary_crc = 0
    if crcs:
        footer_head = struct.pack(
            "<BQQQ",
            Opcode.FOOTER,
            8 + 8 + 4,
            0 if written == 0 else summary_start,
            summary_offset_start,
        )
        summary_crc = zlib.crc32(footer_head, crc)
    Footer(
        summary_start=0 if written == 0 else summary_start,
        summary_offset_start=summary_offset_start,
        summary_crc=summary_crc,
    ).write(w["record_builder"])
    w["flush"]()
    stream.write(MCAP0_MAGIC)
    if w["should_close"]:
        stream.close()
