"""MCAP session log: the writer's cost per message, this tree against a base revision, same run.

Run: ``.venv/bin/python benchmarks/bench_mcap_writer.py [--base main] [--rounds 7] [--n 90000]``.
Prints a table and writes ``benchmarks/results/mcap_writer.json``.

The base revision's ``daemon/`` package is taken with ``git archive BASE daemon`` into a
temporary directory and imported under another name, so both writers run in this process,
interleaved round by round (base, this tree, base, …) on a shared machine; the figures are
medians of per-round ratios (this tree / base), absolute µs only for orientation.

Two levels, both with the daemon's message mix (per reading: 3 received frames, 4 sent frames,
the reading and its answer; zstd, 256 KiB chunks, a flush every 9,000 messages like the 1 s
flush at 1 kHz readings), written to a real file:

* **file writer**: the same pre-encoded JSON messages through the MCAP layer alone (base:
  ``mcap.Writer`` without message indexes driven through its private attributes, this tree:
  ``McapFileWriter`` with every index), time from the first message to the finished file;
  optionally foxglove-sdk's MCAP writer (``--foxglove``, Rust, all indexes) for comparison;
* **thread logger**: ``SessionWriter`` end to end (JSON encoding of the compact records and the
  MCAP file), wall time from the first ``log()`` to the finished file and the process's CPU
  time, per message. Each revision gets the records in the layout it logs (frames with their
  ``direction`` here, when the base has none); this tree also gets the base's layout (no
  ``direction``: the same JSON), which isolates the writer from the longer frame JSON.

File sizes per message are reported too (message indexes add 16 bytes a message, uncompressed).
"""

from __future__ import annotations

import argparse
import importlib
import io
import json
import os
import platform
import statistics
import subprocess
import sys
import tarfile
import tempfile
import time
import typing
from pathlib import Path
from types import ModuleType
from typing import Any

from mcap.writer import CompressionType

ROOT = Path(__file__).resolve().parents[1]
RESULTS = ROOT / "benchmarks" / "results" / "mcap_writer.json"
CHUNK_SIZE = 256 * 1024
FLUSH_EVERY = 9_000
"""Messages between two flushes (the daemon flushes every 1 s: ~9,000 messages at 1 kHz)."""
BASE_NAME = "base_daemon"


def import_base(ref: str, into: Path) -> ModuleType:
    """``daemon/`` of git revision ``ref``, importable as :data:`BASE_NAME`."""
    tar = subprocess.run(
        ["git", "-C", str(ROOT), "archive", ref, "daemon"], check=True, capture_output=True
    ).stdout
    with tarfile.open(fileobj=io.BytesIO(tar)) as t:
        t.extractall(into, filter="data")
    (into / "daemon").rename(into / BASE_NAME)
    sys.path.insert(0, str(into))
    return importlib.import_module(BASE_NAME)


def records(frame_fields: int, n_readings: int) -> list[tuple[str, tuple[Any, ...]]]:
    """The daemon's mix as compact records: per reading 3 received frames, 4 sent frames
    (``frame_fields``: 9 before the direction field, 10 with it), the reading, the answer."""
    out: list[tuple[str, tuple[Any, ...]]] = []
    ts = 1_750_000_000.0
    for i in range(n_readings):
        t = ts + i * 1e-3
        for axis in range(3):
            frame = (0x200 + axis, False, 8, (i * 977 + axis).to_bytes(8, "little"), t, "can0")
            frame += (False, False, False)
            out.append(("/cmm/can_rx", frame + (("rx",) if frame_fields == 10 else ())))
        for kind in (8, 9, 10, 11):
            frame = (0x200 + kind, False, 8, (i * 131 + kind).to_bytes(8, "little"), t, "can0")
            frame += (False, False, False)
            out.append(("/cmm/can_tx", frame + (("tx",) if frame_fields == 10 else ())))
        x, y, z = 100.0 + i * 1e-3, 500.25, 200.125
        out.append(
            ("/cmm/raw", (i, x, y, z, (1, 0, 0), (True,) * 3, "can", (0.0, 0.0, -120.0), None))
        )
        nm = (int(x * 1e6) + 1234, int(y * 1e6) - 77, int(z * 1e6) + 5)
        out.append(
            (
                "/cmm/corrected",
                (i, *nm, "ok", (1.234, -0.077, 0.005), 85.5, 1, "can", "", (0.8, 0.9, 1.1)),
            )
        )
    return out


