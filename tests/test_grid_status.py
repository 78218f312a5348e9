"""The batch path (``CorrectionGrid.correct``) and the single-reading path
(``CorrectionGrid.correct_point``, the daemon's hot path) apply the same status rule and give the
same corrected coordinates, for random points and random combinations of the per-point flags:
outside the volume (both policies), NaN/inf coordinates or stylus, missing or NaN temperatures,
missing or NaN non-temperature inputs. Oracle: each path against the other, point by point."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np
import pytest

from cmm_comp.compensation import CorrectionGrid, Machine
from cmm_comp.compensation.grid.status import REFUSED_STATUSES, STATUS_BY_FLAGS, point_status

ROOT = Path(__file__).resolve().parents[1]
NPL = ROOT / "examples" / "machines" / "npl-bridge.toml"
ALL_STATUSES = {
    "ok",
    "missing_input",
    "no_temperature",
    "clamped_outside_volume",
    "outside_volume",
    "invalid_input",
}


@pytest.fixture(scope="module")
def grid() -> CorrectionGrid:
    base = Machine.from_toml(NPL)
    data = dict(base.description)
    data["effects"] = [
        {"cause": "reversal", "axis": "x", "half_step_um": [2.0, 0.5], "span_mm": [0.0, 900.0]}
    ]
    return CorrectionGrid.build(Machine.from_dict(data), steps=(6, 6, 5))


def _case(
    grid: CorrectionGrid, rng: np.random.Generator, n: int
) -> tuple[np.ndarray, np.ndarray, dict[str, Any], dict[str, Any]]:
    lo, hi = grid.lower_mm, grid.upper_mm
    span = hi - lo
    pts = rng.uniform(lo - 0.2 * span, hi + 0.2 * span, size=(n, 3))
    edge = rng.random(n) < 0.1  # just inside / just outside the tolerance
    pts[edge, 0] = hi[0] + rng.choice([0.5e-9, 2e-9, -1e-3], size=int(edge.sum()))
    inside = rng.random(n) < 0.4
    pts[inside] = rng.uniform(lo, hi, size=(int(inside.sum()), 3))
    pts[rng.random(n) < 0.05, rng.integers(0, 3)] = np.nan
    pts[rng.random(n) < 0.02, rng.integers(0, 3)] = np.inf
    stylus = rng.uniform(-150.0, 150.0, size=(n, 3))
    stylus[rng.random(n) < 0.04, rng.integers(0, 3)] = np.nan
    temps: dict[str, Any] = {}
    for name in ("T_x", "T_y", "T_z", "T_wp"):
        if rng.random() < 0.15:
            continue  # this temperature is missing altogether
        t = rng.uniform(18.0, 23.0, size=n)
        t[rng.random(n) < 0.1] = np.nan
        temps[name] = t
    inputs: dict[str, Any] = {}
    if rng.random() < 0.85:
        d = rng.choice([-1.0, 0.0, 1.0], size=n)
        d[rng.random(n) < 0.1] = np.nan
        inputs["dir_x"] = d
    return pts, stylus, temps, inputs


@pytest.mark.parametrize("policy", ["refuse", "clamp"])
def test_batch_and_single_point_paths_agree(grid: CorrectionGrid, policy: str) -> None:
    seen: set[str] = set()
    for seed in range(12):
        rng = np.random.default_rng(seed)
        n = 300 if seed % 2 else 40  # the batch runs the parallel kernel from 256 points on
        pts, stylus, temps, inputs = _case(grid, rng, n)
        out, status = grid.correct(pts, stylus, temps, inputs, outside=policy)
        for i in range(n):
            one_t = {k: float(v[i]) for k, v in temps.items()}
            one_i = {k: float(v[i]) for k, v in inputs.items()}
            c, st = grid.correct_point(pts[i], stylus[i], one_t, one_i, outside=policy)
            assert st == status[i], (seed, i, pts[i], stylus[i], one_t, one_i)
            np.testing.assert_allclose(c, out[i], rtol=0, atol=1e-9, equal_nan=True)
            assert np.isnan(c).all() == (st in REFUSED_STATUSES)
        seen.update(status.tolist())
    expected = ALL_STATUSES - {"outside_volume" if policy == "clamp" else "clamped_outside_volume"}
    assert seen == expected  # every status was exercised


def test_the_rule_is_first_applicable_reason() -> None:
    # invalid > outside > no temperature > missing input > ok, for every flag combination
    for refuse in (False, True):
        table = STATUS_BY_FLAGS[refuse]
        for flags, status in enumerate(table):
            assert status == point_status(flags, refuse)
            if flags & 1:
                assert status == "invalid_input"
            elif flags & 2:
                assert status == ("outside_volume" if refuse else "clamped_outside_volume")
            elif flags & 4:
                assert status == "no_temperature"
            elif flags & 8:
                assert status == "missing_input"
            else:
                assert status == "ok"
