"""The held-out session generator (tests/heldout_generator) checked on its own terms.

* Its chain meets the project's only in the nominal model: for random tables on all ten models
  ``Machine.volumetric_error`` of the written ``machine.toml`` must give the same errors.
* Hand values and closed forms (a pure pitch through exact rotations, a table's linear error,
  squareness, a first-order lag of a ramp, beam deflections) check the physics independently.
* Effects are sized to ``size ×`` the noise, finite, reproducible by seed; files follow
  docs/formats.md and are read back by the project's readers.
* The generator imports nothing of the project (the independence rule of its README).

No diagnosis accuracy here: that is benchmarks/bench_discovery_heldout.py.
"""

from __future__ import annotations

import ast
from pathlib import Path

import numpy as np
import pytest
from heldout_generator import (
    CAUSES,
    MODEL_AXES,
    TABLE_NAMES,
    Case,
    Identity,
    SessionDesign,
    identity_from_entry,
    make_case,
    random_machine,
    rms3d_um,
    score_diagnosis,
    stylus_error_um,
    write_case,
)
from heldout_generator.beams import GRID, deflection
from heldout_generator.chain import table_slot
from heldout_generator.environment import lag
from heldout_generator.truth import true_temperatures

from cmm_comp.compensation import Machine, read_measurements

PACKAGE = Path(__file__).resolve().parent / "heldout_generator"
SMALL = SessionDesign(n_points=200)


def _machine_dict_roundtrip(tmp_path: Path, desc_dict: dict) -> Machine:
    import tomli_w

    path = tmp_path / "machine.toml"
    path.write_bytes(tomli_w.dumps(desc_dict).encode())
    return Machine.from_toml(path)


# ------------------------------------------------------------------ the nominal model
@pytest.mark.parametrize("model", list(MODEL_AXES))
def test_chain_and_thermal_terms_match_the_project(model: str, tmp_path: Path) -> None:
    rng = np.random.default_rng(abs(hash(model)) % 2**32)
    machine = random_machine(rng, model)
    machine.squareness_urad = rng.uniform(-300.0, 300.0, 3)  # big: exact vs first order differs
    project = _machine_dict_roundtrip(tmp_path, machine.toml_dict())
    n = 300
    q = machine.lower_mm + rng.uniform(0, 1, (n, 3)) * machine.span_mm
    stylus = rng.normal(0.0, 120.0, (n, 3))
    temps = {name: rng.uniform(17.0, 24.0, n) for name in ("T_x", "T_y", "T_z", "T_wp")}
    mine = machine.nominal_error_um(q, stylus, temps)
    theirs = project.volumetric_error(q, stylus_mm=stylus, temps_C=temps)
    assert np.abs(mine).max() > 10.0
    np.testing.assert_allclose(mine, theirs, atol=1e-6, rtol=0)
    first = project.volumetric_error(q, stylus_mm=stylus, temps_C=temps, method="first_order")
    assert np.abs(mine - first).max() > 1e-6  # the check above really is of the exact chain


def test_chain_hand_values() -> None:
    n = 1
    zero = np.zeros((n, 3, 6))
    sq0 = np.zeros((n, 3))
    # MB1, pitch of X (rotation about y) of 0.01 rad, stylus 150 mm down, ram 400 mm out:
    # the tip is rotated exactly about the X carriage: ΔX = sin θ·a_z, ΔZ = (cos θ − 1)·a_z.
    errors = zero.copy()
    errors[0, 0, 4] = 1e4  # µrad
    u = np.array([[100.0, 200.0, 400.0]])
    p = np.array([[0.0, 0.0, -150.0]])
    got = stylus_error_um("MB1", u, p, errors, sq0)[0]
    a_z = 400.0 - 150.0
    np.testing.assert_allclose(
        got, [np.sin(0.01) * a_z * 1e3, 0.0, (np.cos(0.01) - 1) * a_z * 1e3], atol=1e-8
    )
    # FB1: the table's linear error is that of the relative motion (docs/conventions.md)
    errors = zero.copy()
    errors[0, 1, 1] = 1.0  # dy_y
    np.testing.assert_allclose(stylus_error_um("FB1", u, p, errors, sq0)[0], [0, 1.0, 0], atol=1e-9)
    # squareness α tilts X: travel along (cos α, −sin α, 0)
    sq = np.array([[1e4, 0.0, 0.0]])
    got = stylus_error_um("MB1", u, p, zero, sq)[0]
    np.testing.assert_allclose(
        got, [100 * (np.cos(0.01) - 1) * 1e3, -100 * np.sin(0.01) * 1e3, 0], atol=1e-8
    )