def encoded(mix: list[tuple[str, tuple[Any, ...]]]) -> list[tuple[str, int, bytes]]:
    """The mix as (topic, log time, JSON bytes), encoded as this tree's writer does."""
    from cmm_comp.daemon.sessionlog.encoding import encode_message

    t0 = 1_750_000_000_000_000_000
    return [
        (topic, t0 + k * 111_111, encode_message(topic, rec, t0 + k * 111_111))
        for k, (topic, rec) in enumerate(mix)
    ]


def _open(path: Path) -> Any:
    return io.BufferedWriter(io.FileIO(path, "xb"))


def _channels(w: Any, topics: list[str]) -> dict[str, int]:
    sid = w.register_schema("s", "jsonschema", b"{}")
    return {t: w.register_channel(t, "json", sid) for t in topics}


Timing = tuple[float, float]
"""(wall s, CPU s of the calling thread)."""


def _clock() -> Timing:
    return time.perf_counter(), time.thread_time()


def _since(t0: Timing) -> Timing:
    return time.perf_counter() - t0[0], time.thread_time() - t0[1]


def file_base(base: ModuleType, path: Path, msgs: list[tuple[str, int, bytes]]) -> Timing:
    """The base revision's MCAP layer (mcap.Writer, its private-attribute fast path)."""
    from mcap.writer import Writer

    wmod = importlib.import_module(f"{BASE_NAME}.sessionlog.writer")
    smod = importlib.import_module(f"{BASE_NAME}.sessionlog.summary")
    with _open(path) as f:
        t0 = _clock()
        w = Writer(f, chunk_size=CHUNK_SIZE, compression=CompressionType.ZSTD,
                   index_types=wmod.INDEX_TYPES)  # fmt: skip
        smod.spool_chunk_index(w, path.parent)
        w.start(profile="", library="bench")
        ch = _channels(w, sorted({m[0] for m in msgs}))
        append = wmod.MessageAppender(w)
        assert append._fast
        for k, (topic, t, data) in enumerate(msgs):
            append(ch[topic], t, data)
            if k % FLUSH_EVERY == FLUSH_EVERY - 1:
                w.flush()
        smod.finish_writer(w)
        smod.close_spool(w)
        f.flush()
        return _since(t0)


def file_new(path: Path, msgs: list[tuple[str, int, bytes]]) -> Timing:
    """This tree's McapFileWriter (every index)."""
    from cmm_comp.daemon.sessionlog.mcapfile import McapFileWriter

    with _open(path) as f:
        t0 = _clock()
        w = McapFileWriter(
            f, chunk_size=CHUNK_SIZE, compression=CompressionType.ZSTD, spool_dir=path.parent
        )
        w.start(profile="", library="bench")
        ch = _channels(w, sorted({m[0] for m in msgs}))
        add = w.add_message
        for k, (topic, t, data) in enumerate(msgs):
            add(ch[topic], t, data, t)
            if k % FLUSH_EVERY == FLUSH_EVERY - 1:
                w.flush()
        w.finish()
        w.release()
        return _since(t0)


