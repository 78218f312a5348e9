"""Write the golden grids and the corrections the code that wrote them computed (tests/data/grid_golden.md).

Run: ``python tests/grid_golden.py OUT_DIR``. It uses whichever ``cmm_comp`` is
importable, so pointing ``PYTHONPATH`` at an older tree records that tree's answers; it speaks
both the API before issue 26 (``correct(..., with_uncertainty=True)``) and after it
(``correct_with_uncertainty``). Every case is deterministic (fixed seeds, fixed build stamps).
"""

from __future__ import annotations

import sys
from pathlib import Path
from typing import Any

import numpy as np

from cmm_comp.compensation import Machine
from cmm_comp.compensation.grid import CorrectionGrid
from cmm_comp.compensation.grid.field import AnalyticErrorField
from cmm_comp.compensation.uncertainty.grid_field import add_uncertainty

ROOT = Path(__file__).resolve().parents[1]
STAMP = {"built_utc": "2026-11-27T00:00:00+00:00", "library_version": "0.1.0"}


def golden_grids() -> dict[str, CorrectionGrid]:
    """``npl``: the example machine with U (small rotations: the kernels' series branch);
    ``wide``: an analytic field with 40 mrad rotations (the general branch), no U."""
    machine = Machine.from_toml(ROOT / "examples" / "machines" / "npl-bridge.toml")
    npl = CorrectionGrid.build(machine, steps=(7, 6, 5))
    npl = add_uncertainty(npl, machine, rng=np.random.default_rng(26), seed=26, trials=40)
    wide = CorrectionGrid.build(
        AnalyticErrorField(rotation_urad=40_000.0, translation_um=30.0), steps=(6, 7, 5)
    )
    for grid in (npl, wide):
        grid.metadata.update(STAMP)
    return {"npl": npl, "wide": wide}


def _with_u(grid: Any, *args: Any, **kwargs: Any) -> tuple[Any, Any, Any]:
    if hasattr(grid, "correct_with_uncertainty"):
        return grid.correct_with_uncertainty(*args, **kwargs)  # type: ignore[no-any-return]
    return grid.correct(*args, with_uncertainty=True, **kwargs)  # type: ignore[no-any-return]


def cases(grid: CorrectionGrid, signals: list[str]) -> dict[str, np.ndarray]:
    """Every correction entry point on points inside, on and outside the volume, NaN rows,
    per-point styli and signals (arrays, scalars, NaN, at and off the reference)."""
    rng = np.random.default_rng(7)
    n = 300
    span = grid.upper_mm - grid.lower_mm
    pts = rng.uniform(grid.lower_mm - 0.05 * span, grid.upper_mm + 0.05 * span, (n, 3))
    pts[:20] = rng.uniform(grid.lower_mm, grid.upper_mm, (20, 3))
    pts[20] = grid.lower_mm
    pts[21] = grid.upper_mm
    pts[22, 1] = np.nan
    sty = rng.normal(0.0, 80.0, (n, 3))
    sty[23, 2] = np.inf
    temps: dict[str, Any] = {s: rng.uniform(16.0, 26.0, n) for s in signals}
    temps[signals[0]][24] = np.nan
    temps[signals[-1]] = 21.5  # a scalar among arrays
    ref = dict.fromkeys(signals, 20.0)
    out: dict[str, np.ndarray] = {"points": pts, "stylus": sty}
    for tag, t in (("temps", temps), ("ref", ref), ("none", None)):
        c, s = grid.correct(pts, sty, t)
        out[f"correct_{tag}"], out[f"status_{tag}"] = c, s
        c, s = grid.correct(pts[:40], sty[:40], _rows(t, 40))  # the serial batch path
        out[f"correct40_{tag}"], out[f"status40_{tag}"] = c, s
    c, s = grid.correct(pts, sty, temps, outside="clamp")
    out["correct_clamp"], out["status_clamp"] = c, s
    c, s, u = _with_u(grid, pts, sty, temps)
    out["u_correct"], out["u_status"], out["u_um"] = c, s, u
    q, t, s = grid.pose(pts, temps)
    out["pose_q"], out["pose_t"], out["pose_status"] = q, t, s
    e, s = grid.error_um(pts, sty, temps)
    out["error_um"], out["error_status"] = e, s
    cmd, s = grid.command_for_target(pts[:60], sty[:60], _rows(temps, 60))
    out["command"], out["command_status"] = cmd, s
    single_c, single_s, single_u, n1_c, n1_s = [], [], [], [], []
    for i in range(0, n, 7):
        scal = {k: float(np.broadcast_to(v, (n,))[i]) for k, v in temps.items()}
        c1, s1, u1 = grid.correct_point_with_uncertainty(pts[i], sty[i], scal)
        c0, s0 = grid.correct_point(pts[i], sty[i], scal)
        assert (s0, np.array_equal(c0, c1, equal_nan=True)) == (s1, True)
        single_c.append(c1)
        single_s.append(s1)
        single_u.append(u1)
        cn, sn = grid.correct(pts[i : i + 1], sty[i], scal)  # one row: the single path
        n1_c.append(cn[0])
        n1_s.append(sn[0])
    out["point_correct"] = np.array(single_c)
    out["point_status"] = np.array(single_s)
    out["point_u"] = np.array(single_u)
    out["n1_correct"] = np.array(n1_c)
    out["n1_status"] = np.array(n1_s)
    return out


def _rows(temps: dict[str, Any] | None, n: int) -> dict[str, Any] | None:
    if temps is None:
        return None
    return {k: (v[:n] if np.ndim(v) else v) for k, v in temps.items()}


def main(out_dir: Path) -> None:
    out_dir.mkdir(parents=True, exist_ok=True)
    expected: dict[str, np.ndarray] = {}
    for name, grid in golden_grids().items():
        path = out_dir / f"grid_golden_{name}.grid"
        grid.save(path)
        loaded = CorrectionGrid.load(path)
        print(f"{path.name}: sha256 {loaded.sha256}")
        signals = [s.name for s in loaded.signals]
        for key, value in cases(loaded, signals).items():
            expected[f"{name}/{key}"] = value
    np.savez_compressed(out_dir / "grid_golden_expected.npz", **expected)


if __name__ == "__main__":
    main(Path(sys.argv[1]))
