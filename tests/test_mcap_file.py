"""The session log's MCAP writer (``mcapfile.McapFileWriter``): the same
bytes as the ``mcap`` library's writer with all indexes, every chunk indexed by message
indexes, memory that does not grow with the number of chunks, nothing left behind.

Oracles: the ``mcap`` library's own ``Writer`` with ``IndexType.ALL`` (its defaults) for whole
files byte by byte; the ``mcap`` seeking reader (summary, chunk indexes, messages) and its
``breakup_chunk`` for what the message indexes must point at; ``tracemalloc`` for the memory
the bookkeeping holds. The official TypeScript reader reads the daemon's files in
``tests/test_mcap_ts.py``.
"""

from __future__ import annotations

import gc
import io
import json
import os
import struct
import tracemalloc
from pathlib import Path
from typing import Any

import pytest
from mcap.reader import make_reader
from mcap.records import Chunk, Message, MessageIndex
from mcap.stream_reader import StreamReader, breakup_chunk
from mcap.writer import CompressionType, Writer

from cmm_comp.cli.sessionlog.recover import recover
from cmm_comp.daemon.sessionlog.mcapfile import McapFileWriter
from cmm_comp.daemon.sessionlog.writer import SessionWriter

WRITER_PY = Path(__file__).resolve().parents[1] / "daemon" / "sessionlog"


def write_file(w: Any, n_messages: int) -> None:
    """A session-like file through ``w`` (either writer, same public calls): two schemas,
    channels with and without metadata (one registered late), metadata, an attachment, a
    flush in the middle, out-of-order log times, publish time ≠ log time, sequences."""
    w.start(profile="", library="test")
    s1 = w.register_schema("a", "jsonschema", b'{"type":"object"}')
    s2 = w.register_schema("b", "jsonschema", b"{}")
    chans = [
        w.register_channel(f"/t{i}", "json", s1 if i else s2, {"k": "v"} if i == 1 else {})
        for i in range(3)
    ]
    w.add_metadata("session", {"k": "v"})
    for i in range(n_messages):
        data = json.dumps({"i": i, "x": i * 0.5, "pad": "x" * (i % 37)}).encode()
        t = 1_000 + 7 * i + (i * 7919) % 41 - 20  # not monotonic
        w.add_message(chans[i % len(chans)], t, data, t + 3, i % 5)
        if i == n_messages // 3:
            chans.append(w.register_channel("/late", "json", 0))
        if i == n_messages // 2:
            w.add_attachment(5, 6, "note.txt", "text/plain", b"hello")
            w.flush()  # a flushed chunk in the middle, as the periodic flush does
    w.add_metadata("session_end", {"written": str(n_messages)})
    w.finish()


def ours(out: Any, spool_dir: Path | None, **kwargs: Any) -> McapFileWriter:
    w = McapFileWriter(out, spool_dir=spool_dir, **kwargs)
    try:
        write_file(w, 3000)
    finally:
        w.release()
    return w


@pytest.mark.parametrize(
    "compression", [CompressionType.ZSTD, CompressionType.LZ4, CompressionType.NONE]
)
@pytest.mark.parametrize("chunk_size", [600, 64 * 1024])
def test_file_is_byte_identical_to_the_mcap_writer_with_all_indexes(
    tmp_path: Path, compression: CompressionType, chunk_size: int
) -> None:
    stock, mine = io.BytesIO(), io.BytesIO()
    write_file(Writer(stock, chunk_size=chunk_size, compression=compression), 3000)
    ours(mine, tmp_path, chunk_size=chunk_size, compression=compression)
    assert mine.getvalue() == stock.getvalue()
    assert list(tmp_path.iterdir()) == []  # the spool is anonymous and gone


def _message_indexes(data: bytes) -> list[tuple[Chunk, list[MessageIndex]]]:
    """Every chunk of the file with the Message Index records that follow it."""
    out: list[tuple[Chunk, list[MessageIndex]]] = []
    for rec in StreamReader(io.BytesIO(data), skip_magic=False, emit_chunks=True).records:
        if isinstance(rec, Chunk):
            out.append((rec, []))
        elif isinstance(rec, MessageIndex):
            out[-1][1].append(rec)
    return out