def test_table_names_cover_the_eighteen_components() -> None:
    assert len(set(TABLE_NAMES)) == 18
    assert table_slot("ey_x") == (0, 4)
    assert table_slot("dz_y") == (1, 2)


def test_lag_matches_the_closed_form_of_a_ramp() -> None:
    t = np.arange(0.0, 40000.0, 30.0)
    rate, tau, y0 = 2e-4, 1800.0, 3.0
    got = lag(t, rate * t, tau, start=y0)
    exact = rate * (t - tau) + (y0 + rate * tau) * np.exp(-t / tau)
    np.testing.assert_allclose(got, exact, atol=1e-10)
    with pytest.raises(ValueError, match="time constant"):
        lag(t, t, float("nan"))
    with pytest.raises(ValueError, match="uniform"):
        lag(np.array([0.0, 1.0, 3.0]), np.zeros(3), 10.0)


def test_beam_deflections_match_closed_forms() -> None:
    kappa = np.ones_like(GRID)
    w, ws = deflection("simply_supported", kappa)
    np.testing.assert_allclose(w, (GRID**2 - GRID) / 2, atol=1e-6)
    w, ws = deflection("cantilever", kappa)
    np.testing.assert_allclose(w, GRID**2 / 2, atol=1e-6)
    np.testing.assert_allclose(ws, GRID, atol=1e-6)
    w, _ = deflection("propped", kappa)  # fixed at 0, pinned at 1: −κ s²(1 − s)/4
    np.testing.assert_allclose(w, -(GRID**2) * (1 - GRID) / 4, atol=1e-6)
    w, _ = deflection("clamped", kappa)  # a uniform gradient is fully restrained
    assert np.abs(w).max() < 1e-6
    with pytest.raises(ValueError, match="unknown support"):
        deflection("glued", kappa)


# ------------------------------------------------------------------ the effects
def _signal_left_by_the_project(case: Case) -> np.ndarray:
    """Observed − the project's model of the description − noise − sensor-noise thermal term:
    the hidden signal, measured without the generator's own signal path."""
    project = Machine.from_dict(case.description.toml_dict())
    q = case.indicated_mm
    logged = case.session.temps_C
    temps = {k: logged[k] for k in ("T_x", "T_y", "T_z", "T_wp")}
    predicted = project.volumetric_error(q, stylus_mm=case.session.stylus_mm, temps_C=temps)
    sensor = case.description.thermal_um(q, logged) - case.description.thermal_um(
        q, true_temperatures(case.session)
    )
    return (case.reference_mm - q) * 1e3 - predicted - case.noise_um + sensor


@pytest.mark.parametrize("cause", CAUSES)
def test_every_cause_is_sized_finite_and_named(cause: str) -> None:
    size = {"coupling": 0.5, "periodic": 3.0}.get(cause, 1.0)
    case = make_case([cause], [size], seed=3, design=SMALL)
    assert case.hidden == [case.effects[0].identity] and case.hidden[0].cause == cause
    assert np.all(np.isfinite(case.reference_mm))
    signal = _signal_left_by_the_project(case)
    assert rms3d_um(signal) == pytest.approx(size * SMALL.noise_rms_3d_um, rel=0.011)
    np.testing.assert_allclose(signal, case.hidden_signal_um, atol=2e-3)
    knob = case.effects[0].knob
    lo, hi = case.effects[0].knob_range
    assert lo <= abs(knob) <= hi
    if cause != "parametric":
        assert case.effects[0].record["nontable_chi2"] >= 30.0


