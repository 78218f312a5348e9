"""The chunk index spooled to disk and the streamed summary: same bytes as the ``mcap`` writer,
memory that does not grow with the number of chunks, and nothing left behind.

Oracles: the ``mcap`` library's own ``Writer`` (list of chunk indexes, ``finish()``) for whole
files byte by byte; the ``mcap`` seeking reader (summary, chunk indexes, messages) for what a
viewer reads; ``tracemalloc`` for the memory the bookkeeping holds.
"""

from __future__ import annotations

import gc
import io
import json
import os
import tracemalloc
from pathlib import Path

import pytest
from mcap.reader import make_reader
from mcap.records import ChunkIndex
from mcap.writer import CompressionType, IndexType, Writer

from cmm_comp.daemon.sessionlog.recover import recover
from cmm_comp.daemon.sessionlog.summary import (
    ChunkIndexSpool,
    close_spool,
    finish_writer,
    spool_chunk_index,
)
from cmm_comp.daemon.sessionlog.thread_writer import McapLogger
from cmm_comp.daemon.sessionlog.writer import INDEX_TYPES


def write_file(
    out: io.BytesIO | io.BufferedWriter,
    n_messages: int,
    *,
    spooled: bool,
    compression: CompressionType = CompressionType.ZSTD,
    index_types: IndexType = INDEX_TYPES,
    chunk_size: int = 600,
    spool_dir: Path | None = None,
) -> Writer:
    """A small session-like file: two schemas, three channels, metadata, an attachment,
    ``n_messages`` messages across many chunks; finished the stock way or the spooled way."""
    w = Writer(out, chunk_size=chunk_size, compression=compression, index_types=index_types)
    if spooled:
        assert spool_chunk_index(w, spool_dir)
    w.start(profile="", library="test")
    s1 = w.register_schema("a", "jsonschema", b'{"type":"object"}')
    s2 = w.register_schema("b", "jsonschema", b"{}")
    chans = [w.register_channel(f"/t{i}", "json", s1 if i else s2) for i in range(3)]
    w.add_metadata("session", {"k": "v"})
    for i in range(n_messages):
        data = json.dumps({"i": i, "x": i * 0.5, "pad": "x" * (i % 37)}).encode()
        w.add_message(chans[i % 3], 1_000 + 7 * i, data, 1_000 + 7 * i)
        if i == n_messages // 2:
            w.add_attachment(5, 6, "note.txt", "text/plain", b"hello")
            w.flush()  # a flushed chunk in the middle, as the periodic flush does
    w.add_metadata("session_end", {"written": str(n_messages)})
    if spooled:
        try:
            finish_writer(w)
        finally:
            close_spool(w)
    else:
        w.finish()
    return w


@pytest.mark.parametrize(
    ("compression", "index_types"),
    [
        (CompressionType.ZSTD, INDEX_TYPES),
        (CompressionType.LZ4, INDEX_TYPES),
        (CompressionType.NONE, INDEX_TYPES),
        (CompressionType.ZSTD, IndexType.ALL),  # with message indexes (recover's layout)
        (CompressionType.ZSTD, IndexType.NONE),  # no indexes at all
    ],
)
def test_spooled_file_is_byte_identical_to_the_mcap_writer(
    tmp_path: Path, compression: CompressionType, index_types: IndexType
) -> None:
    stock, spooled = io.BytesIO(), io.BytesIO()
    write_file(stock, 3000, spooled=False, compression=compression, index_types=index_types)
    write_file(
        spooled,
        3000,
        spooled=True,
        compression=compression,
        index_types=index_types,
        spool_dir=tmp_path,
    )
    assert spooled.getvalue() == stock.getvalue()
    assert list(tmp_path.iterdir()) == []  # the spool is anonymous and gone


def test_spooled_file_reads_with_the_mcap_reader(tmp_path: Path) -> None:
    path = tmp_path / "s.mcap"
    with open(path, "wb") as f:
        write_file(f, 4000, spooled=True, spool_dir=tmp_path)
    with open(path, "rb") as f:
        reader = make_reader(f)
        summary = reader.get_summary()
        assert summary is not None and summary.statistics is not None
        assert summary.statistics.message_count == 4000
        n_chunks = summary.statistics.chunk_count
        assert n_chunks > 200  # many chunks: the spool was really used
        assert len(summary.chunk_indexes) == n_chunks
        offsets = [c.chunk_start_offset for c in summary.chunk_indexes]
        assert offsets == sorted(offsets) and len(set(offsets)) == n_chunks
        got = [json.loads(m.data)["i"] for _, _, m in reader.iter_messages()]
        assert got == list(range(4000))
        # a time-window read goes through the chunk index
        window = [m.log_time for _, _, m in reader.iter_messages(starting_at=1_000 + 7 * 1000)]
        assert window[0] == 1_000 + 7 * 1000 and len(window) == 3000
        assert [m.name for m in reader.iter_metadata()] == ["session", "session_end"]
        assert [a.name for a in reader.iter_attachments()] == ["note.txt"]


