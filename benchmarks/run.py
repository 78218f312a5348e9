"""Run every benchmark in this folder (``python benchmarks/run.py [name …]``).

Each ``bench_*.py`` prints its own table and writes ``benchmarks/results/<name>.json``. The
long ones (:data:`ON_REQUEST`, e.g. the 1 h soak) run only when named.
"""

from __future__ import annotations

import subprocess
import sys
import time
from pathlib import Path

HERE = Path(__file__).resolve().parent
ON_REQUEST = frozenset({"bench_soak", "bench_calibration_truth", "bench_calibrate_accuracy"})
"""Benchmarks run only when named on the command line (they take an hour or more: the soak;
the calibration's hidden-truth and accuracy runs, hundreds of calibrations)."""


def main(argv: list[str]) -> int:
    scripts = sorted(HERE.glob("bench_*.py"))
    if argv:
        scripts = [s for s in scripts if any(a in s.stem for a in argv)]
    else:
        scripts = [s for s in scripts if s.stem not in ON_REQUEST]
    failed = []
    for script in scripts:
        print(f"\n=== {script.stem}", flush=True)
        t0 = time.perf_counter()
        rc = subprocess.run([sys.executable, str(script)], cwd=HERE.parent).returncode
        print(f"--- {script.stem}: exit {rc}, {time.perf_counter() - t0:.1f} s", flush=True)
        if rc:
            failed.append(script.stem)
    if failed:
        print(f"failed: {', '.join(failed)}")
    return 1 if failed else 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
