"""Identification-rate study of the diagnosis: hidden causes × effect sizes × seeds.

For every cause of docs/formats.md §4 (and clean sessions, and pairs of causes) and every effect size
(3-D RMS of the hidden effect as a multiple of the noise RMS), simulate sessions on the NPL-like
bridge machine (sim_controller), diagnose, and count a case as *named* when the set of (cause,
component/axis/varies_with) found equals the hidden one exactly (``none`` for clean sessions), and
*held-out OK* when the held-out 3-D RMS is within 1.5× the noise RMS. Prints a table, writes
``benchmarks/results/discovery.json``.

    .venv/bin/python benchmarks/bench_discovery.py [--seeds 20] [--sizes 0.25 0.5 1 3] [--jobs 2]
"""

from __future__ import annotations

import argparse
import json
import time
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path

import numpy as np

from cmm_comp.compensation.diagnosis import diagnose
from cmm_comp.compensation.machine import Machine
from cmm_comp.sim_controller.true_machine import HIDDEN_CAUSES, simulate

ROOT = Path(__file__).resolve().parents[1]
MACHINE = ROOT / "examples" / "machines" / "npl-bridge.toml"
PAIRS = [
    ("periodic", "reversal"),
    ("scale_expansion", "thermal_gradient"),
    ("coupling", "probe_lobing"),
    ("parametric", "squareness_drift"),
    ("thermal_lag", "workpiece_expansion"),
]
IDENT_KEYS = ("cause", "component", "axis", "varies_with")


def identity(entry: dict) -> tuple:
    return tuple(entry.get(k) for k in IDENT_KEYS)


def run_case(case: tuple[str, float, int]) -> dict:
    label, size, seed = case
    machine = Machine.from_toml(MACHINE)
    causes = [] if label == "none" else label.split("+")
    truth, data = simulate(machine, causes, [size] * len(causes), seed)
    t0 = time.perf_counter()
    d = diagnose(machine, data)
    found = sorted(identity(e) for e in d.entries)
    hidden = sorted(identity(e.describe()) for e in truth.hidden)
    return {
        "case": label,
        "size": size,
        "seed": seed,
        "named": found == hidden,
        "found": [list(f) for f in found],
        "hidden": [list(h) for h in hidden],
        "heldout_ok": d.summary["heldout_rms_um"]["after"] <= 1.5 * truth.noise_rms_3d_um,
        "heldout_rms_um": d.summary["heldout_rms_um"]["after"],
        "noise_rms_um": truth.noise_rms_3d_um,
        "seconds": time.perf_counter() - t0,
    }


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seeds", type=int, default=20)
    ap.add_argument("--sizes", type=float, nargs="+", default=[0.25, 0.5, 1.0, 3.0])
    ap.add_argument("--clean", type=int, default=100, help="clean sessions")
    ap.add_argument("--jobs", type=int, default=2)
    ap.add_argument("--out", type=Path, default=ROOT / "benchmarks" / "results" / "discovery.json")
    args = ap.parse_args()
    cases = [("none", 0.0, 10_000 + s) for s in range(args.clean)]
    labels = [*HIDDEN_CAUSES, *("+".join(p) for p in PAIRS)]
    cases += [
        (c, z, 1000 * i + s)
        for i, c in enumerate(labels)
        for z in args.sizes
        for s in range(args.seeds)
    ]
    t0 = time.perf_counter()
    with ProcessPoolExecutor(args.jobs) as pool:
        results = list(pool.map(run_case, cases, chunksize=4))
    wall = time.perf_counter() - t0
    table: dict[str, dict[str, float]] = {}
    for label in ["none", *labels]:
        row = {}
        for z in [0.0] if label == "none" else args.sizes:
            rs = [r for r in results if r["case"] == label and r["size"] == z]
            row[f"{z:g}"] = float(np.mean([r["named"] for r in rs]))
            row[f"heldout_ok_{z:g}"] = float(np.mean([r["heldout_ok"] for r in rs]))
        table[label] = row
    head = f"{'case':42s}" + "".join(f"{'×' + format(z, 'g'):>9s}" for z in args.sizes)
    print(f"named exactly (fraction of {args.seeds} seeds; clean: {args.clean} sessions)")
    print(head)
    for label, row in table.items():
        if label == "none":
            print(f"{'none (clean, no false alarm)':42s}{row['0']:>9.2f}")
        else:
            print(f"{label:42s}" + "".join(f"{row[f'{z:g}']:>9.2f}" for z in args.sizes))
    misses = [r for r in results if not r["named"]]
    print(
        f"\n{len(misses)} misses of {len(results)}; wall {wall:.0f} s, "
        f"median diagnosis {np.median([r['seconds'] for r in results]):.2f} s"
    )
    for r in misses[:40]:
        print(
            f"  {r['case']} ×{r['size']:g} seed {r['seed']}: hidden {r['hidden']} found {r['found']}"
        )
    args.out.parent.mkdir(parents=True, exist_ok=True)
    args.out.write_text(
        json.dumps(
            {
                "table": table,
                "results": results,
                "wall_s": wall,
                "seeds": args.seeds,
                "sizes": args.sizes,
            },
            indent=1,
        )
    )
    print(f"wrote {args.out}")


if __name__ == "__main__":
    main()
