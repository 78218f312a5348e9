"""Default grid steps follow the error tables: a grid built without ``steps`` meets the accuracy
target (1 % of the error size or 0.02 µm) on both bundled machines. Oracle: the exact model."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from cmm_comp.compensation import CorrectionGrid, Machine
from cmm_comp.compensation.grid import default_steps

ROOT = Path(__file__).resolve().parents[1]


@pytest.mark.parametrize(
    ("name", "expected"), [("gec-mh2", (31, 21, 21)), ("npl-bridge", (31, 40, 16))]
)
def test_default_grid_meets_the_accuracy_target(name: str, expected: tuple[int, int, int]) -> None:
    machine = Machine.from_toml(ROOT / "examples" / "machines" / f"{name}.toml")
    # tables every 100 mm (gec) / 50 mm (npl): nodes at most 0.6× that apart, never fewer than
    # the machine's own volume.steps
    assert default_steps(machine) == expected
    grid = CorrectionGrid.build(machine)
    assert grid.steps == expected
    rng = np.random.default_rng(7)
    n = 2000
    pts = rng.uniform(machine.volume.lower_mm, machine.volume.upper_mm, (n, 3))
    stylus = rng.uniform(-150, 150, (n, 3))
    temps = {k: rng.uniform(16, 24, n) for k in ("T_x", "T_y", "T_z", "T_wp")}
    exact = machine.volumetric_error(pts, stylus, temps)
    got, status = grid.correct(pts, stylus, temps)
    assert (status == "ok").all()
    err = np.linalg.norm((got - pts) * 1000 - exact, axis=1)
    allowance = np.maximum(0.01 * np.linalg.norm(exact, axis=1), 0.02)
    assert (err <= allowance).all(), f"worst at {np.max(err / allowance):.2f}× the allowance"
