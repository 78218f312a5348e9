"""CPU of the product work the test suite pays most for, this tree against another checkout
(issue 26 item 7: the suite's CPU).

* one session's diagnosis: sessions simulated on the NPL-like bridge machine (``sim_controller``:
  a clean one, one per hidden cause and a pair), each diagnosed, its CPU time and a digest of
  its diagnosis JSON (without its wall-clock ``elapsed_s``) recorded;
* ``grid_u``: the node covariances of docs/uncertainty.md's quick-start grid (``cmm-comp grid
  build … --uncertainty``: 31×40×16 nodes of the example bridge, 1000 trials, seed 0), its CPU
  and a digest of the covariances.

CPU is ``time.process_time`` (all threads), BLAS on one thread. With ``--compare DIR`` (another
checkout, e.g. ``git archive main | tar -x -C DIR``) both trees run in alternating rounds, each
in a fresh interpreter importing ``cmm_comp`` from its tree, and the table gives per-case CPU
medians, the ratio this ÷ other, and whether the output is the same in both trees (bit for bit).

    .venv/bin/python benchmarks/bench_product_cpu.py [--compare DIR] [--rounds 3] [--cases ...]
"""

from __future__ import annotations

import argparse
import hashlib
import json
import os
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

ROOT = Path(__file__).resolve().parents[1]
MACHINE = ROOT / "examples" / "machines" / "npl-bridge.toml"
CASES = (
    "none",
    "coupling",
    "parametric",
    "periodic",
    "reversal",
    "thermal_lag",
    "squareness_drift",
    "coupling+probe_lobing",
    "grid_u",
)
#: The quick start's grid: ``CorrectionGrid.build``'s steps for the example bridge.
GRID_STEPS = (31, 40, 16)


def grid_u(seed: int) -> dict[str, Any]:
    """CPU seconds and the SHA-256 of the covariances of the quick start's grid U."""
    import numpy as np

    from cmm_comp.compensation.machine import Machine
    from cmm_comp.compensation.uncertainty.grid_field import grid_uncertainty

    machine = Machine.from_toml(MACHINE)
    vol = machine.volume
    axes = [np.linspace(vol.lower_mm[k], vol.upper_mm[k], GRID_STEPS[k]) for k in range(3)]
    grid_uncertainty(machine, axes, rng=np.random.default_rng(seed), trials=4)  # first calls
    t0 = time.process_time()
    gu = grid_uncertainty(machine, axes, rng=np.random.default_rng(seed), trials=1000)
    cpu = time.process_time() - t0
    return {"cpu_s": cpu, "json_sha256": hashlib.sha256(gu.covariance.tobytes()).hexdigest()}


def measure(cases: list[str], seed: int) -> dict[str, dict[str, Any]]:
    """Per case: its CPU seconds and the SHA-256 of its output (a diagnosis: its JSON with
    sorted keys, without ``elapsed_s``)."""
    from cmm_comp.compensation.diagnosis import diagnose
    from cmm_comp.compensation.machine import Machine
    from cmm_comp.sim_controller.true_machine import simulate

    out = {}
    if "grid_u" in cases:
        out["grid_u"] = grid_u(seed)
        cases = [c for c in cases if c != "grid_u"]
    if not cases:
        return out
    machine = Machine.from_toml(MACHINE)
    sessions = {}
    for i, case in enumerate(cases):
        causes = [] if case == "none" else case.split("+")
        sessions[case] = simulate(machine, causes, [1.0] * len(causes), seed + i)[1]
    diagnose(machine, sessions[cases[0]])  # imports and first-call costs out of the figures
    for case, data in sessions.items():
        t0 = time.process_time()
        d = diagnose(machine, data)
        cpu = time.process_time() - t0
        report = {k: v for k, v in d.to_json().items() if k != "elapsed_s"}  # wall time
        text = json.dumps(report, sort_keys=True, default=str)
        out[case] = {"cpu_s": cpu, "json_sha256": hashlib.sha256(text.encode()).hexdigest()}
    return out


def _round(env: dict[str, str], cases: list[str], seed: int) -> dict[str, dict[str, Any]]:
    code = (
        "import json, sys; sys.path.insert(0, sys.argv[1]); import bench_product_cpu as b; "
        "print(json.dumps(b.measure(sys.argv[2].split(','), int(sys.argv[3]))))"
    )
    run = subprocess.run(
        [sys.executable, "-c", code, str(Path(__file__).parent), ",".join(cases), str(seed)],
        check=True,
        env={**env, "OPENBLAS_NUM_THREADS": "1"},
        capture_output=True,
        text=True,
    )
    return dict(json.loads(run.stdout))


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--compare", type=Path, help="another checkout, measured alternately")
    ap.add_argument("--rounds", type=int, default=3, help="rounds per tree")
    ap.add_argument("--cases", nargs="+", default=list(CASES), help="causes (a+b: a pair), grid_u")
    ap.add_argument("--seed", type=int, default=7)
    args = ap.parse_args(argv)
    from bench_config_load import shim_env

    with tempfile.TemporaryDirectory() as tmp:
        envs = {"this": dict(os.environ)}
        if args.compare is not None:
            envs["other"] = shim_env(args.compare.resolve(), Path(tmp))
        runs: dict[str, list[dict[str, dict[str, Any]]]] = {k: [] for k in envs}
        for _ in range(args.rounds):
            for key, env in envs.items():
                runs[key].append(_round(env, args.cases, args.seed))
    med = {
        key: {c: statistics.median(r[c]["cpu_s"] for r in rs) for c in args.cases}
        for key, rs in runs.items()
    }
    print(f"CPU per case (s), median of {args.rounds} alternating rounds")
    print(f"{'case':<26}{'this':>8}{'other':>8}{'ratio':>8}  same JSON")
    for c in args.cases:
        this = med["this"][c]
        if "other" in med:
            other = med["other"][c]
            same = runs["this"][0][c]["json_sha256"] == runs["other"][0][c]["json_sha256"]
            print(f"{c:<26}{this:>8.3f}{other:>8.3f}{this / other:>8.3f}  {same}")
        else:
            print(f"{c:<26}{this:>8.3f}")
    total = {k: sum(s for c, s in v.items() if c != "grid_u") for k, v in med.items()}
    if "other" in total and total["other"] > 0:
        print(
            f"{'diagnosis sessions, total':<26}{total['this']:>8.3f}{total['other']:>8.3f}"
            f"{total['this'] / total['other']:>8.3f}"
        )
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