def test_pairs_and_clean_sessions() -> None:
    pair = make_case(["reversal", "probe_lobing"], [0.5, 3.0], seed=1, design=SMALL)
    by_cause = {e.identity.cause: e for e in pair.effects}
    assert set(by_cause) == {"reversal", "probe_lobing"}
    for cause, size in (("reversal", 0.5), ("probe_lobing", 3.0)):
        alone = rms3d_um(by_cause[cause].forward(by_cause[cause].knob).direct_um)
        if cause == "probe_lobing":  # direct at the tip: its signal is its contribution
            assert alone == pytest.approx(size * SMALL.noise_rms_3d_um, rel=0.011)
        assert by_cause[cause].record["signal_rms_3d_um"] == pytest.approx(
            size * SMALL.noise_rms_3d_um, rel=0.011
        )
    clean = make_case([], [], seed=1, design=SMALL)
    assert clean.hidden == [] and not np.any(clean.hidden_signal_um)
    residual = (clean.reference_mm - clean.indicated_mm) * 1e3 - clean.noise_um
    assert np.abs(residual).max() > 1.0  # the description's own errors are there …
    assert np.std(clean.noise_um) == pytest.approx(SMALL.noise_um, rel=0.1)  # … and the noise


def test_reproducible_by_seed(tmp_path: Path) -> None:
    paths = []
    for name, seed in (("a", 5), ("b", 5), ("c", 6)):
        case = make_case(["periodic"], [1.0], seed=seed, design=SMALL)
        paths.append(write_case(case, tmp_path / name))
    (ta, ca), (tb, cb), (_tc, cc) = paths
    assert ta.read_bytes() == tb.read_bytes() and ca.read_bytes() == cb.read_bytes()
    assert ca.read_bytes() != cc.read_bytes()


def test_files_follow_the_formats_and_read_back(tmp_path: Path) -> None:
    design = SessionDesign(model="FB1", layout="lines", n_points=300, styli=5, noise_um=0.5)
    case = make_case(["drift"], [1.0], seed=2, design=design)
    toml_path, csv_path = write_case(case, tmp_path)
    machine = Machine.from_toml(toml_path)
    data = read_measurements(csv_path)
    assert machine.model == "FB1" and not machine.warnings
    assert data.n == case.session.n
    np.testing.assert_allclose(data.indicated_mm, case.indicated_mm, atol=1e-9)
    assert data.normals is not None and data.stylus_mm is not None and data.group is not None
    assert len(set(data.group)) == 7
    observed = data.observed_error_um()
    temps = {k: data.temps_C[k] for k in ("T_x", "T_y", "T_z", "T_wp")}
    predicted = machine.volumetric_error(data.indicated_mm, stylus_mm=data.stylus_mm, temps_C=temps)
    # what the project's model of the written files leaves = the hidden effect + the noise + what
    # the logged temperatures' 3 mK sensor noise does through the thermal terms (+ rounding)
    q = case.indicated_mm
    sensor = case.description.thermal_um(q, case.session.temps_C) - case.description.thermal_um(
        q, true_temperatures(case.session)
    )
    assert 1e-3 < np.abs(sensor).max() < 0.2
    leftover = observed - predicted - case.hidden_signal_um - case.noise_um + sensor
    assert np.abs(leftover).max() < 2e-3


# ------------------------------------------------------------------ scoring
def _entry(cause: str, **keys: str) -> dict:
    return {"cause": cause, **keys, "parameters": {}, "explained_fraction": 1.0}