def test_spool_round_trips_chunk_index_objects(tmp_path: Path) -> None:
    entries = [
        ChunkIndex(
            message_start_time=i,
            message_end_time=2**64 - 1 - i,
            chunk_start_offset=100 * i,
            chunk_length=99 + i,
            message_index_offsets={1: 7 * i, 9: 8 * i} if i % 3 else {},
            message_index_length=i,
            compression=("", "zstd", "lz4", "brotli")[i % 4],
            compressed_size=i * 3,
            uncompressed_size=i * 5,
        )
        for i in range(2500)
    ]
    spool = ChunkIndexSpool(tmp_path)
    try:
        for e in entries:
            spool.append(e)
        assert len(spool) == len(entries)
        assert list(spool) == entries
        assert list(spool) == entries  # again: iteration leaves the spool appendable
        spool.append(entries[0])
        assert len(list(spool)) == len(entries) + 1
        assert sum(len(b) for b in spool.blocks(1000)) == spool.nbytes
    finally:
        spool.close()
    spool.close()  # idempotent
    with pytest.raises(ValueError, match="closed"):
        spool.append(entries[0])


def _held_bytes(n_messages: int, tmp_path: Path) -> int:
    """Python memory held by a spooled writer after ``n_messages`` messages (chunks cut every
    ~600 bytes), before finishing."""
    out = io.BytesIO()
    w = Writer(out, chunk_size=600, compression=CompressionType.NONE, index_types=INDEX_TYPES)
    spool_chunk_index(w, tmp_path)
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
        close_spool(w)
    return held


def test_writer_bookkeeping_does_not_grow_with_chunks(tmp_path: Path) -> None:
    # ~5 messages a chunk: 1000 → ~200 chunks, 11000 → ~2200 chunks. The mcap writer's list
    # holds ~0.8 KiB a chunk (~1.6 MB for the difference), the packed store it replaced 57
    # bytes (~110 kB); the spool holds nothing per chunk.
    small = _held_bytes(1_000, tmp_path)
    large = _held_bytes(11_000, tmp_path)
    assert large - small < 16_000, (small, large)


def test_finishing_a_long_file_does_not_build_the_summary_in_memory(tmp_path: Path) -> None:
    path = tmp_path / "long.mcap"
    with open(path, "wb") as f:
        w = Writer(f, chunk_size=300, compression=CompressionType.NONE, index_types=INDEX_TYPES)
        spool_chunk_index(w, tmp_path)
        w.start()
        ch = w.register_channel("/t", "json", 0)
        for i in range(20_000):
            w.add_message(ch, i, b"y" * 100, i)
        spool = vars(w)["_Writer__chunk_indices"]
        assert isinstance(spool, ChunkIndexSpool) and len(spool) > 5000
        summary_bytes = spool.nbytes  # what Writer.finish() would build in one buffer
        gc.collect()
        tracemalloc.start()
        try:
            finish_writer(w)
            peak = tracemalloc.get_traced_memory()[1]
        finally:
            tracemalloc.stop()
            close_spool(w)
    assert summary_bytes > 400_000
    assert peak < 200_000, (peak, summary_bytes)
    with open(path, "rb") as f:
        summary = make_reader(f).get_summary()
    assert summary is not None and len(summary.chunk_indexes) == len(spool)


def test_logger_single_file_with_many_chunks_reads_and_recovers(tmp_path: Path) -> None:
    """The session logger end to end: a file that never rolls, hundreds of chunks (small
    chunk size), read by the mcap seeking reader; the same file cut in the middle is
    recovered by ``recover`` with every chunk before the cut."""
    path = tmp_path / "one.mcap"
    frame = (0x181, False, 8, bytes(range(8)), 1_700_000_000.5, "vcan0", False, False, False)
    with McapLogger(path, chunk_size=2048) as lg:
        for _ in range(6000):
            assert lg.log("/cmm/can_rx", frame)
        assert lg.stop(60.0)
    assert [p.name for p in tmp_path.iterdir()] == ["one.mcap"]  # no spool left behind
    with open(path, "rb") as f:
        reader = make_reader(f)
        summary = reader.get_summary()
        assert summary is not None and summary.statistics is not None
        assert len(summary.chunk_indexes) == summary.statistics.chunk_count > 100
        topics = [c.topic for _, c, _ in reader.iter_messages(topics=["/cmm/can_rx"])]
        assert len(topics) == 6000
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