def test_every_chunk_has_message_indexes_pointing_at_its_messages(tmp_path: Path) -> None:
    """What ``@mcap/core``'s indexed reader needs (it throws on a chunk index without message
    indexes): per chunk, one Message Index per channel in it, whose (log time, offset) pairs
    are exactly the chunk's messages, decoded by the ``mcap`` library."""
    out = io.BytesIO()
    ours(out, tmp_path, chunk_size=600, compression=CompressionType.ZSTD)
    chunks = _message_indexes(out.getvalue())
    assert len(chunks) > 100
    for chunk, indexes in chunks:
        messages = [r for r in breakup_chunk(chunk) if isinstance(r, Message)]
        assert messages, "a chunk is written only with a message in it"
        by_channel = {i.channel_id: i.records for i in indexes}
        assert sorted(by_channel) == sorted({m.channel_id for m in messages})
        for ch, records in by_channel.items():
            assert [t for t, _ in records] == [m.log_time for m in messages if m.channel_id == ch]
        # the offsets point at Message records (opcode 5) in the uncompressed chunk
        raw = _uncompressed(chunk)
        for records in by_channel.values():
            assert all(raw[off] == 0x05 for _, off in records)
    with open(tmp_path / "f.mcap", "wb") as f:
        f.write(out.getvalue())
    with open(tmp_path / "f.mcap", "rb") as f:
        summary = make_reader(f).get_summary()
    assert summary is not None
    assert all(ci.message_index_offsets for ci in summary.chunk_indexes)


def _uncompressed(chunk: Chunk) -> bytes:
    import zstandard

    if chunk.compression == "zstd":
        return zstandard.ZstdDecompressor().decompress(chunk.data)
    assert chunk.compression == ""
    return chunk.data


def test_file_reads_with_the_mcap_reader(tmp_path: Path) -> None:
    path = tmp_path / "s.mcap"
    with open(path, "wb") as f:
        ours(f, tmp_path, chunk_size=600)
    with open(path, "rb") as f:
        reader = make_reader(f)
        summary = reader.get_summary()
        assert summary is not None and summary.statistics is not None
        assert summary.statistics.message_count == 3000
        n_chunks = summary.statistics.chunk_count
        assert n_chunks > 200  # many chunks: the spool was really used
        assert len(summary.chunk_indexes) == n_chunks
        got = sorted(json.loads(m.data)["i"] for _, _, m in reader.iter_messages())
        assert got == list(range(3000))
        times = [m.log_time for _, _, m in reader.iter_messages()]
        assert times == sorted(times)  # log-time order through the indexes
        # a time-window read goes through the chunk and message indexes
        window = [m.log_time for _, _, m in reader.iter_messages(starting_at=8_000)]
        assert min(window) >= 8_000 and len(window) == sum(t >= 8_000 for t in times)
        assert [m.name for m in reader.iter_metadata()] == ["session", "session_end"]
        assert [a.name for a in reader.iter_attachments()] == ["note.txt"]


def test_bad_calls_raise_and_leave_the_file_writable(tmp_path: Path) -> None:
    out = io.BytesIO()
    w = McapFileWriter(out, spool_dir=tmp_path, chunk_size=100)
    with pytest.raises(ValueError, match="start"):
        w.add_metadata("early", {})
    w.start()
    ch = w.register_channel("/a", "json", 0)
    with pytest.raises(ValueError, match="schema id 3"):
        w.register_channel("/b", "json", 3)
    with pytest.raises(ValueError, match="channel id 9"):
        w.add_message(9, 1, b"{}", 1)
    with pytest.raises(struct.error):
        w.add_message(ch, -1, b"{}", 1)  # not a uint64: refused before anything changed
    w.add_message(ch, 5, b"{}", 5)
    w.finish()
    w.release()
    with pytest.raises(ValueError, match="finished"):
        w.add_message(ch, 6, b"{}", 6)
    reader = make_reader(io.BytesIO(out.getvalue()))
    assert [m.log_time for _, _, m in reader.iter_messages()] == [5]


