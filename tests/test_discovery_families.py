"""Families of causes, alternatives, drift and the nuisance offset (issue 11).

Oracles are physics stated independently of the candidate code:

* with one stylus straight down, an angular error of the Z carriage about y (ey_z) and the
  X straightness of Z (dx_z) move the tip identically — the arm from the Z carriage to the tip is
  the same constant vector at every point — so the diagnosis must name one and list the other as
  an alternative, and say that another stylus length separates them;
* a drift with time cannot be predicted at run time: ``extend`` leaves it out and says so;
* an offset between the reference instrument and the machine is not a cause: a clean session
  shifted by a constant is still ``none`` and the offset is reported.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
from doc_commands import cli

from cmm_comp.compensation.diagnosis import diagnose
from cmm_comp.compensation.effects import (
    CouplingEffect,
    DriftEffect,
    ParametricEffect,
    PeriodicEffect,
    StaticImageEffect,
    effect_from_table,
)
from cmm_comp.compensation.formats.measurements import write_measurements
from cmm_comp.compensation.machine import Machine
from cmm_comp.compensation.thermal import (
    ScaleExpansionEffect,
    ThermalGradientEffect,
    WorkpieceExpansionEffect,
)
from cmm_comp.sim_controller.sessions import measure_session, plan_session

ROOT = Path(__file__).resolve().parents[1]
NPL = ROOT / "examples" / "machines" / "npl-bridge.toml"


@pytest.fixture(scope="module")
def npl() -> Machine:
    return Machine.from_toml(NPL)


def _session(
    machine: Machine, truth: Machine, seed: int, one_stylus: bool = False, temps: bool = True
):
    rng = np.random.default_rng(seed)
    plan = plan_session(machine, rng, n_points=500)
    if not temps:  # the temperature was not logged (and the structure sat at the reference)
        plan.data.temps_C = {}
    if one_stylus:
        plan.data.stylus_mm = np.broadcast_to(
            np.asarray(machine.probe.offset_mm, dtype=float), plan.data.indicated_mm.shape
        ).copy()
    return measure_session(truth, plan, 0.3, rng)


def test_one_stylus_z_tilt_and_z_straightness_are_alternatives(npl: Machine) -> None:
    # no linear part: the slope of a straightness is a squareness, not a table shape
    span = (float(npl.volume.lower_mm[2]), float(npl.volume.upper_mm[2]))
    hidden = ParametricEffect("ey_z", [-6.0, 4.0], span, orders=[2, 3])
    data = _session(npl, npl.with_effects([hidden]), seed=3, one_stylus=True)
    d = diagnose(npl, data)
    named = [e for e in d.entries if e["cause"] == "parametric"]
    assert len(named) == 1, d.entries
    pair = {named[0]["component"]} | {a.get("component") for a in named[0].get("alternatives", [])}
    assert {"ey_z", "dx_z"} <= pair, named[0]
    alt = next(a for a in named[0]["alternatives"] if a.get("component") in {"ey_z", "dx_z"})
    assert "styl" in alt["separated_by"], alt  # a second stylus length, or styli sideways


def test_with_five_styli_the_z_tilt_is_named_without_that_alternative(npl: Machine) -> None:
    span = (float(npl.volume.lower_mm[2]), float(npl.volume.upper_mm[2]))
    hidden = ParametricEffect("ey_z", [6.0, -3.0, 2.0], span)
    data = _session(npl, npl.with_effects([hidden]), seed=3)
    d = diagnose(npl, data)
    assert [(e["cause"], e.get("component")) for e in d.entries] == [("parametric", "ey_z")]
    assert "dx_z" not in {a.get("component") for a in d.entries[0].get("alternatives", [])}


def test_a_constant_instrument_offset_is_not_a_cause(npl: Machine) -> None:
    data = _session(npl, npl, seed=8)
    data.reference_mm = data.reference_mm + np.array([0.004, -0.003, 0.002])
    d = diagnose(npl, data)
    assert d.verdict == "none", d.entries
    assert d.summary["offset_um"]["x"] == pytest.approx(4.0, abs=0.1)
    assert d.summary["offset_um"]["y"] == pytest.approx(-3.0, abs=0.1)


def test_drift_is_named_and_extend_leaves_it_out(npl: Machine, tmp_path: Path) -> None:
    no_temps = _session(npl, npl, seed=5)
    t = no_temps.t_s
    assert t is not None
    span = (float(t.min()), float(t.max()))
    hidden = DriftEffect("x", span, [2.0, -1.0, 0.5], [3.0, 4.0, -2.0, 1.0])
    data = _session(npl, npl.with_effects([hidden]), seed=5, temps=False)
    d = diagnose(npl, data)
    assert ("drift", "x") in {(e["cause"], e.get("axis")) for e in d.entries}, d.entries
    drift = next(e for e in d.entries if e["cause"] == "drift")
    assert drift["compensable"] is False
    csv = write_measurements(tmp_path / "m.csv", data)
    out = cli("extend", NPL, csv, "-o", tmp_path / "x.toml")
    assert out.returncode == 0, out.stderr
    assert "not added: drift" in out.stdout
    assert "drift" not in (tmp_path / "x.toml").read_text()


def _term(npl: Machine, effect, q, signals):
    """What ``effect``'s own hooks add (errors, squareness, direct), evaluated directly — not
    through ``Machine.with_effects``, which itself goes through the effect's table."""
    from cmm_comp.compensation.effects import EvalContext

    n = len(q)
    ctx = EvalContext(
        q_mm=q,
        u_mm=q - npl.volume.reference_mm,
        signals={k: v.copy() for k, v in signals.items()},
        errors=np.zeros((n, 3, 6)),
        squareness_urad=np.zeros((n, 3)),
        direct_um=np.zeros((n, 3)),
        reference_C=20.0,
        reference_mm=npl.volume.reference_mm,
    )
    effect.transform_signals(ctx)
    effect.modify_errors(ctx)
    effect.add_direct(ctx)
    return np.concatenate([ctx.errors.ravel(), ctx.squareness_urad.ravel(), ctx.direct_um.ravel()])


