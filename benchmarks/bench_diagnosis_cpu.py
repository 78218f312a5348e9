"""CPU of one session's diagnosis, this tree against another checkout (issue 26 item 7).

Simulates sessions on the NPL-like bridge machine (``sim_controller``: a clean one, one per
hidden cause and a pair), diagnoses each and records its CPU time (``time.process_time``,
BLAS on one thread) and a digest of its diagnosis JSON. With ``--compare DIR`` (another checkout,
e.g. ``git archive main | tar -x -C DIR``) both trees run in alternating rounds, each in a fresh
interpreter importing ``cmm_comp`` from its tree, and the table gives per-session CPU medians,
the ratio this ÷ other, and whether the diagnosis JSON is the same in both trees.

    .venv/bin/python benchmarks/bench_diagnosis_cpu.py [--compare DIR] [--rounds 3] [--causes ...]
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
)


def measure(cases: list[str], seed: int) -> dict[str, dict[str, Any]]:
    """Per case: the diagnosis' CPU seconds and the SHA-256 of its JSON (sorted keys, without
    its ``elapsed_s``)."""
    from cmm_comp.compensation.diagnosis import diagnose
    from cmm_comp.compensation.machine import Machine
    from cmm_comp.sim_controller.true_machine import simulate

    machine = Machine.from_toml(MACHINE)
    sessions = {}
    for i, case in enumerate(cases):
        causes = [] if case == "none" else case.split("+")
        sessions[case] = simulate(machine, causes, [1.0] * len(causes), seed + i)[1]
    diagnose(machine, sessions[cases[0]])  # imports and first-call costs out of the figures
    out = {}
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
        "import json, sys; sys.path.insert(0, sys.argv[1]); import bench_diagnosis_cpu as b; "
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
    ap.add_argument("--causes", nargs="+", default=list(CASES), help="cases (a+b: a pair)")
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
                runs[key].append(_round(env, args.causes, args.seed))
    med = {
        key: {c: statistics.median(r[c]["cpu_s"] for r in rs) for c in args.causes}
        for key, rs in runs.items()
    }
    print(f"diagnosis CPU per session (s), median of {args.rounds} alternating rounds")
    print(f"{'case':<26}{'this':>8}{'other':>8}{'ratio':>8}  same JSON")
    for c in args.causes:
        this = med["this"][c]
        if "other" in med:
            other = med["other"][c]
            same = runs["this"][0][c]["json_sha256"] == runs["other"][0][c]["json_sha256"]
            print(f"{c:<26}{this:>8.3f}{other:>8.3f}{this / other:>8.3f}  {same}")
        else:
            print(f"{c:<26}{this:>8.3f}")
    total = {k: sum(v.values()) for k, v in med.items()}
    if "other" in total:
        print(
            f"{'total':<26}{total['this']:>8.3f}{total['other']:>8.3f}"
            f"{total['this'] / total['other']:>8.3f}"
        )
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