def _held_bytes(n_messages: int, tmp_path: Path) -> int:
    """Python memory held by the writer after ``n_messages`` messages (chunks cut every
    ~600 bytes), before finishing."""
    out = io.BytesIO()
    w = McapFileWriter(out, chunk_size=600, compression=CompressionType.NONE, spool_dir=tmp_path)
    w.start()
    ch = w.register_channel("/t", "json", 0)
    gc.collect()
    tracemalloc.start()
    try:
        base = tracemalloc.get_traced_memory()[0]
        for i in range(n_messages):
            w.add_message(ch, i, b"x" * 100, i)
            if i % 1000 == 0:
                out.seek(0)
                out.truncate()  # the file's bytes are not the bookkeeping under test
        gc.collect()
        held = tracemalloc.get_traced_memory()[0] - base
    finally:
        tracemalloc.stop()
        w.release()
    return held


def test_writer_bookkeeping_does_not_grow_with_chunks(tmp_path: Path) -> None:
    # ~5 messages a chunk: 1000 → ~200 chunks, 11000 → ~2200 chunks. The mcap writer's list
    # holds ~0.8 KiB a chunk (~1.6 MB for the difference); the spool holds nothing per chunk.
    small = _held_bytes(1_000, tmp_path)
    large = _held_bytes(11_000, tmp_path)
    assert large - small < 16_000, (small, large)


def test_finishing_a_long_file_does_not_build_the_summary_in_memory(tmp_path: Path) -> None:
    path = tmp_path / "long.mcap"
    with open(path, "wb") as f:
        w = McapFileWriter(f, chunk_size=300, compression=CompressionType.NONE, spool_dir=tmp_path)
        w.start()
        ch = w.register_channel("/t", "json", 0)
        for i in range(20_000):
            w.add_message(ch, i, b"y" * 100, i)
        chunks = w.chunk_count
        assert chunks > 5000
        gc.collect()
        tracemalloc.start()
        try:
            w.finish()
            peak = tracemalloc.get_traced_memory()[1]
        finally:
            tracemalloc.stop()
            w.release()
    summary_bytes = chunks * 80  # a Chunk Index record with one message index offset: ~80 B
    assert summary_bytes > 400_000
    assert peak < 200_000, (peak, summary_bytes)
    with open(path, "rb") as f:
        summary = make_reader(f).get_summary()
    assert summary is not None and len(summary.chunk_indexes) == w.chunk_count >= chunks


def test_logger_single_file_with_many_chunks_reads_and_recovers(tmp_path: Path) -> None:
    """The session logger end to end: a file that never rolls, hundreds of chunks (small
    chunk size), read by the mcap seeking reader; the same file cut in the middle is
    recovered by ``recover`` with every chunk before the cut."""
    path = tmp_path / "one.mcap"
    frame = (0x181, False, 8, bytes(range(8)), 1_700_000_000.5, "vcan0", False, False, False)
    with SessionWriter(path, chunk_size=2048) as lg:
        for _ in range(12000):
            assert lg.log("/cmm/can_rx", frame)
        assert lg.stop(60.0)
    assert [p.name for p in tmp_path.iterdir()] == ["one.mcap"]  # no spool left behind
    with open(path, "rb") as f:
        reader = make_reader(f)
        summary = reader.get_summary()
        assert summary is not None and summary.statistics is not None
        assert len(summary.chunk_indexes) == summary.statistics.chunk_count > 100
        assert all(ci.message_index_offsets for ci in summary.chunk_indexes)
        topics = [c.topic for _, c, _ in reader.iter_messages(topics=["/cmm/can_rx"])]
        assert len(topics) == 12000
    data = path.read_bytes()
    cut = tmp_path / "cut.mcap"
    cut.write_bytes(data[: len(data) // 2])
    report = recover(cut, tmp_path / "fixed.mcap")
    assert not report.complete
    with open(tmp_path / "fixed.mcap", "rb") as f:
        reader = make_reader(f)
        n = sum(1 for _ in reader.iter_messages(topics=["/cmm/can_rx"]))
        summary = reader.get_summary()
    assert summary is not None and len(summary.chunk_indexes) >= 2  # 1 MiB chunks
    assert n == report.messages_by_topic["/cmm/can_rx"] > 1000
    assert sorted(os.listdir(tmp_path)) == ["cut.mcap", "fixed.mcap", "one.mcap"]


def test_no_private_attribute_of_the_mcap_writer_is_used() -> None:
    """The writer depends on the MCAP format, not on ``mcap``'s internals (name-mangled
    ``_Writer__*`` attributes may change in any release)."""
    for path in WRITER_PY.glob("*.py"):
        assert "_Writer__" not in path.read_text(), path
