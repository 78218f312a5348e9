"""Concrete effects: hand values, TOML round trip, linearity in their signals, lag filter oracle."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest
from scipy.integrate import solve_ivp

from cmm_comp.compensation.effects import (
    CouplingEffect,
    EvalContext,
    ParametricEffect,
    PeriodicEffect,
    ProbeLobingEffect,
    ReversalEffect,
    effect_from_table,
    lobing_signals,
)
from cmm_comp.compensation.machine import Machine
from cmm_comp.compensation.thermal import (
    FirstOrderLag,
    ScaleExpansionEffect,
    SquarenessDriftEffect,
    ThermalGradientEffect,
    ThermalLagEffect,
    WorkpieceExpansionEffect,
    lag_filter,
)

ROOT = Path(__file__).resolve().parents[1]

NPL = ROOT / "examples" / "machines" / "npl-bridge.toml"

ALL = [
    ParametricEffect("dx_x", [1.0, -0.5, 0.3, 0.1], (0.0, 900.0)),
    ParametricEffect("alpha", [3.0]),
    CouplingEffect("ey_y", "x", [4.0, -1.0], (0.0, 1150.0), (0.0, 900.0)),
    ThermalGradientEffect("y", 3.0),
    ThermalLagEffect(1800.0, 0.5),
    ScaleExpansionEffect("z", 1.5),
    WorkpieceExpansionEffect(2.0, (450.0, 575.0, 0.0)),
    SquarenessDriftEffect("beta1", 2.0),
    ReversalEffect("x", [1.0, 0.2], (0.0, 900.0)),
    PeriodicEffect("y", 37.0, 0.8, -0.3),
    ProbeLobingEffect(3, 0.7, 0.2),
]


def _ctx(q: np.ndarray, signals: dict[str, np.ndarray]) -> EvalContext:
    n = len(q)
    return EvalContext(
        q_mm=q,
        u_mm=q.copy(),
        signals=signals,
        errors=np.zeros((n, 3, 6)),
        squareness_urad=np.zeros((n, 3)),
        direct_um=np.zeros((n, 3)),
        reference_C=20.0,
        reference_mm=np.zeros(3),
    )


def _inputs(n: int, rng: np.random.Generator) -> tuple[dict, dict]:
    temps = {
        k: 20 + rng.normal(0, 1, n)
        for k in ("T_x", "T_y", "T_z", "T_wp", "T_top", "T_bottom", "T_air")
    }
    nrm = rng.normal(size=(n, 3))
    nrm /= np.linalg.norm(nrm, axis=1, keepdims=True)
    inputs = {
        "t": np.linspace(0, 7200, n),
        "dir_x": rng.choice([-1.0, 1.0], n),
        "nx": nrm[:, 0],
        "ny": nrm[:, 1],
        "nz": nrm[:, 2],
    }
    return temps, inputs


@pytest.mark.parametrize("effect", ALL, ids=lambda e: e.cause)
def test_round_trip_through_machine_toml(effect, tmp_path) -> None:
    base = Machine.from_toml(NPL)
    ext = base.with_effects([effect])
    ext.to_toml(tmp_path / "m.toml")
    loaded = Machine.from_toml(tmp_path / "m.toml")
    rng = np.random.default_rng(1)
    q = rng.uniform([0, 0, 0], [900, 1150, 400], (40, 3))
    temps, inputs = _inputs(40, rng)
    a = ext.volumetric_error(q, (10, 0, -100), temps, inputs=inputs)
    b = loaded.volumetric_error(q, (10, 0, -100), temps, inputs=inputs)
    c = base.volumetric_error(q, (10, 0, -100), temps, inputs=inputs)
    np.testing.assert_allclose(a, b, atol=1e-12)
    assert np.max(np.abs(a - c)) > 1e-3  # the effect does something
    assert effect_from_table(effect.to_table()).to_table() == effect.to_table()


def test_thermal_gradient_hand_values() -> None:
    q = np.array([[500.0, 0.0, 0.0]])
    ctx = _ctx(q, {"T_top": np.array([21.0]), "T_bottom": np.array([20.0])})
    ThermalGradientEffect("x", 2.0).modify_errors(ctx)
    assert ctx.errors[0, 0, 4] == pytest.approx(1.0)  # ey_x = 2 µrad/(m·°C)·1 °C·0.5 m
    assert ctx.errors[0, 0, 2] == pytest.approx(-0.25)  # dz_x = −2·1·0.5²/2 µm


def test_coupling_vanishes_on_reference_lines_and_is_bilinear() -> None:
    e = CouplingEffect("ey_y", "x", [1.0, 0.0], (0.0, 1000.0), (0.0, 1000.0))
    q = np.array([[0.0, 700.0, 0.0], [300.0, 0.0, 0.0], [500.0, 500.0, 0.0]])
    ctx = _ctx(q, {})
    e.modify_errors(ctx)
    # s − s_ref = 2q/1000: (1.0)·(1.0) at (500, 500)
    np.testing.assert_allclose(ctx.errors[:, 1, 4], [0.0, 0.0, 1.0], atol=1e-12)


def test_parametric_shape_zero_at_reference_and_legendre_p2() -> None:
    e = ParametricEffect("dy_x", [1.0, 0.0, 0.0], (0.0, 1000.0), [2, 3, 4])
    ctx = _ctx(np.array([[0.0, 0, 0], [500.0, 0, 0], [1000.0, 0, 0]]), {})
    e.modify_errors(ctx)
    # P2(s) − P2(−1): s = −1, 0, 1 → 0, −0.5 − 1, 0
    np.testing.assert_allclose(ctx.errors[:, 0, 1], [0.0, -1.5, 0.0], atol=1e-12)


def test_lobing_signals_hand_values() -> None:
    c60, s60 = math.cos(math.pi / 3), math.sin(math.pi / 3)
    sig = lobing_signals(
        np.array([1.0, c60, 0.0]), np.array([0.0, s60, 0.0]), np.array([0.0, 0.0, 1.0]), 3
    )
    np.testing.assert_allclose(sig["lobe3_c_x"], [1.0, -c60, 0.0], atol=1e-12)  # cos 180° = −1
    np.testing.assert_allclose(sig["lobe3_s_y"], [0.0, 0.0, 0.0], atol=1e-12)
    np.testing.assert_allclose(sig["lobe3_c_z"], [0.0, 0.0, 0.0], atol=1e-12)  # vertical: no lobing


def test_lag_filter_matches_ode_solution() -> None:
    t = np.sort(np.random.default_rng(3).uniform(0, 7200, 300))
    temp = 20 + np.sin(t / 900.0) + t / 7200
    tau = 600.0

    def rhs(tt, y):
        return [(np.interp(tt, t, temp) - y[0]) / tau]

    sol = solve_ivp(rhs, (t[0], t[-1]), [temp[0]], t_eval=t, rtol=1e-10, atol=1e-12, max_step=5.0)
    np.testing.assert_allclose(lag_filter(t, temp, tau), sol.y[0], atol=1e-6)
    shuffled = np.random.default_rng(4).permutation(len(t))
    np.testing.assert_allclose(
        lag_filter(t[shuffled], temp[shuffled], tau), lag_filter(t, temp, tau)[shuffled]
    )
    lag = FirstOrderLag(tau)
    stream = [lag.update(tt, x) for tt, x in zip(t, temp, strict=True)]
    np.testing.assert_allclose(stream, lag_filter(t, temp, tau), atol=1e-12)


@pytest.mark.parametrize(
    "effect",
    [e for e in ALL if e.signals()],
    ids=lambda e: e.cause,
)
def test_linear_in_declared_signals(effect) -> None:
    """The grid stores one sensitivity per signal: the effect must be linear in them."""
    base = Machine.from_toml(NPL)
    m = base.with_effects([effect])
    signals = m.runtime_signals()
    mine = effect.signals()
    assert set(mine) <= set(signals)
    rng = np.random.default_rng(2)
    q = rng.uniform([0, 0, 0], [900, 1150, 400], (20, 3))
    ref = {k: np.full(20, v) for k, v in signals.items()}
    d1 = {k: ref[k] + rng.normal(0, 1, 20) for k in mine}
    d2 = {k: ref[k] + 2 * (d1[k] - ref[k]) for k in mine}

    def ev(s):
        return m.volumetric_error(q, (0, 0, -100), inputs={**ref, **s}) - m.volumetric_error(
            q, (0, 0, -100), inputs=ref
        )

    # exact rigid-body chain: second-order terms (µrad² · mm) stay below 0.1 nm
    np.testing.assert_allclose(ev(d2), 2 * ev(d1), rtol=1e-6, atol=1e-4)
    assert all(v == (20.0 if k.startswith("T_") else 0.0) for k, v in mine.items())


def test_bad_tables_are_rejected_with_the_reason() -> None:
    with pytest.raises(ValueError, match="varies_with"):
        effect_from_table(
            {
                "cause": "coupling",
                "component": "ey_y",
                "varies_with": "q",
                "coefficients": [1, 2],
                "span_mm": [0, 1],
                "span_with_mm": [0, 1],
            }
        )
    with pytest.raises(ValueError, match="period_mm"):
        effect_from_table({"cause": "periodic", "axis": "x", "a_cos_um": 1, "b_sin_um": 0})
    with pytest.raises(ValueError, match="unknown effect cause"):
        effect_from_table({"cause": "gremlins"})


def test_lobing_with_radial_power_one_fades_in_proportion_to_rho() -> None:
    # n = (0.6, 0, 0.8): ρ = 0.6, φ = 0 → C = ρᵖ; by hand: p = 1 → 0.6, p = 2 → 0.36
    one = lobing_signals([0.6], [0.0], [0.8], 2, radial_power=1)
    two = lobing_signals([0.6], [0.0], [0.8], 2)
    np.testing.assert_allclose(one["lobe2r1_c_x"], [0.6 * 0.6])
    np.testing.assert_allclose(one["lobe2r1_c_z"], [0.8 * 0.6])
    np.testing.assert_allclose(two["lobe2_c_x"], [0.6 * 0.36])
    # φ = 45°, horizontal: cos 2φ = 0, sin 2φ = 1 whatever the power
    h = np.sqrt(0.5)
    sig = lobing_signals([h], [h], [0.0], 2, radial_power=1)
    np.testing.assert_allclose(sig["lobe2r1_s_x"], [h], atol=1e-12)
    np.testing.assert_allclose(sig["lobe2r1_c_y"], [0.0], atol=1e-12)
    eff = ProbeLobingEffect.from_table(
        {"lobes": 2, "a_cos_um": 1.0, "b_sin_um": 0.0, "radial_power": 1}
    )
    assert eff.to_table()["radial_power"] == 1
    assert "radial_power" not in ProbeLobingEffect(3, 1.0, 0.0).to_table()
