"""Identification accuracy of ``cmm-comp calibrate`` on simulated machines with hidden truth.

For each data kind alone and all mixed, N random machines (the ten models in turn; each table a
random cubic, with ``--wave`` also a sinusoid of 0.4–1.5 × the travel) are simulated by
tests/calibration_sim.py (public machine API only: noise, unknown plate poses, stations known to
±30 mm, dead paths) and calibrated through the command line. Identified vs true volumetric error
at the calibration stylus on the 6 × 6 × 6 grid after removing the best rigid motion: the RMS
difference as % of the truth's RMS, and the fraction of (node, component) within U (k = 2).

    python benchmarks/bench_calibrate_accuracy.py [--machines N] [--wave] [--kinds laser plate …]

Prints a table and writes benchmarks/results/calibrate_accuracy[_wave].json.
"""

from __future__ import annotations

import argparse
import json
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "tests"))

from calibration_sim import MODELS, Setup, compare, run_cli, simulate  # noqa: E402

SETUP = Setup(
    lower=np.zeros(3), upper=np.array([800.0, 600.0, 500.0]), stylus=np.array([0.0, 0.0, -120.0])
)
CONFIGS = {
    "laser": ("laser",),
    "plate": ("plate",),
    "multilateration": ("multilateration",),
    "mixed": ("laser", "plate", "multilateration"),
}


def run_one(kinds: tuple[str, ...], index: int, seed: int, wave: bool) -> dict[str, object]:
    model = MODELS[index % len(MODELS)]
    with tempfile.TemporaryDirectory() as tmp:
        d = Path(tmp)
        machine, plan = simulate(
            d, model, SETUP, kinds, np.random.default_rng(seed + index), nodes=11, wave=wave
        )
        t0 = time.perf_counter()
        proc = run_cli(["calibrate", str(plan), "-o", "machine.toml", "--report", "report"], d)
        proc.check_returncode()
        result = compare(machine, d / "report" / "volumetric_u.csv")
        return {"model": model, **result, "seconds": time.perf_counter() - t0}


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--machines", type=int, default=10, help="machines per configuration")
    ap.add_argument("--wave", action="store_true", help="tables with a sinusoid as well")
    ap.add_argument("--kinds", nargs="+", choices=sorted(CONFIGS), default=list(CONFIGS))
    ap.add_argument("--seed", type=int, default=5000)
    args = ap.parse_args()
    summary = {}
    print(
        f"{'data':<16} {'machines':>8} {'RMS % median':>13} {'RMS % max':>10} "
        f"{'coverage pooled':>16} {'coverage min':>13} {'s median':>9}"
    )
    for name in args.kinds:
        runs = [run_one(CONFIGS[name], i, args.seed, args.wave) for i in range(args.machines)]
        rms = np.array([r["rms_percent"] for r in runs], dtype=float)
        cov = np.array([r["coverage"] for r in runs], dtype=float)
        secs = np.array([r["seconds"] for r in runs], dtype=float)
        summary[name] = {
            "runs": runs,
            "rms_percent_median": float(np.median(rms)),
            "rms_percent_max": float(rms.max()),
            "coverage_pooled": float(cov.mean()),
            "coverage_min": float(cov.min()),
            "seconds_median": float(np.median(secs)),
        }
        s = summary[name]
        print(
            f"{name:<16} {len(runs):>8} {s['rms_percent_median']:>13.2f} "
            f"{s['rms_percent_max']:>10.2f} {s['coverage_pooled']:>16.3f} "
            f"{s['coverage_min']:>13.3f} {s['seconds_median']:>9.1f}",
            flush=True,
        )
    out = {
        "truth": "cubic + sinusoid per table" if args.wave else "cubic per table",
        "volume_mm": [SETUP.lower.tolist(), SETUP.upper.tolist()],
        "stylus_mm": SETUP.stylus.tolist(),
        "configurations": summary,
        "note": "wall times on a machine shared with other jobs (2 cores)",
    }
    path = (
        ROOT
        / "benchmarks"
        / "results"
        / ("calibrate_accuracy_wave.json" if args.wave else "calibrate_accuracy.json")
    )
    path.write_text(json.dumps(out, indent=2) + "\n")
    print(f"wrote {path}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
