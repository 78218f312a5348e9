"""Where a ball plate alone misses the RMS bar (issue 27): inside or beyond the plate's reach, and
what an independent simple fit reaches on the same data.

For the machines of a results JSON of ``bench_calibration_truth.py`` (``--replay``, the plate
cases), each case is rebuilt by the independent generator (``tests/calibration_generator``) and:

* ``cmm-comp calibrate`` runs on it as a user types it (the installed CLI, a subprocess) and is
  scored as the truth benchmark scores it (RMS difference after the best rigid motion, % of the
  truth's rigid-body-free RMS, over the 6 × 6 × 6 grid of the whole volume, coverage within U);
* the same score **within the plate's reach**: the grid nodes inside the bounding box of the
  measured ball centres, each side's best rigid motion fitted over those nodes only, and the
  coverage inside and outside that box;
* an **independent simple fit** (written here from the papers' model, not from
  ``compensation/``): the 18 error functions as Legendre polynomials of order P (3 and 5) on the
  volume's travel plus the 3 squareness, each placement's pose (6 DOF) estimated, plain linear
  least squares (columns scaled; the directions the plate does not see — singular values below
  ``--rcond`` of the largest — left at zero, the minimum-norm solution), no smoothness prior. Its
  model is the generator's own exact chain (``TrueMachine.error_um`` with the trial
  coefficients: the kinematics of ``tests/calibration_generator/kinematics.py``), linearised at
  zero error; each placement's nominal pose from a rigid fit of the certificate to the centres.

Prints one line per machine and the summary; writes ``--out`` (JSON, every case).
``--plate-plan`` (default ``reach_limited``, the plan the recorded results were run with: the
generator's default is now ``full_reach``, whose balls reach the ends of every axis).

    .venv/bin/python benchmarks/bench_calibration_plate_reach.py \
        --replay benchmarks/results/calibration_truth_previous.json
"""

from __future__ import annotations

import os

for _var in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_var, "1")

import argparse  # noqa: E402
import copy  # noqa: E402
import csv  # noqa: E402
import json  # noqa: E402
import sys  # noqa: E402
import tempfile  # noqa: E402
import tomllib  # noqa: E402
from datetime import UTC, datetime  # noqa: E402
from pathlib import Path  # noqa: E402
from typing import Any  # noqa: E402

import numpy as np  # noqa: E402
from numpy.typing import NDArray  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "tests"))

from calibration_generator.case import MODELS, Case, build_case  # noqa: E402
from calibration_generator.machine import COMPONENTS, SQUARENESS, TrueMachine  # noqa: E402
from calibration_generator.plate import PLATE_PLANS  # noqa: E402
from calibration_generator.scoring import (  # noqa: E402
    calibrate_and_score,
    match_nodes,
    read_u_csv,
    remove_rigid,
    rms,
    run_cli,
)

FloatArray = NDArray[np.float64]
RESULTS = ROOT / "benchmarks" / "results" / "calibration_plate_reach.json"
#: the machines of the 12:27 UTC run of 2026-12-05 (the development data of the diagnosis)
REPLAY = ROOT / "benchmarks" / "results" / "calibration_truth_2026-12-05T1227.json"


def read_plate(case: Case) -> tuple[NDArray[Any], FloatArray, FloatArray]:
    """(placement labels, certificate centres (N, 3) mm, measured centres (N, 3) mm)."""
    cert = tomllib.loads((case.directory / "plate.toml").read_text(encoding="utf-8"))["ball"]
    balls = {str(b["id"]): np.array([b["u_mm"], b["v_mm"], b["w_mm"]], float) for b in cert}
    with (case.directory / "plate.csv").open(encoding="utf-8", newline="") as fh:
        rows = list(csv.DictReader(fh))
    labels = np.array([r["placement"] for r in rows])
    q = np.array([[float(r[k]) for k in "xyz"] for r in rows])
    b = np.array([balls[str(int(r["ball"]))] for r in rows])
    return labels, b, q


def rigid_fit(b: FloatArray, q: FloatArray) -> tuple[FloatArray, FloatArray]:
    """(R, t) of the least-squares rigid motion b → q (Kabsch)."""
    cb, cq = b.mean(0), q.mean(0)
    u, _, vt = np.linalg.svd((b - cb).T @ (q - cq))
    d = np.sign(np.linalg.det(vt.T @ u.T))
    r = vt.T @ np.diag([1.0, 1.0, d]) @ u.T
    return r, cq - r @ cb


