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
"""

from __future__ import annotations

import json
import os
import platform
import time
from pathlib import Path

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


def main() -> int:
    machine = Machine.from_toml(ROOT / "examples" / "machines" / "npl-bridge.toml")
    temps = dict(machine.runtime_signals())
    warm_t0 = time.perf_counter()
    grid = CorrectionGrid.build(machine, steps=(20, 20, 10))
    first_build_s = time.perf_counter() - warm_t0
    rng = np.random.default_rng(0)
    n = 1_000_000
    pts = rng.uniform(machine.volume.lower_mm, machine.volume.upper_mm, size=(n, 3))
    stylus = np.array([0.0, 0.0, -120.0])
    ugrid = add_uncertainty(grid, machine, rng=np.random.default_rng(0), trials=200)
    ugrid.correct_with_uncertainty(pts[:1000], stylus, temps)
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
        runs["ugrid_with_u"].append(
            _median_time(lambda: ugrid.correct_with_uncertainty(pts, stylus, temps), 1)
        )
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
    result = {
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
    print(f"grid benchmark on {machine.name}, {numba.get_num_threads()} numba threads")
    print(f"{'case':<46}{'value':>12}")
    for key, val in batch.items():
        print(f"{'batch 1M ' + key + ' (s)':<46}{val:>12.3f}")
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
    for key, (p50, p99) in single.items():
        print(f"{'single ' + key + ' p50 / p99 (µs)':<46}{p50:>6.1f} /{p99:>5.1f}")
    print(f"{'build 50×50×50 (s)':<46}{build50:>12.2f}")
    out = ROOT / "benchmarks" / "results" / "grid.json"
    out.parent.mkdir(parents=True, exist_ok=True)
    out.write_text(json.dumps(result, indent=1))
    print(f"wrote {out.relative_to(ROOT)}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
