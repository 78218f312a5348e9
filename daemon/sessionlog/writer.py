"""Writing one MCAP session file: naming, opening (schemas, channels, ``session`` metadata),
finishing (``session_end`` metadata, summary, indexes). The file is written by
:class:`.mcapfile.McapFileWriter` with every index (message, chunk, attachment, metadata).

Pure file work, no threads: :class:`~.thread_writer.McapLogger` drives it (in the daemon's
process, or in the child of :class:`~.process_writer.McapProcessLogger`).
"""

from __future__ import annotations

import io
import os
import re
from collections.abc import Callable, Mapping
from pathlib import Path
from typing import IO, Any

from mcap.writer import CompressionType

from .mcapfile import McapFileWriter
from .schemas import MESSAGE_ENCODING, SCHEMA_ENCODING, TopicSchema

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
