"""Period laws, the cyclic error with a law and an envelope, the shaped drift, the reference's
terms and the columns a dense record adds (issue 24). Oracles: the laws' definitions (the phase
is the integral of 2π/p: finite differences), closed forms, TOML round trips, scipy.
"""

from __future__ import annotations

import math

import numpy as np
import pytest
from scipy import integrate

from cmm_comp.compensation.diagnosis.reference_effects import ReferenceScaleEffect
from cmm_comp.compensation.diagnosis.ripple import find_chirp
from cmm_comp.compensation.effects import DriftEffect, PeriodicEffect, PeriodLaw, effect_from_table
from cmm_comp.compensation.formats.measurements import (
    measurements_from_columns,
    read_measurements,
    write_measurements,
)


def _dphase(law: PeriodLaw, r: np.ndarray, h: float = 1e-4) -> np.ndarray:
    return (law.phase(r + h) - law.phase(r - h)) / (2 * h)


@pytest.mark.parametrize(
    "law",
    [
        PeriodLaw("triangulation", 0.33, 0.0, r0_mm=110.0),
        PeriodLaw("triangulation", 0.2, 5.0, r0_mm=-60.0),
        PeriodLaw(
            "smooth",
            0.3,
            0.0,
            knots_mm=(-20.0, -10.0, 0.0, 10.0, 20.0),
            period_at_knots_mm=(0.45, 0.38, 0.3, 0.26, 0.22),
        ),
    ],
)
def test_the_phase_advances_by_one_cycle_per_local_period(law: PeriodLaw) -> None:
    r = np.linspace(-20, 20, 41)
    # (a smooth law is integrated numerically: 4001 points over the travel)
    assert np.allclose(_dphase(law, r), 2 * math.pi / law.period_at(r), rtol=1e-4)
    assert law.phase(np.array([law.centre_mm]))[0] == pytest.approx(0.0, abs=1e-9)
    assert law.period_at(np.array([law.centre_mm]))[0] == pytest.approx(law.period_mm)


def test_triangulation_is_the_square_of_the_distance() -> None:
    # a sensor at r0 = 110 reading a target: its period grows as (distance)²
    law = PeriodLaw("triangulation", 0.33, 0.0, r0_mm=110.0)
    d = 110.0 - np.array([-20.0, 20.0])
    assert np.allclose(law.period_at(np.array([-20.0, 20.0])), 0.33 * (d / 110.0) ** 2)
    # the phase between two readings is the integral of 2π/p (scipy's quadrature)
    num, _ = integrate.quad(lambda r: 2 * math.pi / float(law.period_at(np.array([r]))[0]), 0, 15)
    assert law.phase(np.array([15.0]))[0] == pytest.approx(num, rel=1e-8)


def test_bad_laws_are_refused_with_their_reason() -> None:
    with pytest.raises(ValueError, match="r0_mm"):
        PeriodLaw("triangulation", 0.3, 0.0)
    with pytest.raises(ValueError, match="knots"):
        PeriodLaw("smooth", 0.3, 0.0, knots_mm=(1.0,), period_at_knots_mm=(0.3,))
    with pytest.raises(ValueError, match="law must be"):
        PeriodLaw("chirp", 0.3)


def test_constant_law_periodic_is_the_classic_cyclic_error() -> None:
    eff = PeriodicEffect("x", 25.0, 1.5, -0.5, [(0.2, 0.1)])
    q = np.linspace(0, 100, 11)
    w = 2 * math.pi / 25.0
    want = (
        1.5 * np.cos(w * q)
        - 0.5 * np.sin(w * q)
        + 0.2 * np.cos(2 * w * q)
        + 0.1 * np.sin(2 * w * q)
    )
    assert np.allclose(eff.value_um(q), want)
    assert eff.to_table() == {
        "cause": "periodic",
        "axis": "x",
        "period_mm": 25.0,
        "a_cos_um": 1.5,
        "b_sin_um": -0.5,
        "harmonics_um": [[0.2, 0.1]],
    }


