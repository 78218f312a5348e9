"""Thermal terms (docs/formats.md §1) against values computed by hand.

Axis j adds ``α_j·(T_j − T_ref)·(q_j − ref_j)/1000`` µm to component j; a workpiece adds
``−α_wp·(T_wp − T_ref)·(q − fixture)/1000`` µm. The thermal part is isolated as
``volumetric_error(temps) − volumetric_error()`` (the terms are additive, outside the chain).
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np
import pytest

from cmm_comp.compensation.machine import Machine

ROOT = Path(__file__).resolve().parents[1]


def thermal_part(machine: Machine, points: Any, temps: dict[str, Any]) -> np.ndarray:
    return machine.volumetric_error(points, temps_C=temps) - machine.volumetric_error(points)


def simple_machine(**thermal: Any) -> Machine:
    data = {
        "name": "thermal",
        "model": "FB1",
        "volume": {
            "x": [0.0, 1000.0],
            "y": [0.0, 800.0],
            "z": [0.0, 500.0],
            "reference": [100.0, 50.0, 20.0],
        },
        "thermal": {"expansion": {"x": 10.0, "y": 12.0, "z": 8.0}, **thermal},
        "squareness": {"alpha": 30.0},
        "errors": {"ez_y": {"polynomial": [0.0, 0.02]}},  # the chain is not trivial
    }
    return Machine.from_dict(data)


def test_npl_bridge_hand_values() -> None:
    """npl-bridge: α = 10.5 per axis, workpiece 11.5 about (450, 575, 0), reference 0, 20 °C.

    At q = (300, 500, 200) with T_x = 22, T_y = 19, T_z = 20, T_wp = 21:
    X: 10.5·2·300/1000 = 6.3; Y: 10.5·(−1)·500/1000 = −5.25; Z: 0;
    workpiece: −11.5·1·(−150, −75, 200)/1000 = (1.725, 0.8625, −2.3).
    """
    machine = Machine.from_toml(ROOT / "examples" / "machines" / "npl-bridge.toml")
    temps = {"T_x": 22.0, "T_y": 19.0, "T_z": 20.0, "T_wp": 21.0}
    got = thermal_part(machine, [[300.0, 500.0, 200.0]], temps)
    np.testing.assert_allclose(got, [[6.3 + 1.725, -5.25 + 0.8625, -2.3]], atol=1e-12)


def test_positions_are_measured_from_the_reference_point() -> None:
    """(q − ref) for the scales: q = (600, 450, 320), ref = (100, 50, 20), ΔT = 5, 2, −3:
    X 10·5·500/1000 = 25; Y 12·2·400/1000 = 9.6; Z 8·(−3)·300/1000 = −7.2."""
    machine = simple_machine()
    got = thermal_part(machine, [[600.0, 450.0, 320.0]], {"T_x": 25.0, "T_y": 22.0, "T_z": 17.0})
    np.testing.assert_allclose(got, [[25.0, 9.6, -7.2]], atol=1e-12)


def test_missing_temperatures_default_to_the_reference() -> None:
    machine = simple_machine(workpiece_expansion=11.0, workpiece_fixture=[0.0, 0.0, 0.0])
    pts = [[600.0, 450.0, 320.0]]
    np.testing.assert_allclose(thermal_part(machine, pts, {}), 0.0, atol=1e-12)
    np.testing.assert_allclose(thermal_part(machine, pts, {"T_y": None}), 0.0, atol=1e-12)
    # only T_x given: Y, Z and the workpiece stay at the reference temperature
    np.testing.assert_allclose(
        thermal_part(machine, pts, {"T_x": 21.0}), [[10 * 1 * 500 / 1000, 0.0, 0.0]], atol=1e-12
    )
    # only T_wp: −11·3·(600, 450, 320)/1000
    np.testing.assert_allclose(
        thermal_part(machine, pts, {"T_wp": 23.0}), [[-19.8, -14.85, -10.56]], atol=1e-12
    )


def test_reference_temperature_is_the_machines() -> None:
    machine = simple_machine(reference_C=18.0)
    got = thermal_part(machine, [[200.0, 50.0, 20.0]], {"T_x": 20.0, "T_y": 20.0, "T_z": 20.0})
    # X: 10·2·100/1000 = 2; Y and Z at their reference position: 0
    np.testing.assert_allclose(got, [[2.0, 0.0, 0.0]], atol=1e-12)
    # at 18 °C nothing happens, however the positions
    cold = thermal_part(machine, [[900.0, 700.0, 400.0]], {"T_x": 18.0, "T_y": 18.0, "T_z": 18.0})
    np.testing.assert_allclose(cold, 0.0, atol=1e-12)


def test_workpiece_grows_from_the_reference_without_a_fixture() -> None:
    """Without ``workpiece_fixture`` the machine uses the reference point (machine.py's choice;
    docs/formats.md leaves it open): −11·2·(q − (100, 50, 20))/1000 at q = (600, 450, 320)."""
    machine = simple_machine(workpiece_expansion=11.0)
    got = thermal_part(machine, [[600.0, 450.0, 320.0]], {"T_wp": 22.0})
    np.testing.assert_allclose(got, [[-11.0, -8.8, -6.6]], atol=1e-12)


def test_per_point_temperatures_are_vectorised() -> None:
    machine = simple_machine(workpiece_expansion=11.5, workpiece_fixture=[500.0, 400.0, 0.0])
    rng = np.random.default_rng(5)
    pts = rng.uniform([0, 0, 0], [1000, 800, 500], (7, 3))
    temps = {
        "T_x": rng.uniform(18, 24, 7),
        "T_y": 21.0,  # scalars and arrays mix
        "T_z": rng.uniform(18, 24, 7),
        "T_wp": rng.uniform(18, 24, 7),
    }
    together = thermal_part(machine, pts, temps)
    for n in range(7):
        one = {k: (v[n] if np.ndim(v) else v) for k, v in temps.items()}
        np.testing.assert_allclose(together[n], thermal_part(machine, pts[n : n + 1], one)[0])
    ref = np.array([100.0, 50.0, 20.0])
    alpha = np.array([10.0, 12.0, 8.0])
    dt = np.column_stack([temps["T_x"] - 20, np.full(7, 1.0), temps["T_z"] - 20])
    by_hand = (
        alpha * dt * (pts - ref) / 1000
        - 11.5 * (temps["T_wp"] - 20)[:, None] * (pts - [500.0, 400.0, 0.0]) / 1000
    )
    np.testing.assert_allclose(together, by_hand, atol=1e-10)


def test_thermal_terms_do_not_depend_on_the_stylus() -> None:
    machine = simple_machine()
    pts = [[600.0, 450.0, 320.0]]
    temps = {"T_x": 25.0, "T_y": 22.0, "T_z": 17.0}
    for stylus in ((0.0, 0.0, 0.0), (50.0, -30.0, -200.0)):
        diff = machine.volumetric_error(pts, stylus, temps) - machine.volumetric_error(pts, stylus)
        np.testing.assert_allclose(diff, [[25.0, 9.6, -7.2]], atol=1e-12)


def test_temperature_arrays_of_the_wrong_length_are_refused() -> None:
    machine = simple_machine()
    with pytest.raises(ValueError, match=r"signal 'T_x' must be a scalar or have shape \(2,\)"):
        machine.volumetric_error([[0, 0, 0], [1, 1, 1]], temps_C={"T_x": [20.0, 21.0, 22.0]})
