"""Correction-grid benchmark: ``python benchmarks/bench_grid.py`` prints a table, writes JSON.

* batch: 1M random points through ``CorrectionGrid.correct`` vs scipy's linear
  ``RegularGridInterpolator`` on the same 20×20×10 grid (3 values per node: the translation,
  and 7: the whole node pose), median of 5 interleaved runs;
* single point: ``correct_point`` and ``correct`` on one reading, p50/p99 µs, vs a bare numpy
  call measured in the same run;
* build: ``CorrectionGrid.build`` at 50×50×50 on the example machine (target < 10 s);
* uncertainty (issue 13): the same 20×20×10 grid carrying U per node — its correction path with
  U not asked for vs the grid without U (the hot path may not slow down by more than 10 %), and
  with ``correct_with_uncertainty`` (the extra cost of U), batch and single point, interleaved in
  the same run.

Run: ``python benchmarks/bench_grid.py [--points N] [--compare DIR] [--rounds N]``. ``--compare`` takes another
checkout of this repository (e.g. ``git archive main | tar -x -C DIR``) and measures both trees in
alternating subprocess rounds (the same measurement code, imported against each tree), printing
each figure of this tree and its ratio this ÷ that (medians over the rounds). Writes
benchmarks/results/grid.json (not with --compare). A tree from before issue 26 has no
``correct_with_uncertainty``: its ``correct(..., with_uncertainty=True)`` is measured instead.
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
from typing import Any

import numba
import numpy as np
from scipy.interpolate import RegularGridInterpolator

ROOT = Path(__file__).resolve().parents[1]

from cmm_comp.compensation.grid import CorrectionGrid  # noqa: E402
from cmm_comp.compensation.machine import Machine  # noqa: E402
from cmm_comp.compensation.uncertainty.grid_field import add_uncertainty  # noqa: E402


def _median_time(fn, reps: int) -> float:  # type: ignore[no-untyped-def]
    times = []
    for _ in range(reps):
        t0 = time.perf_counter()
        fn()
        times.append(time.perf_counter() - t0)
    return float(np.median(times))


def _percentiles_us(fn, n: int) -> tuple[float, float]:  # type: ignore[no-untyped-def]
    times = np.empty(n)
    for i in range(n):
        t0 = time.perf_counter()
        fn()
        times[i] = time.perf_counter() - t0
    return float(np.percentile(times, 50) * 1e6), float(np.percentile(times, 99) * 1e6)


def _with_u(grid: CorrectionGrid) -> Any:
    """``correct_with_uncertainty`` of ``grid``, or the flag of a tree from before issue 26."""
    if hasattr(grid, "correct_with_uncertainty"):
        return grid.correct_with_uncertainty
    return lambda *a: grid.correct(*a, with_uncertainty=True)  # type: ignore[call-arg]


def measure(n: int = 1_000_000) -> dict[str, Any]:
    """Every figure of the module docstring for ``n`` batch points, on the tree ``cmm_comp`` is
    imported from (the kernels are compiled or loaded before anything is timed)."""
    machine = Machine.from_toml(ROOT / "examples" / "machines" / "npl-bridge.toml")
    temps = dict(machine.runtime_signals())
    warm_t0 = time.perf_counter()
    grid = CorrectionGrid.build(machine, steps=(20, 20, 10))
    first_build_s = time.perf_counter() - warm_t0
    rng = np.random.default_rng(0)
    pts = rng.uniform(machine.volume.lower_mm, machine.volume.upper_mm, size=(n, 3))
    stylus = np.array([0.0, 0.0, -120.0])
    ugrid = add_uncertainty(grid, machine, rng=np.random.default_rng(0), trials=200)
    ugrid_with_u = _with_u(ugrid)
    ugrid_with_u(pts[:1000], stylus, temps)
    rgi3 = RegularGridInterpolator(grid.axes, grid.translation_um, method="linear")
    pose7 = np.concatenate([grid.q_work_stylus, grid.translation_um], axis=-1)
    rgi7 = RegularGridInterpolator(grid.axes, pose7, method="linear")
    grid.correct(pts[:1000], stylus, temps)
    rgi3(pts[:1000])
    runs: dict[str, list[float]] = {
        "grid": [],
        "grid_temps": [],
        "rgi3": [],
        "rgi7": [],
        "ugrid_no_u": [],
        "ugrid_with_u": [],
    }
    t_shift = {k: np.full(n, 21.0) for k in temps}
    for _ in range(5):  # interleaved, so that load changes hit all alike
        runs["rgi3"].append(_median_time(lambda: rgi3(pts), 1))
        runs["grid"].append(_median_time(lambda: grid.correct(pts, stylus, temps), 1))
        runs["ugrid_no_u"].append(_median_time(lambda: ugrid.correct(pts, stylus, temps), 1))
        runs["ugrid_with_u"].append(_median_time(lambda: ugrid_with_u(pts, stylus, temps), 1))
        runs["rgi7"].append(_median_time(lambda: rgi7(pts), 1))
        runs["grid_temps"].append(_median_time(lambda: grid.correct(pts, stylus, t_shift), 1))
    batch = {k: float(np.median(v)) for k, v in runs.items()}
    p = tuple(pts[0])
    t_scalar = {k: 21.0 for k in temps}
    one = pts[:1]
    single: dict[str, tuple[float, float]] = {}
    for _ in range(2):  # interleaved halves: the grid with U and without alike
        for key, fn in (
            ("correct_point", lambda: grid.correct_point(p, stylus, t_scalar)),
            ("correct_point_ugrid", lambda: ugrid.correct_point(p, stylus, t_scalar)),
            ("uncertainty_point_ugrid", lambda: ugrid.uncertainty_point(p, stylus, t_scalar)),
            ("correct_N1", lambda: grid.correct(one, stylus, t_scalar)),
            ("numpy_add_baseline", lambda: np.add(one, 1.0)),
        ):
            p50, p99 = _percentiles_us(fn, 10000)
            old = single.get(key)
            single[key] = (p50, p99) if old is None else ((old[0] + p50) / 2, (old[1] + p99) / 2)
    t0 = time.perf_counter()
    CorrectionGrid.build(machine, steps=(50, 50, 50))
    build50 = time.perf_counter() - t0
    return {
        "machine": machine.name,
        "grid_steps": [20, 20, 10],
        "points": n,
        "threads": numba.get_num_threads(),
        "cpu_count": os.cpu_count(),
        "python": platform.python_version(),
        "batch_s": batch,
        "ratio_vs_rgi_linear_3values": batch["grid"] / batch["rgi3"],
        "ratio_vs_rgi_linear_7values": batch["grid"] / batch["rgi7"],
        "ratio_with_temperatures_vs_rgi3": batch["grid_temps"] / batch["rgi3"],
        "ratio_hot_path_grid_with_u_stored_vs_without": batch["ugrid_no_u"] / batch["grid"],
        "ratio_correct_with_uncertainty_vs_without": batch["ugrid_with_u"] / batch["grid"],
        "ratio_single_correct_point_ugrid_vs_grid": single["correct_point_ugrid"][0]
        / single["correct_point"][0],
        "single_point_us": {k: {"p50": v[0], "p99": v[1]} for k, v in single.items()},
        "build_50x50x50_s": build50,
        "first_build_20x20x10_s_incl_kernel_load": first_build_s,
    }


def _print(result: dict[str, Any]) -> None:
    batch, single, build50 = (
        result["batch_s"],
        result["single_point_us"],
        result["build_50x50x50_s"],
    )
    print(f"grid benchmark on {result['machine']}, {result['threads']} numba threads")
    print(f"{'case':<46}{'value':>12}")
    for key, val in batch.items():
        print(f"{'batch ' + key + ' (s)':<46}{val:>12.3f}")
    print(
        f"{'ratio grid / RGI linear (3 values)':<46}{result['ratio_vs_rgi_linear_3values']:>12.2f}"
    )
    print(
        f"{'ratio grid / RGI linear (7 values)':<46}{result['ratio_vs_rgi_linear_7values']:>12.2f}"
    )
    print(
        f"{'ratio grid with temperatures / RGI (3)':<46}{result['ratio_with_temperatures_vs_rgi3']:>12.2f}"
    )
    print(
        f"{'ratio hot path, grid carrying U / without':<46}"
        f"{result['ratio_hot_path_grid_with_u_stored_vs_without']:>12.3f}"
    )
    print(
        f"{'ratio correct with U returned / without':<46}"
        f"{result['ratio_correct_with_uncertainty_vs_without']:>12.3f}"
    )
    for key, v in single.items():
        print(f"{'single ' + key + ' p50 / p99 (µs)':<46}{v['p50']:>6.1f} /{v['p99']:>5.1f}")
    print(f"{'build 50×50×50 (s)':<46}{build50:>12.2f}")


def _figures(result: dict[str, Any]) -> dict[str, float]:
    """The compared figures: batch seconds, single-point p50/p99 µs, the 50³ build."""
    out = {f"batch {k} (s)": v for k, v in result["batch_s"].items()}
    for key, v in result["single_point_us"].items():
        out[f"single {key} p50 (µs)"] = v["p50"]
        out[f"single {key} p99 (µs)"] = v["p99"]
    out["build 50×50×50 (s)"] = result["build_50x50x50_s"]
    # the same round's scipy and numpy calls (the same code in both trees) cancel load drift
    for k, v in result["batch_s"].items():
        out[f"batch {k} ÷ rgi3 of the round"] = v / result["batch_s"]["rgi3"]
    base = result["single_point_us"]["numpy_add_baseline"]["p50"]
    for key, v in result["single_point_us"].items():
        out[f"single {key} p50 ÷ numpy p50 of the round"] = v["p50"] / base
    return out


def _round(env: dict[str, str], n: int) -> dict[str, float]:
    """One :func:`measure` in a fresh interpreter importing ``cmm_comp`` as ``env`` says."""
    code = (
        "import json, sys; sys.path.insert(0, sys.argv[1]); import bench_grid as b; "
        "print(json.dumps(b.measure(int(sys.argv[2]))))"
    )
    run = subprocess.run(
        [sys.executable, "-c", code, str(Path(__file__).parent), str(n)],
        check=True,
        env=env,
        capture_output=True,
        text=True,
    )
    return _figures(json.loads(run.stdout))


def compare(other: Path, rounds: int, n: int) -> None:
    """Both trees in alternating rounds; this tree's medians and the ratios this ÷ other."""
    from bench_config_load import shim_env

    with tempfile.TemporaryDirectory() as tmp:
        envs = {"this": dict(os.environ), "other": shim_env(other, Path(tmp))}
        runs: dict[str, list[dict[str, float]]] = {k: [] for k in envs}
        for _ in range(rounds):
            for key, env in envs.items():
                runs[key].append(_round(env, n))
    med = {k: {f: statistics.median(r[f] for r in v) for f in v[0]} for k, v in runs.items()}
    print(f"{rounds} alternating rounds per tree, {n} batch points; this tree ÷ {other}")
    print(f"{'figure':<52}{'this':>10}{'other':>10}{'ratio':>8}")
    for f, this in med["this"].items():
        print(f"{f:<52}{this:>10.4g}{med['other'][f]:>10.4g}{this / med['other'][f]:>8.3f}")


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--compare", type=Path, help="another checkout, measured alternately")
    ap.add_argument("--rounds", type=int, default=3, help="rounds per tree with --compare")
    ap.add_argument("--points", type=int, default=1_000_000, help="batch points")
    args = ap.parse_args(argv)
    if args.compare is not None:
        compare(args.compare.resolve(), args.rounds, args.points)
        return 0
    result = measure(args.points)
    _print(result)
    out = ROOT / "benchmarks" / "results" / "grid.json"
    out.parent.mkdir(parents=True, exist_ok=True)
    out.write_text(json.dumps(result, indent=1))
    print(f"wrote {out.relative_to(ROOT)}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
