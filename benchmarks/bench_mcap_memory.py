"""MCAP session log: memory growth (RSS) of the logging process and of the writer child.

Run: ``.venv/bin/python benchmarks/bench_mcap_memory.py [--seconds 180] [--rate-hz 1000]``.
Logs readings the way the CAN endpoint does (3 frames in, raw, 4 frames out, corrected: 9
messages per reading, a ``/cmm/counters`` record a second) at ``--rate-hz`` readings/s, paced
by sleeping, through each writer into a rolling directory; samples VmRSS of this process and
of the writer child from /proc every second, and fits a line to the samples after the warm-up:
growth in MiB/h. Prints a table and writes ``benchmarks/results/mcap_memory.json``. Not in CI.
"""

from __future__ import annotations

import argparse
import json
import platform
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

import numpy as np

from cmm_comp.daemon.sessionlog.process_writer import McapProcessLogger
from cmm_comp.daemon.sessionlog.writer import SessionWriter

RESULTS = Path(__file__).resolve().parent / "results" / "mcap_memory.json"
FRAME = (0x181, False, 8, bytes(range(8)), 1_700_000_000.5, "vcan0", False, False, False)
RAW = (1.0, 2.0, 3.0, (1, 1, 1), (True, True, True), "can", (0.0, 0.0, -120.0), None)


def rss_mib(pid: int | str = "self") -> float:
    """Resident set size of ``pid``, MiB (VmRSS of /proc/PID/status)."""
    with open(f"/proc/{pid}/status") as f:
        for line in f:
            if line.startswith("VmRSS:"):
                return int(line.split()[1]) / 1024
    raise RuntimeError(f"no VmRSS for {pid}")


def slope_mib_per_h(t_s: list[float], rss: list[float]) -> float:
    """Least-squares slope of RSS (MiB) over time (s), MiB/h."""
    return float(np.polyfit(np.asarray(t_s), np.asarray(rss), 1)[0] * 3600.0)


def run(writer: str, seconds: float, warmup_s: float, rate_hz: float, roll_mb: float) -> dict:
    """Log for ``seconds`` through ``writer`` and return the RSS samples and slopes."""
    with tempfile.TemporaryDirectory() as tmp:
        kw: dict[str, Any] = {"roll_bytes": int(roll_mb * 1e6)}
        lg: SessionWriter | McapProcessLogger = (
            McapProcessLogger(tmp, **kw) if writer == "process" else SessionWriter(tmp, **kw)
        )
        child = lg.child_pid if isinstance(lg, McapProcessLogger) else None
        samples: list[tuple[float, float, float]] = []
        t0 = time.monotonic()
        next_sample, next_counters, i = t0, t0 + 1.0, 0
        while (now := time.monotonic()) - t0 < seconds:
            for _ in range(3):
                lg.log("/cmm/can_rx", FRAME)
            lg.log("/cmm/raw", (i, *RAW))
            for _ in range(4):
                lg.log("/cmm/can_tx", FRAME)
            lg.log("/cmm/corrected", (i, 1, 2, 3, "ok", (0.1, 0.2, 0.3), 55.0, 3, "can", ""))
            lg.kick()
            i += 1
            if now >= next_counters:
                lg.log("/cmm/counters", {"counters": {"readings": i}, "period_s": 1.0})
                next_counters += 1.0
            if now >= next_sample:
                samples.append((now - t0, rss_mib(), rss_mib(child) if child else 0.0))
                next_sample += 1.0
            delay = t0 + i / rate_hz - time.monotonic()
            if delay > 0:
                time.sleep(delay)
        lg.stop(60.0)
        st = lg.stats()
        files = len(st.files)
    after = [s for s in samples if s[0] >= warmup_s]
    t = [s[0] for s in after]
    out = {
        "writer": writer,
        "readings": i,
        "messages_written": st.written,
        "dropped": st.dropped,
        "files": files,
        "parent_rss_mib": [round(s[1], 2) for s in samples],
        "parent_mib_per_h": round(slope_mib_per_h(t, [s[1] for s in after]), 2),
    }
    if child:
        out["child_rss_mib"] = [round(s[2], 2) for s in samples]
        out["child_mib_per_h"] = round(slope_mib_per_h(t, [s[2] for s in after]), 2)
    return out


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seconds", type=float, default=180.0)
    ap.add_argument("--warmup-s", type=float, default=30.0)
    ap.add_argument("--rate-hz", type=float, default=1000.0, help="readings/s (9 messages each)")
    ap.add_argument("--roll-mb", type=float, default=20.0, help="file size that rolls, MB")
    ap.add_argument("--writers", default="process,thread")
    ap.add_argument("--out", default=str(RESULTS))
    args = ap.parse_args(argv)
    rows = [
        run(w, args.seconds, args.warmup_s, args.rate_hz, args.roll_mb)
        for w in args.writers.split(",")
    ]
    print(
        f"{'writer':<8} {'readings':>9} {'dropped':>8} {'files':>5} "
        f"{'parent MiB/h':>13} {'child MiB/h':>12}"
    )
    for r in rows:
        child = f"{r['child_mib_per_h']:12.1f}" if "child_mib_per_h" in r else f"{'-':>12}"
        print(
            f"{r['writer']:<8} {r['readings']:9d} {r['dropped']:8d} {r['files']:5d} "
            f"{r['parent_mib_per_h']:13.1f} {child}"
        )
    result = {
        "args": vars(args),
        "python": sys.version.split()[0],
        "machine": platform.machine(),
        "runs": rows,
    }
    Path(args.out).parent.mkdir(parents=True, exist_ok=True)
    Path(args.out).write_text(json.dumps(result, indent=2) + "\n")
    return 0


if __name__ == "__main__":
    sys.exit(main())