def _unit_machines(m0: TrueMachine, order: int) -> tuple[TrueMachine, list[TrueMachine]]:
    """The zero-error machine and one machine per unit coefficient (µm, µrad)."""
    zero = copy.deepcopy(m0)
    zero.legendre = {c: np.zeros(order + 1) for c in COMPONENTS}
    zero.squareness_urad = {s: 0.0 for s in SQUARENESS}
    zero.reversal_um = {}
    units = []
    for c in COMPONENTS:
        for k in range(order + 1):
            m = copy.deepcopy(zero)
            m.legendre[c] = np.eye(order + 1)[k]
            units.append(m)
    for s in SQUARENESS:
        m = copy.deepcopy(zero)
        m.squareness_urad = {**zero.squareness_urad, s: 1.0}
        units.append(m)
    return zero, units


def _pose_columns(
    labels: NDArray[Any], b: FloatArray, q: FloatArray
) -> tuple[FloatArray, FloatArray]:
    """(right-hand side (3N,) µm, pose columns (3N, 6P)): q + e/1000 = R·b + t linearised at
    each placement's rigid fit; a pose change is a translation (µm) and a rotation (µrad)."""
    places = sorted(set(labels.tolist()))
    n = len(q)
    rhs = np.zeros((n, 3))
    cols = np.zeros((n, 3, 6 * len(places)))
    for j, p in enumerate(places):
        idx = np.flatnonzero(labels == p)
        r0, t0 = rigid_fit(b[idx], q[idx])
        rb = b[idx] @ r0.T
        rhs[idx] = 1000.0 * (rb + t0 - q[idx])
        lever_m = (rb - rb.mean(0)) / 1000.0
        for i, ii in enumerate(idx):
            x = lever_m[i]
            cols[ii, :, 6 * j : 6 * j + 3] = np.eye(3)
            cols[ii, :, 6 * j + 3 : 6 * j + 6] = [
                [0, x[2], -x[1]],
                [-x[2], 0, x[0]],
                [x[1], -x[0], 0],
            ]
    return rhs.reshape(-1), cols.reshape(3 * n, -1)


def simple_fit(case: Case, order: int, rcond: float) -> TrueMachine:
    """The independent simple fit of the module docstring: the identified machine."""
    labels, b, q = read_plate(case)
    zero, units = _unit_machines(case.machine, order)
    a_err = np.column_stack([m.error_um(q, case.stylus_mm).reshape(-1) for m in units])
    rhs, a_pose = _pose_columns(labels, b, q)
    a = np.hstack([a_err, a_pose])
    scale = np.linalg.norm(a, axis=0)
    scale[scale == 0] = 1.0
    sol = np.linalg.lstsq(a / scale, rhs, rcond=rcond)[0] / scale
    theta = sol[: a_err.shape[1]]
    ident = copy.deepcopy(zero)
    nc = order + 1
    for i, c in enumerate(COMPONENTS):
        ident.legendre[c] = theta[i * nc : (i + 1) * nc].copy()
    for i, s in enumerate(SQUARENESS):
        ident.squareness_urad[s] = float(theta[len(COMPONENTS) * nc + i])
    return ident


def reach_scores(
    case: Case, identified_um: FloatArray, u_um: FloatArray | None = None
) -> dict[str, float]:
    """RMS ratio over the volume and within the plate's reach; coverage inside/outside."""
    _, _, q = read_plate(case)
    nodes, truth = case.nodes_mm, case.truth_um
    inside = np.all((nodes >= q.min(0) - 1.0) & (nodes <= q.max(0) + 1.0), axis=1)
    diff = remove_rigid(nodes, identified_um - truth)[0]
    out = {
        "rms_ratio": rms(diff) / rms(remove_rigid(nodes, truth)[0]),
        "nodes_in_reach": int(inside.sum()),
        "rms_ratio_in_reach": float("nan"),
    }
    if inside.sum() >= 8:
        d_in = remove_rigid(nodes[inside], (identified_um - truth)[inside])[0]
        out["rms_ratio_in_reach"] = rms(d_in) / rms(remove_rigid(nodes[inside], truth[inside])[0])
    if u_um is not None:
        ok = np.abs(diff) <= u_um
        out["coverage_in_reach"] = float(ok[inside].mean()) if inside.any() else float("nan")
        out["coverage_out_of_reach"] = float(ok[~inside].mean()) if (~inside).any() else 1.0
    span = case.machine.upper_mm - case.machine.lower_mm
    out["reach_fraction_xyz"] = ((q.max(0) - q.min(0)) / span).round(3).tolist()
    return out