def test_scoring_named_strict_alternatives_and_clean() -> None:
    hidden = [Identity("parametric", component="ex_z")]
    noise = 0.433
    exact = {
        "verdict": "found",
        "effects": [_entry("parametric", component="ex_z")],
        "heldout_rms_um": {"after": 0.5},
    }
    s = score_diagnosis(hidden, exact, noise)
    assert s.named and s.strict and s.heldout_ok and s.heldout_ratio == pytest.approx(0.5 / noise)
    alt = {
        "verdict": "found",
        "effects": [
            {
                **_entry("parametric", component="dy_z"),
                "alternatives": [{"cause": "parametric", "component": "ex_z"}],
            }
        ],
        "heldout_rms_um": {"after": 0.7},
    }
    s = score_diagnosis(hidden, alt, noise)
    assert s.named and not s.strict and not s.heldout_ok
    extra = {
        "verdict": "found",
        "effects": [_entry("parametric", component="ex_z"), _entry("drift", axis="x")],
    }
    s = score_diagnosis(hidden, extra, noise)
    assert not s.named and s.extra == ["drift(axis=x)"]
    # a pair: two entries, matched one to one
    pair = [Identity("periodic", axis="z"), Identity("reversal", axis="x")]
    two = {
        "verdict": "found",
        "effects": [_entry("reversal", axis="x"), _entry("periodic", axis="z", period_mm="5")],
    }
    assert score_diagnosis(pair, two, noise).strict
    one = {"verdict": "found", "effects": [_entry("periodic", axis="z")]}
    assert not score_diagnosis(pair, one, noise).named
    both_in_one = {
        "verdict": "found",
        "effects": [
            {**_entry("periodic", axis="z"), "alternatives": [{"cause": "reversal", "axis": "x"}]}
        ],
    }
    assert not score_diagnosis(pair, both_in_one, noise).named  # one entry, two hidden effects
    harmonic = {
        "verdict": "found",
        "effects": [_entry("periodic", axis="z"), _entry("periodic", axis="z")],
    }
    assert score_diagnosis([Identity("periodic", axis="z")], harmonic, noise).strict  # a set
    assert score_diagnosis([], {"verdict": "none", "effects": []}, noise).named
    assert not score_diagnosis(
        [], {"verdict": "found", "effects": [_entry("unexplained")]}, noise
    ).named
    assert score_diagnosis(hidden, None, noise).error == "no diagnosis JSON"


def test_identity_reading_is_the_contracts() -> None:
    assert identity_from_entry(_entry("coupling", component="EY_X", varies_with="y")) == Identity(
        "coupling", component="ey_x", varies_with="y"
    )
    assert identity_from_entry({"cause": "thermal_lag", "axis": "x"}) == Identity("thermal_lag")
    assert identity_from_entry({"cause": "no-such"}) is None
    assert identity_from_entry({"cause": "periodic"}) == Identity("periodic", axis="?")
    with pytest.raises(ValueError, match="required"):
        Identity("coupling", component="ey_x")


# ------------------------------------------------------------------ bad input
@pytest.mark.parametrize(
    ("kwargs", "match"),
    [
        ({"causes": ["nope"]}, "unknown cause"),
        ({"causes": ["drift", "drift"], "sizes": [1.0, 1.0]}, "each cause once"),
        ({"causes": ["drift"], "sizes": [float("nan")]}, "effect size"),
        ({"causes": ["drift"], "sizes": [float("inf")]}, "effect size"),
        ({"causes": ["drift"], "sizes": [-1.0]}, "effect size"),
        ({"causes": ["drift"], "sizes": [1.0, 2.0]}, "one size per cause"),
        ({"causes": ["drift"], "seed": -3}, "seed"),
    ],
)
def test_make_case_refuses_bad_input(kwargs: dict, match: str) -> None:
    with pytest.raises(ValueError, match=match):
        make_case(**kwargs)


@pytest.mark.parametrize(
    ("kwargs", "match"),
    [
        ({"noise_um": float("nan")}, "noise_um"),
        ({"noise_um": 0.0}, "noise_um"),
        ({"n_points": 10}, "n_points"),
        ({"duration_h": float("inf")}, "duration_h"),
        ({"styli": 3}, "styli"),
        ({"layout": "grid"}, "layout"),
        ({"model": "XX9"}, "model"),
    ],
)
def test_design_refuses_bad_input(kwargs: dict, match: str) -> None:
    with pytest.raises(ValueError, match=match):
        SessionDesign(**kwargs)


# ------------------------------------------------------------------ independence
def test_generator_imports_nothing_of_the_project() -> None:
    forbidden = (
        "cmm_comp",
        "compensation",
        "sim_controller",
        "independent_generator",
        "daemon",
        "protocol",
        "cli",
    )
    for path in PACKAGE.glob("*.py"):
        tree = ast.parse(path.read_text())
        for node in ast.walk(tree):
            names: list[str] = []
            if isinstance(node, ast.Import):
                names = [a.name for a in node.names]
            elif isinstance(node, ast.ImportFrom) and node.level == 0 and node.module:
                names = [node.module]
            for name in names:
                assert name.split(".")[0] not in forbidden, f"{path.name} imports {name}"
