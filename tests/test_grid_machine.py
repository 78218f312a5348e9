"""Accuracy target on the real model: a 20×20×10 grid reproduces ``machine.volumetric_error``
within 1 % of the error size (or 0.02 µm) at random points, stylus offsets and temperatures."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from cmm_comp.compensation.grid import CorrectionGrid
from cmm_comp.compensation.machine import Machine

EXAMPLE = Path(__file__).resolve().parents[1] / "examples" / "machines" / "npl-bridge.toml"


@pytest.fixture(scope="module")
def machine() -> Machine:
    return Machine.from_toml(EXAMPLE)


def test_20x20x10_grid_within_1_percent(machine: Machine, tmp_path: Path) -> None:
    grid = CorrectionGrid.build(machine, steps=(20, 20, 10))
    path = tmp_path / "npl.grid"
    grid.save(path)
    grid = CorrectionGrid.load(path, expect_machine=machine)
    rng = np.random.default_rng(20240517)
    n = 5000
    pts = rng.uniform(machine.volume.lower_mm, machine.volume.upper_mm, size=(n, 3))
    stylus = rng.uniform(-150.0, 150.0, size=(n, 3))
    temps = {name: rng.uniform(16.0, 24.0, n) for name in machine.runtime_signals()}
    exact_um = machine.volumetric_error(pts, stylus_mm=stylus, temps_C=temps)
    corrected, status = grid.correct(pts, stylus, temps)
    assert np.all(status == "ok")
    err = np.linalg.norm((corrected - pts) * 1000.0 - exact_um, axis=1)
    allowed = np.maximum(0.01 * np.linalg.norm(exact_um, axis=1), 0.02)
    assert np.all(err <= allowed), f"worst {np.max(err / allowed):.2f} of allowed"
    # the corrected point is the true one: indicated + error
    np.testing.assert_allclose(corrected, pts + exact_um / 1000.0, atol=allowed.max() / 1000.0)


def test_sensitivities_are_linear_on_the_real_model(machine: Machine) -> None:
    grid = CorrectionGrid.build(machine, steps=(6, 6, 4))
    for name, nl in grid.metadata["nonlinearity"].items():
        assert nl["translation_um"] < 1e-9 and nl["rotation_urad"] < 1e-9, name
    assert {s.name for s in grid.signals} == set(machine.runtime_signals())
    pts = np.random.default_rng(1).uniform(
        machine.volume.lower_mm, machine.volume.upper_mm, (200, 3)
    )
    for name in machine.runtime_signals():
        temps = {k: 20.0 for k in machine.runtime_signals()} | {name: 27.0}
        got, _ = grid.error_um(pts, (0, 0, -120), temps)
        base, _ = grid.error_um(pts, (0, 0, -120), {k: 20.0 for k in machine.runtime_signals()})
        exact = machine.volumetric_error(pts, (0, 0, -120), temps) - machine.volumetric_error(
            pts, (0, 0, -120), {k: 20.0 for k in machine.runtime_signals()}
        )
        np.testing.assert_allclose(got - base, exact, atol=1e-6)