@pytest.mark.parametrize(
    "effect",
    [
        CouplingEffect(
            "ey_x", "y", [1.0, -2.0, 0.5], (0.0, 900.0), (0.0, 1150.0), (0, 1, 2), (1,), 3.0
        ),
        CouplingEffect(
            "ez_y", "x", [1.0, 2.0, 3.0, 4.0], (0.0, 1150.0), (0.0, 900.0), (0, 1), (1, 2)
        ),
        CouplingEffect(
            "ey_z", "x", [0.5, 1.0], (0.0, 600.0), (0.0, 900.0), (1, 2), (1,), -1.0, [2.0, -0.5]
        ),
        PeriodicEffect("x", 37.5, 1.0, -0.5, [[0.3, 0.1], [0.0, -0.2]]),
        DriftEffect("y", (0.0, 3600.0), [1.0, 2.0], [0.5, -1.0, 0.25]),
        ThermalGradientEffect("y", 4.0, -2.0, 0.7, 0.3, 1.1, offset_um_per_C=-0.6),
        ThermalGradientEffect("x", 1.0, 0.5, 0.0, 0.0, 0.2, tilt_poly_urad_per_C=[0.7, -0.3]),
        ScaleExpansionEffect("x", 2.5, 130.0),
        WorkpieceExpansionEffect(-3.0, [100.0, 250.0, 40.0]),
        StaticImageEffect(
            ThermalGradientEffect("y", 4.0, -2.0, 0.7, 0.3, 1.1, offset_um_per_C=-0.6),
            ThermalGradientEffect("y", -1.0, 0.5, 0.2, -0.4, 0.3, offset_um_per_C=0.8),
            {"T_top": 21.3, "T_bottom": 20.4},
        ),
    ],
)
def test_new_effect_shapes_round_trip_through_their_tables(npl: Machine, effect) -> None:
    """The table an effect writes recreates the same term (what extend → grid relies on): every
    parameter must survive, so each is given a non-default value above."""
    again = effect_from_table(json.loads(json.dumps(effect.to_table())))
    rng = np.random.default_rng(1)
    lo, hi = npl.volume.lower_mm, npl.volume.upper_mm
    q = lo + rng.random((50, 3)) * (hi - lo)
    signals = {
        "t": rng.uniform(0, 3600, 50),
        "T_top": rng.uniform(20.5, 21.5, 50),
        "T_bottom": np.full(50, 20.0),
        "T_x": rng.uniform(20.5, 22.0, 50),
        "T_wp": rng.uniform(18.5, 21.0, 50),
    }
    a = _term(npl, effect, q, signals)
    b = _term(npl, again, q, signals)
    assert np.max(np.abs(a)) > 1e-3
    assert np.allclose(a, b, rtol=0.0, atol=1e-12)


def test_gradient_tilt_follows_the_slope_of_the_straightness(npl: Machine) -> None:
    """Physics: a carriage on a bowed rail tilts with the rail's local slope. For X (bending in
    x-z) the pitch is ey_x = −d(dz_x)/dx; the straightness' slope by finite differences must
    match the tilt at every point, whatever the supports (h), for the written effect."""
    eff = ThermalGradientEffect(
        "x", 8.0, 3.0, 0.0, 0.0, 1.5, offset_um_per_C=2.0, tilt_poly_urad_per_C=[4.0, -6.0]
    )
    eff.reference_C = 20.0
    from cmm_comp.compensation.effects import EvalContext

    u = np.linspace(-300.0, 500.0, 81)
    q = np.zeros((81, 3))
    q[:, 0] = u + npl.volume.reference_mm[0]
    ctx = EvalContext(
        q_mm=q,
        u_mm=q - npl.volume.reference_mm,
        signals={"T_top": np.full(81, 21.0), "T_bottom": np.full(81, 20.0)},
        errors=np.zeros((81, 3, 6)),
        squareness_urad=np.zeros((81, 3)),
        direct_um=np.zeros((81, 3)),
        reference_C=20.0,
        reference_mm=npl.volume.reference_mm,
    )
    eff.modify_errors(ctx)
    dz = ctx.errors[:, 0, 2]  # µm
    slope_urad = np.gradient(dz, u / 1000.0)  # µm/m = µrad
    assert np.allclose(-slope_urad[1:-1], ctx.errors[1:-1, 0, 4], atol=1e-3)


