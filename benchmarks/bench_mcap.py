"""MCAP session log: hot-path ``log()`` cost and sustained throughput vs the raw mcap writer.

Run: ``.venv/bin/python benchmarks/bench_mcap.py [--n 200000]``. Prints a table and writes
``benchmarks/results/mcap.json``. Both sides write the same ~110-byte ``/cmm/raw`` JSON messages
to a temporary file with the same chunk size and compression, in the same process; compare the
ratios, not the absolute numbers (the machine is shared).
"""

from __future__ import annotations

import argparse
import json
import platform
import statistics
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

from mcap.writer import CompressionType, Writer

from cmm_comp.daemon.sessionlog.writer import SessionWriter
from cmm_comp.protocol.session_topics import TOPIC_SCHEMAS, stamp_from_ns

RESULTS = Path(__file__).resolve().parent / "results" / "mcap.json"
CHUNK_SIZE = 256 * 1024


def payload(i: int) -> dict[str, Any]:
    return {"seq": i, "x_mm": 412.123456 + i * 1e-3, "y_mm": -87.5, "z_mm": 12.25}


def raw_writer(path: Path, n: int, compression: CompressionType) -> float:
    """Baseline: json + mcap Writer in the calling thread. Returns messages/s."""
    t0 = time.perf_counter()
    with open(path, "wb") as f:
        w = Writer(f, chunk_size=CHUNK_SIZE, compression=compression)
        w.start()
        sch = TOPIC_SCHEMAS["/cmm/raw"]
        cid = w.register_channel(
            "/cmm/raw", "json", w.register_schema(sch.name, "jsonschema", sch.as_bytes())
        )
        for i in range(n):
            t_ns = time.time_ns()
            data = json.dumps(
                {**payload(i), "stamp": stamp_from_ns(t_ns)}, separators=(",", ":")
            ).encode()
            w.add_message(cid, t_ns, data, t_ns)
        w.finish()
    return n / (time.perf_counter() - t0)


def logger_run(path: Path, n: int, compression: CompressionType) -> dict[str, float]:
    """SessionWriter end to end: first log() to finished file. Also times each log() call."""
    lg = SessionWriter(path, queue_size=n + 1, compression=compression, chunk_size=CHUNK_SIZE)
    costs_ns = []
    pc = time.perf_counter_ns
    t0 = time.perf_counter()
    for i in range(n):
        a = pc()
        lg.log("/cmm/raw", payload(i))
        costs_ns.append(pc() - a)
    t_enq = time.perf_counter() - t0
    lg.stop(600.0)
    total = time.perf_counter() - t0
    st = lg.stats()
    assert st.written == n and st.dropped == 0, st
    costs_ns.sort()
    return {
        "msgs_per_s": n / total,
        "enqueue_msgs_per_s": n / t_enq,
        "log_p50_us": costs_ns[len(costs_ns) // 2] / 1e3,
        "log_p99_us": costs_ns[int(len(costs_ns) * 0.99)] / 1e3,
        "log_max_us": costs_ns[-1] / 1e3,
    }


def log_cost_batched(path: Path, n: int) -> float:
    """Mean log() cost without the per-call timer overhead (µs), queue never full."""
    with SessionWriter(path, queue_size=n + 1) as lg:
        p = payload(0)
        t0 = time.perf_counter()
        for _ in range(n):
            lg.log("/cmm/raw", p)
        dt = time.perf_counter() - t0
    return dt / n * 1e6


def paced_run(path: Path, rate_hz: float, duration_s: float) -> dict[str, float]:
    """log() cost at a steady daemon-like rate (the writer mostly idle), µs."""
    n = int(rate_hz * duration_s)
    costs_ns = []
    pc = time.perf_counter_ns
    with SessionWriter(path, flush_period_s=1.0) as lg:
        t0 = time.monotonic()
        for i in range(n):
            a = pc()
            lg.log("/cmm/raw", payload(i))
            costs_ns.append(pc() - a)
            delay = t0 + (i + 1) / rate_hz - time.monotonic()
            if delay > 0:
                time.sleep(delay)
    costs_ns.sort()
    return {
        "rate_hz": rate_hz,
        "log_p50_us": costs_ns[n // 2] / 1e3,
        "log_p99_us": costs_ns[int(n * 0.99)] / 1e3,
        "log_p999_us": costs_ns[int(n * 0.999)] / 1e3,
        "log_max_us": costs_ns[-1] / 1e3,
    }


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__)
    ap.add_argument("--n", type=int, default=100_000, help="messages per run")
    ap.add_argument("--repeat", type=int, default=3, help="runs per case (median is reported)")
    args = ap.parse_args(argv)
    rows: dict[str, dict[str, float]] = {}
    with tempfile.TemporaryDirectory() as tmp:
        d = Path(tmp)
        for comp in (CompressionType.ZSTD, CompressionType.NONE):
            tag = comp.name.lower()
            base = [raw_writer(d / f"raw-{tag}-{k}.mcap", args.n, comp) for k in range(args.repeat)]
            runs = [logger_run(d / f"log-{tag}-{k}.mcap", args.n, comp) for k in range(args.repeat)]
            med = {key: statistics.median(r[key] for r in runs) for key in runs[0]}
            rows[tag] = {"raw_writer_msgs_per_s": statistics.median(base), **med}
            rows[tag]["ratio_vs_raw"] = med["msgs_per_s"] / rows[tag]["raw_writer_msgs_per_s"]
        mean_cost = statistics.median(
            log_cost_batched(d / f"cost-{k}.mcap", args.n) for k in range(args.repeat)
        )
        paced = paced_run(d / "paced.mcap", 5000.0, 2.0)
    print(f"n = {args.n} messages of /cmm/raw (~110 B JSON), median of {args.repeat} runs")
    print(f"mean log() cost, untimed loop: {mean_cost:.2f} µs")
    hdr = (
        "compression",
        "raw msg/s",
        "logger msg/s",
        "ratio",
        "enqueue msg/s",
        "log p50 µs",
        "log p99 µs",
        "log max µs",
    )
    print(" | ".join(hdr))
    print(" | ".join("---" for _ in hdr))
    for tag, r in rows.items():
        print(
            f"{tag} | {r['raw_writer_msgs_per_s']:,.0f} | {r['msgs_per_s']:,.0f} | "
            f"{r['ratio_vs_raw']:.2f} | {r['enqueue_msgs_per_s']:,.0f} | {r['log_p50_us']:.2f} | "
            f"{r['log_p99_us']:.2f} | {r['log_max_us']:.1f}"
        )
    print(
        f"paced at {paced['rate_hz']:.0f} msg/s: log() p50 {paced['log_p50_us']:.2f} µs, "
        f"p99 {paced['log_p99_us']:.2f} µs, p99.9 {paced['log_p999_us']:.2f} µs, "
        f"max {paced['log_max_us']:.1f} µs"
    )
    RESULTS.parent.mkdir(parents=True, exist_ok=True)
    RESULTS.write_text(
        json.dumps(
            {
                "n": args.n,
                "repeat": args.repeat,
                "python": sys.version.split()[0],
                "machine": platform.machine(),
                "log_mean_us": mean_cost,
                "cases": rows,
                "paced": paced,
            },
            indent=2,
        )
        + "\n"
    )
    print(f"wrote {RESULTS}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