def run_one(seed: int, model: str, tmp: Path, args: argparse.Namespace) -> dict[str, Any]:
    case = build_case(tmp / f"plate-{model}-{seed}", seed, "plate", model, args.plate_plan)
    work = tmp / f"run-{seed}"
    score = calibrate_and_score(case, work, lambda p, o, r: run_cli(p, o, r, args.timeout))
    row: dict[str, Any] = {"seed": seed, "model": model, "calibrate": score.as_dict()}
    if score.values:
        from cmm_comp.compensation.machine import Machine

        ident = Machine.from_toml(work / "identified.toml").volumetric_error(
            case.nodes_mm, stylus_mm=case.stylus_mm
        )
        nodes_csv, _, u_um = read_u_csv(work / "report" / "volumetric_u.csv")
        row["ours"] = reach_scores(case, ident, u_um[match_nodes(case.nodes_mm, nodes_csv)])
    for p in args.orders:
        fit = simple_fit(case, p, args.rcond)
        row[f"simple_P{p}"] = reach_scores(case, fit.error_um(case.nodes_mm, case.stylus_mm))
    return row


def _summary(rows: list[dict[str, Any]], key: str) -> dict[str, Any]:
    r = np.array([row[key]["rms_ratio"] for row in rows if key in row])
    rin = np.array([row[key]["rms_ratio_in_reach"] for row in rows if key in row])
    return {
        "machines": int(r.size),
        "rms_ratio_median": float(np.median(r)),
        "rms_ratio_max": float(r.max()),
        "within_20pct": int((r <= 0.2).sum()),
        "rms_ratio_in_reach_median": float(np.nanmedian(rin)),
        "rms_ratio_in_reach_max": float(np.nanmax(rin)),
    }


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument(
        "--replay",
        default=str(REPLAY),
        help=f"a calibration_truth JSON (its seeds; default {REPLAY})",
    )
    ap.add_argument("--orders", default="3,5", help="simple fit's polynomial orders (3,5)")
    ap.add_argument("--rcond", type=float, default=1e-4, help="simple fit's cut-off (1e-4)")
    ap.add_argument("--first", type=int, help="only the first N machines of the file")
    ap.add_argument("--timeout", type=float, default=900.0, help="s per calibrate")
    ap.add_argument("--out", default=str(RESULTS))
    ap.add_argument(
        "--plate-plan",
        choices=PLATE_PLANS,
        default="reach_limited",
        help="the generator's plate plan (default reach_limited: the plan this diagnosis was "
        "written for and its recorded results were run with; full_reach: the lab's plan)",
    )
    args = ap.parse_args(argv)
    args.orders = [int(p) for p in args.orders.split(",")]
    seeds = [int(s) for s in json.loads(Path(args.replay).read_text())["seeds"]]
    if args.first:
        seeds = seeds[: args.first]
    rows: list[dict[str, Any]] = []
    with tempfile.TemporaryDirectory(prefix="plate_reach_") as tmp:
        for i, seed in enumerate(seeds):
            row = run_one(seed, MODELS[i % len(MODELS)], Path(tmp), args)
            rows.append(row)
            text = " | ".join(
                f"{k} {100 * row[k]['rms_ratio']:.1f} % (in reach "
                f"{100 * row[k]['rms_ratio_in_reach']:.1f} %)"
                for k in ["ours", *(f"simple_P{p}" for p in args.orders)]
                if k in row
            )
            print(f"[{i + 1}/{len(seeds)}] {row['model']} {seed}: {text}", flush=True)
    keys = ["ours", *(f"simple_P{p}" for p in args.orders)]
    summary = {k: _summary(rows, k) for k in keys}
    for k, s in summary.items():
        print(
            f"{k:<10} RMS median {100 * s['rms_ratio_median']:.1f} %, max "
            f"{100 * s['rms_ratio_max']:.1f} %, ≤ 20 %: {s['within_20pct']}/{s['machines']}; "
            f"in reach median {100 * s['rms_ratio_in_reach_median']:.1f} %, max "
            f"{100 * s['rms_ratio_in_reach_max']:.1f} %"
        )
    doc = {
        "benchmark": "calibration_plate_reach",
        "date": datetime.now(UTC).isoformat(timespec="seconds"),
        "command": " ".join([Path(sys.argv[0]).name, *(argv or sys.argv[1:])]),
        "replay": args.replay,
        "plate_plan": args.plate_plan,
        "rcond": args.rcond,
        "summary": summary,
        "cases": rows,
    }
    out = Path(args.out)
    out.parent.mkdir(parents=True, exist_ok=True)
    text = json.dumps(doc, indent=1, default=float).replace("NaN", "null")
    out.write_text(text + "\n", encoding="utf-8")
    print(f"wrote {out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