def file_foxglove(path: Path, msgs: list[tuple[str, int, bytes]]) -> Timing:
    """foxglove-sdk's MCAP writer (Rust; all indexes; compression on the calling thread)."""
    import foxglove
    from foxglove.mcap import MCAPCompression, MCAPWriteOptions

    ctx = foxglove.Context()
    opts = MCAPWriteOptions(
        compression=MCAPCompression.Zstd, chunk_size=CHUNK_SIZE, compression_threads=0
    )
    t0 = _clock()
    w = foxglove.open_mcap(str(path), context=ctx, writer_options=opts)
    schema = foxglove.Schema(name="s", encoding="jsonschema", data=b"{}")
    ch = {
        t: foxglove.Channel(t, message_encoding="json", schema=schema, context=ctx).base
        for t in sorted({m[0] for m in msgs})
    }
    for k, (topic, t, data) in enumerate(msgs):
        ch[topic].log(data, t)
        if k % FLUSH_EVERY == FLUSH_EVERY - 1:
            w.flush()
    w.close()
    return _since(t0)


def logger_run(cls: Any, path: Path, mix: list[tuple[str, tuple[Any, ...]]]) -> tuple[float, float]:
    """SessionWriter end to end: (wall s, process CPU s) from the first log() to the finished
    file."""
    # the queue never fills (low-priority topics stop at half of it)
    lg = cls(path, queue_size=2 * len(mix) + 2, chunk_size=CHUNK_SIZE, flush_period_s=1.0)
    log = lg.log
    c0, t0 = time.process_time(), time.perf_counter()
    for topic, rec in mix:
        log(topic, rec)
    assert lg.stop(600.0)
    wall, cpu = time.perf_counter() - t0, time.process_time() - c0
    st = lg.stats()
    assert st.written >= len(mix) and st.dropped == 0 and st.encode_errors == 0, st
    return wall, cpu


def _frame_fields(records_mod: ModuleType) -> int:
    """Fields of a frame record in a revision (with ``direction``: 10)."""
    return len(typing.get_args(records_mod.FrameRecord))