def _dent_um(
    q_mm: np.ndarray, centre_mm: np.ndarray, span_mm: np.ndarray, radius: float, depth_um: float
):
    """A dent in the z error (raised cosine in the distance normalised by the travel, zero
    beyond ``radius``): a local defect no global cause has, shaped unlike any candidate basis
    (compact support, a cosine in r)."""
    r = np.linalg.norm((q_mm - centre_mm) / span_mm, axis=1)
    out = np.zeros_like(q_mm)
    inside = r < radius
    out[inside, 2] = -depth_um * 0.5 * (1.0 + np.cos(np.pi * r[inside] / radius))
    return out


@pytest.mark.parametrize("seed", [1, 3])
def test_a_local_dent_is_unexplained_where_it_sits_never_a_cause(npl: Machine, seed: int) -> None:
    rng = np.random.default_rng(seed)
    plan = plan_session(npl, rng, n_points=600)
    lo, hi = np.asarray(npl.volume.lower_mm), np.asarray(npl.volume.upper_mm)
    centre = lo + np.array([0.75, 0.3, 0.7]) * (hi - lo)
    data = measure_session(npl, plan, 0.3, rng)
    dent = _dent_um(plan.data.indicated_mm, centre, hi - lo, 0.3, depth_um=3.0)
    assert np.count_nonzero(dent[:, 2] < -1.5) >= 15  # the session sees the dent
    data.reference_mm = data.reference_mm + dent / 1000.0
    d = diagnose(npl, data)
    assert [e["cause"] for e in d.entries] == ["unexplained"], d.entries
    where = np.asarray(d.entries[0]["parameters"]["where_mm"])
    assert d.entries[0]["parameters"]["axis"] == "z"
    # the located centre lies inside the dent, independent of the basis' grid
    assert np.linalg.norm((where - centre) / (hi - lo)) < 0.3, (where, centre)
    assert d.extended_machine().effects == npl.effects  # nothing to compensate


def test_static_image_is_the_effect_at_the_calibration_state(npl: Machine) -> None:
    """Physics of an on-site calibration: the tables hold what the effect did at the frozen
    state, so the term is E(T; c) + E(T_cal; b), each evaluated on its own (oracle: two plain
    effects, the second fed constant temperatures)."""
    dyn = ThermalGradientEffect("x", 3.0, -1.5, 0.4, 0.2, 0.9, offset_um_per_C=0.3)
    stat = ThermalGradientEffect("x", -2.0, 0.7, 0.1, -0.3, 0.5, offset_um_per_C=-0.4)
    frozen = {"T_top": 21.6, "T_bottom": 20.3}
    rng = np.random.default_rng(3)
    lo, hi = npl.volume.lower_mm, npl.volume.upper_mm
    q = lo + rng.random((40, 3)) * (hi - lo)
    signals = {"T_top": rng.uniform(20.5, 22.0, 40), "T_bottom": rng.uniform(19.8, 20.6, 40)}
    both = _term(npl, StaticImageEffect(dyn, stat, frozen), q, signals)
    held = {k: np.full(40, v) for k, v in frozen.items()}
    expect = _term(npl, dyn, q, signals) + _term(npl, stat, q, held)
    assert np.max(np.abs(expect)) > 1e-3
    np.testing.assert_allclose(both, expect, atol=1e-12)
    # the signals seen by other effects are untouched
    with pytest.raises(ValueError, match="same kind"):
        StaticImageEffect(dyn, ScaleExpansionEffect("x", 1.0), frozen)
    with pytest.raises(ValueError, match="finite"):
        StaticImageEffect(dyn, stat, {"T_top": float("nan")})
    with pytest.raises(ValueError, match="signals"):
        effect_from_table({**dyn.to_table(), "static_image": {"curvature_urad_per_m_C": 1.0}})


def test_scale_fixed_elsewhere_expands_about_its_fixing_point(npl: Machine) -> None:
    """A scale fixed at x = 130 mm: no error there whatever the temperature (hand value)."""
    eff = ScaleExpansionEffect("x", 2.0, 130.0)
    q = np.array([[130.0, 200.0, 100.0], [630.0, 200.0, 100.0]])
    out = _term(npl, eff, q, {"T_x": np.array([23.0, 23.0])})
    direct = out[-6:].reshape(2, 3)
    assert direct[0, 0] == pytest.approx(0.0, abs=1e-12)
    assert direct[1, 0] == pytest.approx(2.0 * 3.0 * 500.0 / 1000.0)
