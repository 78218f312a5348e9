"""Benchmark: the daemon's start to ``ready`` with numba's kernel cache and without one.

Without a writable cache folder (a read-only installation, no home, no ``NUMBA_CACHE_DIR``) the
daemon compiles its grid kernels in memory at every start (``compensation/jit.py``); with the
systemd unit's ``CacheDirectory=`` only the first start does. Each round starts the daemon of a
``cmm-comp daemon init`` folder (NPL example machine, virtual CAN, no session log) twice, in
alternating order: once with ``NUMBA_CACHE_DIR`` pointing at a warm cache, once with numba's own
switch leaving it no cache locator (``NUMBA_CACHE_LOCATOR_CLASSES=ZipCacheLocator``, what a
read-only install without a home amounts to). Measured: wall time from ``exec`` to the
``state ready`` event line, and the daemon process's CPU time (user + system) at that moment.

Run: ``python benchmarks/bench_kernel_cache.py [--rounds N]``; writes
benchmarks/results/kernel_cache.json.
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
OUT = ROOT / "benchmarks" / "results" / "kernel_cache.json"
MACHINE = ROOT / "examples" / "machines" / "npl-bridge.toml"
CMM = Path(sys.executable).with_name("cmm-comp")
TICKS = os.sysconf("SC_CLK_TCK")


def _cpu_s(pid: int) -> float:
    fields = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()
    return (int(fields[11]) + int(fields[12])) / TICKS  # utime + stime


def start_to_ready(config: Path, env: dict[str, str]) -> tuple[float, float]:
    """(wall s, CPU s) from exec to the daemon's ``state ready`` line; the daemon is stopped."""
    argv = [str(CMM), "daemon", "--config", str(config), "--mcap-path", "", "--metrics-port", "0"]
    t0 = time.perf_counter()
    proc = subprocess.Popen(argv, stdout=subprocess.PIPE, stderr=subprocess.DEVNULL, env=env)
    try:
        assert proc.stdout is not None
        for line in proc.stdout:
            if b'"event":"state"' in line and b'"state":"ready"' in line:
                return time.perf_counter() - t0, _cpu_s(proc.pid)
        raise RuntimeError(f"daemon ended without a ready line (exit {proc.wait()})")
    finally:
        proc.terminate()
        proc.wait(60)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--rounds", type=int, default=3)
    args = ap.parse_args(argv)
    results: dict[str, list[tuple[float, float]]] = {"cache": [], "no cache": []}
    with tempfile.TemporaryDirectory() as tmp:
        folder = Path(tmp) / "d"
        subprocess.run(
            [str(CMM), "daemon", "init", str(folder), "--machine", str(MACHINE),
             "--can-interface", "virtual"],
            check=True, capture_output=True,
        )  # fmt: skip
        base = {k: v for k, v in os.environ.items() if not k.startswith("NUMBA_CACHE")}
        envs = {
            "cache": {**base, "NUMBA_CACHE_DIR": str(Path(tmp) / "cache")},
            "no cache": {**base, "NUMBA_CACHE_LOCATOR_CLASSES": "ZipCacheLocator"},
        }
        start_to_ready(folder / "daemon.toml", envs["cache"])  # warms the cache
        for r in range(args.rounds):
            order = ("cache", "no cache") if r % 2 == 0 else ("no cache", "cache")
            for case in order:
                results[case].append(start_to_ready(folder / "daemon.toml", envs[case]))
    table = {
        case: {
            "wall_s_median": statistics.median(w for w, _ in runs),
            "cpu_s_median": statistics.median(c for _, c in runs),
            "runs": [{"wall_s": w, "cpu_s": c} for w, c in runs],
        }
        for case, runs in results.items()
    }
    ratio = table["no cache"]["cpu_s_median"] / table["cache"]["cpu_s_median"]
    print(f"daemon start to ready, {args.rounds} interleaved rounds (median):")
    print(f"{'case':<10} {'wall s':>8} {'CPU s':>8}")
    for case, row in table.items():
        print(f"{case:<10} {row['wall_s_median']:8.1f} {row['cpu_s_median']:8.1f}")
    print(f"CPU without a cache / with: {ratio:.1f}×")
    load = os.getloadavg()
    OUT.write_text(
        json.dumps(
            {
                "benchmark": "kernel_cache",
                "rounds": args.rounds,
                "cases": table,
                "cpu_ratio_no_cache_over_cache": ratio,
                "machine": {"cpus": os.cpu_count(), "loadavg": load, "python": sys.version},
                "platform": platform.platform(),
            },
            indent=1,
        )
        + "\n"
    )
    return 0


if __name__ == "__main__":
    sys.exit(main())
