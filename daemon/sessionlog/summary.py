"""The summary section of a long MCAP file without memory that grows with the file.

A session file that never rolls (an explicit ``*.mcap`` path) at 1 kHz cuts ~8 chunks a
second: ~29k Chunk Index records an hour, ~700k a day. Kept in a list until the file is
finished (what the ``mcap`` package's writer does), they grew the writer's memory for as long
as the daemon ran, and the summary (~60 MB a day) was built in memory at once.

Here the Chunk Index records go to disk instead: :class:`ChunkIndexSpool` writes each one, as
the summary holds it, to an anonymous temporary file next to the log (``O_TMPFILE``: nothing is
left behind by a crash, and the entries are in the log's chunks anyway: ``cmm-comp mcap
recover`` rebuilds them). :func:`write_summary` then writes the summary section group by group,
streaming the spooled records into it, so finishing a file of any length needs a few KiB.
"""

from __future__ import annotations

import io
import tempfile
import zlib
from collections.abc import Callable, Iterable, Iterator, Sequence
from pathlib import Path
from typing import IO

from . import mcapwire

COPY_BLOCK = 64 * 1024
"""Bytes read from the spool at a time when it is copied into the summary."""


class ChunkIndexSpool:
    """Chunk Index records kept on disk, in order, in an anonymous temporary file in
    ``directory`` (created at the first record). Memory stays constant whatever the number of
    chunks. :meth:`close` deletes the file (idempotent)."""

    def __init__(self, directory: str | Path | None = None) -> None:
        self._dir = None if directory is None else str(directory)
        self._file: IO[bytes] | None = None
        self._n = 0
        self._bytes = 0
        self._closed = False

    def append(self, record: bytes) -> None:
        """Add one Chunk Index record (its bytes, as the summary holds them)."""
        if self._closed:
            raise ValueError("chunk index spool is closed")
        if self._file is None:
            # closed by close() (the owner's finish, or its error path)
            self._file = tempfile.TemporaryFile(  # noqa: SIM115
                dir=self._dir, prefix=".mcap-chunk-index-"
            )
        self._file.write(record)
        self._n += 1
        self._bytes += len(record)

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

    def close(self) -> None:
        """Delete the spool file (the records are gone: call after the file is finished)."""
        self._closed = True
        if self._file is not None:
            f, self._file = self._file, None
            f.close()


SummaryGroup = tuple[int, Iterable[bytes]]
"""``(opcode of the group's records, the records as bytes blocks)``."""


def write_summary(
    write: Callable[[bytes], object], summary_start: int, groups: Sequence[SummaryGroup]
) -> bytes:
    """Write the summary section starting at file offset ``summary_start`` through ``write``:
    each group's records, one Summary Offset record per group (also for an empty group, as the
    ``mcap`` package's writer does), and return the Footer record (its summary CRC covers the
    whole summary section and the footer's offsets, per the spec). Holds one block at a time."""
    written = 0
    crc = 0
    offsets: list[bytes] = []

    def emit(data: bytes) -> None:
        nonlocal written, crc
        if data:
            write(data)
            written += len(data)
            crc = zlib.crc32(data, crc)

    for opcode, blocks in groups:
        start = written
        for block in blocks:
            emit(block)
        offsets.append(mcapwire.summary_offset(opcode, summary_start + start, written - start))
    summary_offset_start = summary_start + written
    emit(b"".join(offsets))
    head = mcapwire.FOOTER_HEAD.pack(mcapwire.Op.FOOTER, 20, summary_start, summary_offset_start)
    return mcapwire.footer(summary_start, summary_offset_start, zlib.crc32(head, crc))