def test_a_chirped_periodic_with_envelope_round_trips() -> None:
    law = PeriodLaw("triangulation", 0.33, 0.0, r0_mm=110.0)
    eff = PeriodicEffect("x", 0.33, 3.0, 1.0, [], law, [[1, 1, 2.0, -1.0]], (-20.0, 20.0))
    back = effect_from_table(eff.to_table())
    q = np.linspace(-20, 20, 401)
    assert np.allclose(back.value_um(q), eff.value_um(q))  # type: ignore[attr-defined]
    # the envelope: first harmonic amplitude |(3 + 2s, 1 − s)| with s = q/20
    s = q / 20.0
    assert eff.describe()["parameters"]["amplitude_um"] == pytest.approx(
        float(np.max(np.hypot(3 + 2 * s, 1 - s))), rel=1e-3
    )
    assert eff.shortest_wavelength_mm()["x"] == pytest.approx(
        float(law.period_at(np.array([20.0]))[0])
    )


def test_shaped_drift_changes_along_the_axis() -> None:
    # linear in time (k = 1), shape 2 − 3·P2(s) along x: start → end change is 2·(2 − 3·P2)
    eff = DriftEffect("x", (0.0, 100.0), [0.0], [0.0, 0.0], [[2.0, 0.0, -3.0]], (-20.0, 20.0))
    ch = eff.change_along_axis_um(points=3)
    p2 = lambda s: 0.5 * (3 * s**2 - 1)  # noqa: E731
    assert np.allclose(ch["change_um"], [2 * (2 - 3 * p2(s)) for s in (-1.0, 0.0, 1.0)])
    assert eff.describe()["parameters"]["shape"] == "smooth"
    back = effect_from_table(eff.to_table())
    assert back.to_table() == eff.to_table()
    uniform = DriftEffect("x", (0.0, 100.0), [1.0], [0.0, 0.0])
    assert uniform.shape() == {"shape": "uniform"}
    # expansion about u_f: offset o·τ + (u/1000)·s1·τ vanishes at u = −1000·o/s1
    expansion = DriftEffect("x", (0.0, 100.0), [2.0], [0.0, 100.0])
    assert expansion.shape()["fixed_point_u_mm"] == pytest.approx(-20.0)


def test_reference_scale_gives_the_cosine_angle() -> None:
    # a beam misaligned by θ reads short by 1 − cos θ: k = −10⁶(1 − cos θ) µm/m
    theta = 2e-3
    eff = ReferenceScaleEffect("x", -1e6 * (1 - math.cos(theta)), 0.0)
    assert eff.describe()["parameters"]["cosine_angle_mrad"] == pytest.approx(2.0, rel=1e-6)
    assert eff.source == "reference" and not eff.compensable


def test_find_chirp_recovers_a_triangulation_law_from_a_record() -> None:
    """A dense record built with numpy alone: a ripple periodic in u = K/(r0 − r), a smooth
    curve and noise; the local spectral analysis must give back r0 and the period."""
    rng = np.random.default_rng(5)
    r = np.sort(rng.uniform(-20, 20, 6000))
    r0, k = 100.0, 30000.0
    ripple = 5.0 * np.cos(2 * math.pi * k / (r0 - r)) + 1.5 * np.cos(4 * math.pi * k / (r0 - r))
    y = ripple + 20 * (r / 20) ** 3 + rng.normal(0, 0.5, len(r))
    chirp = find_chirp(r, y, np.zeros(len(r)), None, 0.05)
    assert chirp is not None and chirp.law.kind == "triangulation"
    # p(r) = (r0 − r)²/K: at the centre 0 → 100²/30000 = 0.333 mm
    assert chirp.law.period_mm == pytest.approx(r0**2 / k, rel=0.01)
    assert chirp.law.r0_mm == pytest.approx(r0, rel=0.03)
    # a constant-period ripple is no chirp
    flat = 5.0 * np.cos(2 * math.pi * r / 0.3) + rng.normal(0, 0.5, len(r))
    assert find_chirp(r, flat, np.zeros(len(r)), None, 0.05) is None


def test_measurements_carry_velocity_and_state(tmp_path) -> None:
    cols = {
        "x": [0.0, 1.0],
        "y": [0.0, 0.0],
        "z": [0.0, 0.0],
        "ref_x": [0.0, 1.001],
        "ref_y": [0.0, 0.0],
        "ref_z": [0.0, 0.0],
        "v_x": [0.0, -0.2],
        "state": ["rest", "steady"],
    }
    data = measurements_from_columns(cols)
    back = read_measurements(write_measurements(tmp_path / "m.csv", data))
    assert np.allclose(back.velocities["v_x"], [0.0, -0.2])
    assert list(back.state) == ["rest", "steady"]
    assert list(back.subset([1]).state) == ["steady"]
