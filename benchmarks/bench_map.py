"""Benchmark: `cmm-comp map` of a 20×20×20 grid (target < 2 s), against a baseline in the same run.

Baseline: scipy's cubic spline evaluation of 21 tables at the same 8000 nodes (the unavoidable
part of any parametric-model map). Prints a table and writes benchmarks/results/map.json.
Run: ``python benchmarks/bench_map.py``.
"""

from __future__ import annotations

import json
import platform
import time
from pathlib import Path

import numpy as np
from scipy.interpolate import CubicSpline

from cmm_comp.compensation.machine import Machine
from cmm_comp.compensation.reports.maps import volumetric_map

ROOT = Path(__file__).resolve().parents[1]
OUT = ROOT / "benchmarks" / "results" / "map.json"


def best_of(fn, repeat: int = 5) -> float:
    times = []
    for _ in range(repeat):
        t0 = time.perf_counter()
        fn()
        times.append(time.perf_counter() - t0)
    return min(times)


def main() -> None:
    rows = []
    for name in ("npl-bridge", "gec-mh2"):
        machine = Machine.from_toml(ROOT / "examples" / "machines" / f"{name}.toml")
        steps = (20, 20, 20)
        nodes = np.stack(np.meshgrid(*machine.volume.nodes(steps), indexing="ij"), -1).reshape(
            -1, 3
        )
        q = np.linspace(0, 1000, 20)
        splines = [CubicSpline(q, np.sin(q / 100 + k)) for k in range(21)]

        def baseline(nodes=nodes, splines=splines) -> None:
            for k, s in enumerate(splines):
                s(nodes[:, k % 3])

        t_base = best_of(baseline)
        t_map = best_of(lambda machine=machine, steps=steps: volumetric_map(machine, steps))
        t_load = best_of(
            lambda name=name: Machine.from_toml(ROOT / "examples" / "machines" / f"{name}.toml")
        )
        rows.append(
            {
                "machine": name,
                "nodes": int(np.prod(steps)),
                "map_s": t_map,
                "load_s": t_load,
                "baseline_splines_s": t_base,
                "ratio_map_to_baseline": t_map / t_base,
                "target_s": 2.0,
                "meets_target": t_map + t_load < 2.0,
            }
        )
    import subprocess
    import sys
    import tempfile

    with tempfile.TemporaryDirectory() as tmp:
        cmd = [
            sys.executable,
            "-m",
            "cmm_comp.cli",
            "map",
            str(ROOT / "examples" / "machines" / "npl-bridge.toml"),
            "--out",
            f"{tmp}/map.csv",
            "--steps",
            "20",
            "20",
            "20",
        ]
        t_cli = best_of(lambda: subprocess.run(cmd, check=True, capture_output=True), repeat=3)
        base_cmd = [sys.executable, "-c", "import numpy, scipy.interpolate"]
        t_py = best_of(lambda: subprocess.run(base_cmd, check=True, capture_output=True), repeat=3)
    rows.append(
        {
            "machine": "npl-bridge (whole `cmm-comp map` process)",
            "nodes": 8000,
            "cli_s": t_cli,
            "baseline_python_numpy_scipy_import_s": t_py,
            "ratio_cli_to_baseline": t_cli / t_py,
            "target_s": 2.0,
            "meets_target": t_cli < 2.0,
        }
    )
    print(
        f"cmm-comp map 20×20×20, whole process: {t_cli:.2f} s (python+numpy+scipy start {t_py:.2f} s, "
        f"ratio {t_cli / t_py:.1f}); target < 2 s: {'yes' if t_cli < 2 else 'NO'}"
    )
    print(
        f"{'machine':<12} {'nodes':>6} {'map s':>8} {'load s':>8} {'baseline s':>11} {'ratio':>7}  target < 2 s"
    )
    for r in rows:
        if "map_s" not in r:
            continue
        print(
            f"{r['machine']:<12} {r['nodes']:>6} {r['map_s']:>8.4f} {r['load_s']:>8.4f} "
            f"{r['baseline_splines_s']:>11.5f} {r['ratio_map_to_baseline']:>7.1f}  {'yes' if r['meets_target'] else 'NO'}"
        )
    OUT.parent.mkdir(parents=True, exist_ok=True)
    OUT.write_text(json.dumps({"machine": platform.node(), "results": rows}, indent=2) + "\n")
    print(f"wrote {OUT}")


if __name__ == "__main__":
    main()
