"""Recover an MCAP file cut by a crash: everything readable, rewritten as a complete file.

A writer killed mid-session leaves a file without summary, indexes or footer, which seeking
readers (``mcap.reader.make_reader``, many viewers) refuse. :func:`recover` reads the file
record by record with the ``mcap`` package's ``StreamReader`` (CRCs checked), stops at the first
record that is cut or corrupt, and writes every schema, channel, message, metadata record and
attachment before that point into a new, complete, indexed file (plus a ``recovered`` metadata
record saying where the cut was). A chunk is all or nothing: a half-written last chunk is lost
whole, which is what the writers' periodic flush bounds (docs/mcap.md).
"""

from __future__ import annotations

import io
import os
from dataclasses import dataclass, field
from pathlib import Path

from mcap.records import Attachment, Channel, Footer, Header, Message, Metadata, Schema
from mcap.writer import CompressionType

from cmm_comp.daemon.sessionlog.mcapfile import MAGIC, McapFileWriter

from .reader import intact_records

RECOVER_LIBRARY = "cmm-comp mcap recover"
RECOVER_CHUNK_SIZE = 1024 * 1024
"""Chunk size of the recovered file, bytes (uncompressed)."""


@dataclass
class RecoverReport:
    """What :func:`recover` read and wrote. Offsets are bytes from the start of the source."""

    source: Path
    output: Path
    size: int
    """Source size, bytes."""
    complete: bool
    """The source had its footer (nothing was cut)."""
    cut_at: int | None
    """Offset of the first record that could not be read (None when complete)."""
    error: str | None
    messages_by_topic: dict[str, int] = field(default_factory=dict)
    schemas: int = 0
    channels: int = 0
    metadata: int = 0
    attachments: int = 0
    orphan_messages: int = 0
    """Messages on a channel never defined before them (skipped)."""

    @property
    def messages(self) -> int:
        """Messages written to the output."""
        return sum(self.messages_by_topic.values())


def recover(
    source: str | os.PathLike[str],
    output: str | os.PathLike[str],
    *,
    overwrite: bool = False,
    compression: CompressionType = CompressionType.ZSTD,
) -> RecoverReport:
    """Rewrite the readable part of ``source`` as a complete MCAP file at ``output``.

    The output is written to a temporary file next to it and renamed at the end, so a failure
    leaves no half-written output. Raises FileExistsError when ``output`` exists (unless
    ``overwrite``), ValueError when ``output`` is ``source`` or ``source`` is not an MCAP file
    (not even its magic bytes readable)."""
    src, dst = Path(source), Path(output)
    if dst.exists() and dst.resolve() == src.resolve():
        raise ValueError(f"{dst}: the output must not be the file being recovered")
    if dst.exists() and not overwrite:
        raise FileExistsError(f"{dst}: exists (pass overwrite / --force to replace it)")
    tmp = dst.with_name(f".{dst.name}.recover-{os.getpid()}.tmp")
    try:
        with open(src, "rb") as f, open(tmp, "wb") as out:
            report = _copy(f, out, src, dst, compression)
        os.replace(tmp, dst)
    finally:
        tmp.unlink(missing_ok=True)
    return report


def _copy(
    f: io.BufferedReader,
    out: io.BufferedWriter,
    src: Path,
    dst: Path,
    compression: CompressionType,
) -> RecoverReport:
    size = os.fstat(f.fileno()).st_size
    if f.read(len(MAGIC)) != MAGIC:
        raise ValueError(f"{src}: not an MCAP file (no MCAP magic at the start)")
    f.seek(0)
    report = RecoverReport(src, dst, size, complete=False, cut_at=None, error=None)
    # every index; the chunk index spooled next to the output: memory stays flat
    writer = McapFileWriter(
        out, chunk_size=RECOVER_CHUNK_SIZE, compression=compression, spool_dir=dst.parent
    )
    try:
        _copy_records(f, writer, size, src, report)
        writer.finish()
    finally:
        writer.release()
    return report


def _copy_records(
    f: io.BufferedReader, writer: McapFileWriter, size: int, src: Path, report: RecoverReport
) -> None:
    started = False
    schema_ids: dict[int, int] = {0: 0}
    channels: dict[int, tuple[int, str]] = {}
    good_end = 0
    cut: list[str] = []
    for record in intact_records(f, cut, record_size_limit=size):
        if not started:
            header = record if isinstance(record, Header) else Header("", "")
            writer.start(profile=header.profile, library=header.library or RECOVER_LIBRARY)
            started = True
        if isinstance(record, Message):
            ch = channels.get(record.channel_id)
            if ch is None:
                report.orphan_messages += 1
            else:
                writer.add_message(
                    ch[0], record.log_time, record.data, record.publish_time, record.sequence
                )
                report.messages_by_topic[ch[1]] = report.messages_by_topic.get(ch[1], 0) + 1
        elif isinstance(record, Schema) and record.id not in schema_ids:
            schema_ids[record.id] = writer.register_schema(
                record.name, record.encoding, record.data
            )
            report.schemas += 1
        elif isinstance(record, Channel) and record.id not in channels:
            new_id = writer.register_channel(
                record.topic,
                record.message_encoding,
                schema_ids.get(record.schema_id, 0),
                dict(record.metadata),
            )
            channels[record.id] = (new_id, record.topic)
            report.channels += 1
        elif isinstance(record, Metadata):
            writer.add_metadata(record.name, dict(record.metadata))
            report.metadata += 1
        elif isinstance(record, Attachment):
            writer.add_attachment(
                record.create_time, record.log_time, record.name, record.media_type, record.data
            )
            report.attachments += 1
        elif isinstance(record, Footer):
            report.complete = True
        good_end = f.tell()
    if cut:
        report.cut_at, report.error = good_end, cut[0]
    if not started:  # cut inside the header: an empty but valid file
        writer.start(profile="", library=RECOVER_LIBRARY)
    report.complete = report.complete and report.error is None
    if not report.complete:
        writer.add_metadata(
            "recovered",
            {
                "source": src.name,
                "source_bytes": str(size),
                "cut_at": str(report.cut_at),
                "error": report.error or "",
            },
        )