FRAME_FIELDS_NOW = 10
"""This tree's frame record: ``can_endpoint.frame_record`` (with its direction)."""


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--base", default="main", help="git revision to compare with (default main)")
    ap.add_argument("--rounds", type=int, default=7, help="interleaved rounds (median reported)")
    ap.add_argument("--n", type=int, default=90_000, help="messages per run (9 per reading)")
    ap.add_argument("--foxglove", action="store_true", help="also foxglove-sdk's MCAP writer")
    args = ap.parse_args(argv)
    from cmm_comp.daemon.sessionlog.writer import SessionWriter

    n_readings = max(1, args.n // 9)
    with tempfile.TemporaryDirectory() as tmp:
        d = Path(tmp)
        base = import_base(args.base, d / "src")
        base_logger = importlib.import_module(f"{BASE_NAME}.sessionlog.thread_writer").McapLogger
        base_fields = _frame_fields(importlib.import_module(f"{BASE_NAME}.sessionlog.records"))
        base_mix = records(base_fields, n_readings)
        new_mix = records(FRAME_FIELDS_NOW, n_readings)
        msgs = encoded(new_mix)
        n = len(msgs)
        rows: dict[str, list[float]] = {
            f"{k}_{w}": [] for k in ("file", "filecpu") for w in ("base", "new", "fox")
        }
        rows.update({f"{k}_{w}": [] for k in ("log", "cpu") for w in ("base", "new", "same")})
        sizes: dict[str, int] = {}
        for r in range(args.rounds):
            order = [("base", "new"), ("new", "base")][r % 2]  # alternate who goes first
            for who in order:
                p = d / f"f-{who}-{r}.mcap"
                wall, cpu = file_base(base, p, msgs) if who == "base" else file_new(p, msgs)
                rows[f"file_{who}"].append(wall / n * 1e6)
                rows[f"filecpu_{who}"].append(cpu / n * 1e6)
                sizes[f"file_{who}"] = p.stat().st_size
                p.unlink()
            if args.foxglove:
                p = d / f"f-fox-{r}.mcap"
                wall, cpu = file_foxglove(p, msgs)
                rows["file_fox"].append(wall / n * 1e6)
                rows["filecpu_fox"].append(cpu / n * 1e6)
                sizes["file_fox"] = p.stat().st_size
                p.unlink()
            three = ("base", "new", "same")
            for who in three[r % 3 :] + three[: r % 3]:  # rotate who goes first
                p = d / f"l-{who}-{r}.mcap"
                cls, mix = {
                    "base": (base_logger, base_mix),
                    "new": (SessionWriter, new_mix),
                    "same": (SessionWriter, base_mix),
                }[who]
                wall, cpu = logger_run(cls, p, mix)
                rows[f"log_{who}"].append(wall / len(mix) * 1e6)
                rows[f"cpu_{who}"].append(cpu / len(mix) * 1e6)
                sizes[f"log_{who}"] = p.stat().st_size
                p.unlink()
            print(f"round {r + 1}/{args.rounds} done", file=sys.stderr, flush=True)

    def ratio(a: str, b: str) -> dict[str, float]:
        per_round = [x / y for x, y in zip(rows[a], rows[b], strict=True)]
        return {
            "median": statistics.median(per_round),
            "min": min(per_round),
            "max": max(per_round),
        }

    med = {k: statistics.median(v) for k, v in rows.items() if v}
    ratios = {
        "file_new/base": ratio("file_new", "file_base"),
        "file_cpu_new/base": ratio("filecpu_new", "filecpu_base"),
        "log_wall_new/base": ratio("log_new", "log_base"),
        "log_cpu_new/base": ratio("cpu_new", "cpu_base"),
        "log_wall_same_records/base": ratio("log_same", "log_base"),
        "log_cpu_same_records/base": ratio("cpu_same", "cpu_base"),
    }
    if rows["file_fox"]:
        ratios["file_foxglove/base"] = ratio("file_fox", "file_base")
        ratios["file_cpu_foxglove/base"] = ratio("filecpu_fox", "filecpu_base")
    print(f"{n} messages (daemon mix, {n_readings} readings), {args.rounds} interleaved rounds")
    print(f"base = {args.base}; machine shared: ratios are per round, then the median")
    print("| level | base µs/msg | this tree µs/msg | ratio (median, min–max) |")
    print("|---|---|---|---|")
    for label, a, b in (
        ("file writer (wall)", "file_base", "file_new"),
        ("file writer (thread CPU)", "filecpu_base", "filecpu_new"),
        ("thread logger (wall)", "log_base", "log_new"),
        ("thread logger (CPU)", "cpu_base", "cpu_new"),
        ("thread logger, base's records (wall)", "log_base", "log_same"),
        ("thread logger, base's records (CPU)", "cpu_base", "cpu_same"),
    ):
        rt = ratio(b, a)
        print(
            f"| {label} | {med[a]:.2f} | {med[b]:.2f} | "
            f"{rt['median']:.2f} ({rt['min']:.2f}–{rt['max']:.2f}) |"
        )
    for label, a, b in (
        ("file writer, foxglove-sdk (wall)", "file_base", "file_fox"),
        ("file writer, foxglove-sdk (thread CPU)", "filecpu_base", "filecpu_fox"),
    ):
        if rows[b]:
            rt = ratio(b, a)
            print(
                f"| {label} | {med[a]:.2f} | {med[b]:.2f} | "
                f"{rt['median']:.2f} ({rt['min']:.2f}–{rt['max']:.2f}) |"
            )
    per_msg = {k: v / n for k, v in sizes.items()}
    print("bytes per message: " + ", ".join(f"{k} {v:.1f}" for k, v in per_msg.items()))
    RESULTS.parent.mkdir(parents=True, exist_ok=True)
    RESULTS.write_text(
        json.dumps(
            {
                "base": args.base,
                "n": n,
                "rounds": args.rounds,
                "python": sys.version.split()[0],
                "machine": platform.machine(),
                "cpus": os.cpu_count(),
                "median_us_per_message": med,
                "ratios": ratios,
                "bytes_per_message": per_msg,
                "per_round_us": rows,
            },
            indent=2,
        )
        + "\n"
    )
    print(f"wrote {RESULTS}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
