"""Random-error propagation (paper section 5.1) against a Monte Carlo of the exact model.

``Machine.random_error`` gives the 2σ random volumetric error from the first-order partial
derivatives and the 2σ random parts of the parametric errors. The oracle samples every random
component independently as a Gaussian with σ = band/2 at the point, pushes each sample through
the exact rigid-body chain (``kinematics.exact_pose``, the same evaluation as
``Machine.volumetric_error``) and compares 2·std with the formula.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np
import pytest

from cmm_comp.compensation.kinematics import exact_pose
from cmm_comp.compensation.machine import Machine
from cmm_comp.compensation.parametric_errors import AXIS_INDEX, TABLE_COMPONENTS

ROOT = Path(__file__).resolve().parents[1]
SAMPLES = 20_000
#: relative standard error of a standard deviation from n samples is 1/sqrt(2n) ≈ 0.5 %
REL_TOL = 0.03


def synthetic_machine(model: str, seed: int = 0, probe_um: float = 0.0) -> Machine:
    """Every table with a random part: tabulated (varying along the axis) or a uniform band."""
    rng = np.random.default_rng(seed)
    upper = np.array([700.0, 900.0, 500.0])
    errors: dict[str, Any] = {}
    for i, comp in enumerate(TABLE_COMPONENTS):
        k = AXIS_INDEX[comp[3]]
        pos = np.linspace(0.0, upper[k], 8)
        amp = 8.0 if comp[0] == "e" else 2.0
        errors[comp] = {"position": pos.tolist(), "value": rng.normal(0, amp, 8).tolist()}
        if i % 2:
            errors[comp]["random_band"] = float(rng.uniform(0.5, 3.0))
        else:
            errors[comp]["random"] = rng.uniform(0.2, 4.0, 8).tolist()
    data = {
        "name": f"mc-{model}",
        "model": model,
        "volume": {
            "x": [0.0, upper[0]],
            "y": [0.0, upper[1]],
            "z": [0.0, upper[2]],
            "reference": [50.0, 100.0, 0.0],
        },
        "probe": {"random_um": probe_um},
        "squareness": {
            "alpha": 5.0,
            "beta1": -3.0,
            "beta2": 2.0,
            "random": {"alpha": 2.0, "beta1": 1.5, "beta2": 3.0},
        },
        "errors": errors,
    }
    return Machine.from_dict(data)


def monte_carlo_2sigma(
    machine: Machine, point_mm: np.ndarray, stylus_mm: np.ndarray, rng: np.random.Generator
) -> np.ndarray:
    """2·std (3,) µm of the exact-model volumetric error under the random parts at one point."""
    q = np.repeat(point_mm[None, :], SAMPLES, axis=0)
    errors = machine.parametric_errors(q)
    sigma = np.zeros((3, 6))
    for table in machine.tables.values():
        c = table.component
        k = AXIS_INDEX[c.axis]
        sigma[k, c.slot] = table.evaluate_random(np.array([point_mm[k]]))[0] / 2.0
    errors = errors + rng.standard_normal(errors.shape) * sigma
    squareness = machine.squareness_urad + rng.standard_normal((SAMPLES, 3)) * (
        machine.squareness_random_urad / 2.0
    )
    u = q - machine.volume.reference_mm
    rot, t_um = exact_pose(machine.chain, u, errors, squareness)
    err = t_um + 1000.0 * np.einsum("nij,j->ni", rot - np.eye(3), stylus_mm)
    err = err + rng.standard_normal((SAMPLES, 3)) * machine.probe.random_um / 2.0
    return 2.0 * err.std(axis=0, ddof=1)


def check(machine: Machine, points: np.ndarray, stylus: np.ndarray, seed: int) -> None:
    rng = np.random.default_rng(seed)
    formula = machine.random_error(points, stylus)
    for point, expected in zip(points, formula, strict=True):
        mc = monte_carlo_2sigma(machine, point, stylus, rng)
        np.testing.assert_allclose(mc, expected, rtol=REL_TOL, atol=1e-6, err_msg=f"at {point}")


@pytest.mark.parametrize("model", ["MB2", "FB1", "MH1", "FH2", "CY1"])
def test_formula_matches_monte_carlo_of_the_exact_model(model: str) -> None:
    machine = synthetic_machine(model, seed=sum(map(ord, model)), probe_um=0.8)
    points = np.array([[650.0, 850.0, 450.0], [120.0, 400.0, 300.0], [700.0, 0.0, 0.0]])
    check(machine, points, np.array([30.0, -40.0, -150.0]), seed=1)


@pytest.mark.parametrize("example", ["npl-bridge", "gec-mh2"])
def test_example_machines_match_monte_carlo(example: str) -> None:
    machine = Machine.from_toml(ROOT / "examples" / "machines" / f"{example}.toml")
    points = np.array([machine.volume.upper_mm * 0.9, machine.volume.upper_mm * [0.2, 0.7, 0.5]])
    check(machine, points, np.array([0.0, 25.0, -120.0]), seed=2)


def test_monte_carlo_oracle_can_fail() -> None:
    """The oracle discriminates: doubling one band changes the Monte Carlo beyond tolerance."""
    machine = synthetic_machine("MB1", seed=4)
    point, stylus = np.array([600.0, 800.0, 400.0]), np.array([0.0, 0.0, -100.0])
    formula = machine.random_error(point[None, :], stylus)[0]
    machine.squareness_random_urad = machine.squareness_random_urad * 3.0
    mc = monte_carlo_2sigma(machine, point, stylus, np.random.default_rng(3))
    assert np.max(np.abs(mc / formula - 1.0)) > 5 * REL_TOL


def test_random_probing_error_adds_in_quadrature() -> None:
    points = np.array([[10.0, 20.0, 30.0], [600.0, 500.0, 100.0]])
    stylus = (5.0, 5.0, -60.0)
    without = synthetic_machine("FB2", seed=9, probe_um=0.0).random_error(points, stylus)
    with_probe = synthetic_machine("FB2", seed=9, probe_um=1.2).random_error(points, stylus)
    np.testing.assert_allclose(with_probe**2, without**2 + 1.2**2, rtol=1e-12)


def test_only_probing_error_gives_the_probing_error_everywhere() -> None:
    data = {
        "name": "probe only",
        "model": "MB1",
        "volume": {"x": [0.0, 100.0], "y": [0.0, 100.0], "z": [0.0, 100.0]},
        "probe": {"random_um": 0.7},
    }
    machine = Machine.from_dict(data)
    pts = np.random.default_rng(0).uniform(0.0, 100.0, (5, 3))
    np.testing.assert_allclose(machine.random_error(pts, (0.0, 0.0, -50.0)), 0.7, rtol=1e-15)
