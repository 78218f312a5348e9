"""Benchmark: start-up of the ``cmm-comp`` CLI (``--help``, ``map``, ``daemon --help``).

A command imports only what it uses: ``cmm-comp map`` must not pay for python-can, pymodbus,
mcap or numba. Each case is a whole process (best of N), against baselines in the same run:
a bare ``python -c pass`` and ``python -c "import numpy, scipy.interpolate"``. Also lists which
heavy libraries each command imports (``-X importtime``).

Run: ``python benchmarks/bench_startup.py [--entry MODULE] [--python PY] [--repeat N]``;
``--entry``/``--python`` measure another checkout (e.g. the tree before the move, whose CLI
module was ``daemon.cli``). Writes benchmarks/results/startup.json (not with --entry).
"""

from __future__ import annotations

import argparse
import json
import platform
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
OUT = ROOT / "benchmarks" / "results" / "startup.json"
MACHINE = ROOT / "examples" / "machines" / "npl-bridge.toml"
HEAVY = ("can", "pymodbus", "mcap", "numba", "matplotlib", "scipy")


def best_of(cmd: list[str], repeat: int) -> float:
    times = []
    for _ in range(repeat):
        t0 = time.perf_counter()
        subprocess.run(cmd, check=True, capture_output=True)
        times.append(time.perf_counter() - t0)
    return min(times)


def heavy_imports(cmd: list[str]) -> list[str]:
    """Top-level heavy packages a command imports (from ``-X importtime`` on stderr)."""
    run = subprocess.run([cmd[0], "-X", "importtime", *cmd[1:]], capture_output=True, text=True)
    names = set()
    for line in run.stderr.splitlines():
        if line.startswith("import time:") and "|" in line:
            names.add(line.rsplit("|", 1)[1].strip().split(".")[0])
    return sorted(n for n in HEAVY if n in names)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--entry", default="cmm_comp.cli", help="CLI module run with -m")
    ap.add_argument("--python", default=sys.executable)
    ap.add_argument("--repeat", type=int, default=7)
    args = ap.parse_args(argv)
    py, entry = args.python, args.entry
    with tempfile.TemporaryDirectory() as tmp:
        cases = {
            "cmm-comp --help": [py, "-m", entry, "--help"],
            "cmm-comp map (5×5×5)": [
                *(py, "-m", entry, "map", str(MACHINE), "--out", f"{tmp}/m.csv"),
                *("--steps", "5", "5", "5"),
            ],
            "cmm-comp daemon --help": [py, "-m", entry, "daemon", "--help"],
        }
        base = {
            "python -c pass": [py, "-c", "pass"],
            "python: import numpy, scipy.interpolate": [
                py,
                "-c",
                "import numpy, scipy.interpolate",
            ],
        }
        rows = []
        for name, cmd in {**base, **cases}.items():
            t = best_of(cmd, args.repeat)
            rows.append(
                {"case": name, "s": t, "heavy": heavy_imports(cmd) if name in cases else []}
            )
    t_np = rows[1]["s"]
    print(f"{'case':<42} {'best s':>7} {'÷ numpy+scipy':>14}  heavy imports")
    for r in rows:
        r["ratio_to_numpy_scipy"] = r["s"] / t_np
        print(
            f"{r['case']:<42} {r['s']:>7.3f} {r['ratio_to_numpy_scipy']:>14.2f}  "
            f"{', '.join(r['heavy']) or '-'}"
        )
    if entry == "cmm_comp.cli" and py == sys.executable:
        OUT.parent.mkdir(parents=True, exist_ok=True)
        OUT.write_text(json.dumps({"machine": platform.node(), "results": rows}, indent=2) + "\n")
        print(f"wrote {OUT}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
