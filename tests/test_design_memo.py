"""Issue 26 item 7: a candidate's design built with its Legendre shapes evaluated once per axis
position vector (a memo shared by the unit-amplitude effects) is the design of the plain path.

The oracle is the plain path itself, kept here: one effect per unit amplitude, each evaluated on
a fresh context with no memo (every shape computed by the effect's own code). Designs must agree
to 1e-12 of their largest entry, on every candidate family the diagnosis builds from the
effects' hooks, on two machine models and two simulated sessions each, with their rich shapes
and their static images; and on hand-made effects (a coupling with a slope and a part along its
own axis, a span given as a list) whose shapes are written out below from numpy's Legendre
module, apart from the effects' code.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np
import pytest
from numpy.polynomial import legendre

from cmm_comp.compensation.diagnosis.candidate import (
    Candidate,
    effect_displacement_um,
    with_static_image,
)
from cmm_comp.compensation.diagnosis.candidates import all_candidates, all_twins
from cmm_comp.compensation.diagnosis.residuals import Residuals, compute_residuals
from cmm_comp.compensation.effects import (
    CouplingEffect,
    EvalContext,
    ParametricEffect,
    harmonic_kernel,
)
from cmm_comp.compensation.effects.parametric import SHAPES
from cmm_comp.compensation.machine import Machine
from cmm_comp.sim_controller.true_machine import simulate

MACHINES = Path(__file__).resolve().parents[1] / "examples" / "machines"


def _oracle(cand: Candidate, res: Residuals, theta: Any) -> np.ndarray:
    """The plain path: one effect per unit amplitude, no shared memo."""
    cols = []
    for j in range(cand.n_params):
        amps = [0.0] * cand.n_params
        amps[j] = 1.0
        cols.append(effect_displacement_um(res, cand.build(amps, theta)))
    return np.stack(cols, axis=2)


def _close(new: np.ndarray, old: np.ndarray) -> None:
    assert new.shape == old.shape
    scale = max(float(np.max(np.abs(old), initial=0.0)), 1e-300)
    assert float(np.max(np.abs(new - old), initial=0.0)) <= 1e-12 * scale


@pytest.fixture(
    scope="module",
    params=[("npl-bridge.toml", ["coupling"], 3), ("gec-mh2.toml", ["thermal_lag"], 5)],
    ids=["npl-coupling", "gec-lag"],
)
def session(request: pytest.FixtureRequest) -> Residuals:
    name, causes, seed = request.param
    machine = Machine.from_toml(MACHINES / name)
    _, data = simulate(machine, causes, [1.0], seed, n_points=300)
    return compute_residuals(machine, data)


def test_every_effect_built_design_is_the_plain_one(session: Residuals) -> None:
    cands = [*all_candidates(session), *all_twins(session)]
    checked: set[str] = set()
    for cand in cands:
        for c in (cand, cand.rich):
            if c is None or c.design_fn is not None:
                continue
            for theta in c.thetas[:2]:
                _close(c.design_uncached(session, theta), _oracle(c, session, theta))
            checked.add(c.cause)
            if c.drivers:  # its static image: both halves through the memo path
                img = with_static_image(c, session)
                theta = c.thetas[0]
                both = np.concatenate([_oracle(c, session, theta)] * 2, axis=2)
                new = img.design_uncached(session, theta)
                _close(new[:, :, c.n_params :], both[:, :, c.n_params :])
    # the families whose designs come from the effects' hooks are all there
    assert {"parametric", "coupling", "reversal"} <= checked, checked


def _legendre(q: np.ndarray, span: tuple[float, float], order: int, ref: float) -> np.ndarray:
    lo, hi = span
    c = np.zeros(order + 1)
    c[order] = 1.0
    s = 2.0 * (q - lo) / (hi - lo) - 1.0
    sr = 2.0 * (ref - lo) / (hi - lo) - 1.0
    return legendre.legval(s, c) - legendre.legval(sr, c)


def _ctx(q: np.ndarray, ref: np.ndarray, memo: dict[Any, Any] | None) -> EvalContext:
    n = q.shape[0]
    return EvalContext(
        q_mm=q,
        u_mm=q - ref,
        signals={},
        errors=np.zeros((n, 3, 6)),
        squareness_urad=np.zeros((n, 3)),
        direct_um=np.zeros((n, 3)),
        reference_C=20.0,
        reference_mm=ref,
        extras={} if memo is None else {SHAPES: memo},
    )


def test_hand_made_effects_match_numpy_legendre_with_and_without_memo() -> None:
    rng = np.random.default_rng(4)
    q = rng.uniform([0, -200, 100], [900, 700, 600], size=(200, 3))
    ref = np.array([300.0, 50.0, 400.0])
    span_a, span_b = (0.0, 900.0), (-200.0, 700.0)
    shape: dict[str, Any] = {"orders": (0, 1, 2), "along": [0.4, -0.2], "offset": 0.1}
    coupling = CouplingEffect(
        "dz_x", "y", [1.5, -0.7, 0.3], span_a, span_b, **shape, with_slope=True
    )
    parametric = ParametricEffect("dx_x", [2.0, -1.0, 0.5], [0.0, 900.0], [1, 2, 4])  # type: ignore[arg-type]
    memo: dict[Any, Any] = {}
    for memo_or_none in (None, memo, memo):  # no memo, a fresh one, the same one again
        ctx = _ctx(q, ref, memo_or_none)
        coupling.modify_errors(ctx)
        parametric.modify_errors(ctx)
        x, y = q[:, 0], q[:, 1]
        sb = _legendre(y, span_b, 1, ref[1])
        dz = (
            0.1
            + 0.4 * _legendre(x, span_a, 1, ref[0])
            - 0.2 * _legendre(x, span_a, 2, ref[0])
            + sb
            * (1.5 - 0.7 * _legendre(x, span_a, 1, ref[0]) + 0.3 * _legendre(x, span_a, 2, ref[0]))
        )
        dx = sum(
            c * _legendre(x, (0.0, 900.0), k, ref[0]) for c, k in ((2.0, 1), (-1.0, 2), (0.5, 4))
        )
        # the slope of dz along x (µrad): numerical derivative of the same shape
        h = 1e-3
        xs = np.stack([x + h, y, q[:, 2]], axis=1)
        xm = np.stack([x - h, y, q[:, 2]], axis=1)
        plus, minus = _ctx(xs, ref, None), _ctx(xm, ref, None)
        no_slope = CouplingEffect("dz_x", "y", [1.5, -0.7, 0.3], span_a, span_b, **shape)
        no_slope.modify_errors(plus)
        no_slope.modify_errors(minus)
        slope_urad = (plus.errors[:, 0, 2] - minus.errors[:, 0, 2]) / (2 * h) * 1000.0
        # dz_x is errors[:, x, slot of dz]; ey_x (the carriage tilt) follows −slope
        np.testing.assert_allclose(ctx.errors[:, 0, 2], dz, rtol=1e-12, atol=1e-9)
        np.testing.assert_allclose(ctx.errors[:, 0, 0], dx, rtol=1e-12, atol=1e-9)
        np.testing.assert_allclose(ctx.errors[:, 0, 4], -slope_urad, rtol=1e-6, atol=1e-6)
    assert memo, "the shared memo was used"


@pytest.mark.parametrize("compiled", [True, False], ids=["compiled", "numpy"])
def test_harmonic_columns_are_numpy_s_cos_and_sin(
    compiled: bool, monkeypatch: pytest.MonkeyPatch
) -> None:
    """The period-scan columns (compiled loop, and numpy below its threshold) against the numpy
    expression they replaced (phases ``np.outer(q, n·ω)``, numpy's ``cos``/``sin``), harmonics
    1–3, phases up to ~10⁵ rad."""
    monkeypatch.setattr(harmonic_kernel, "COMPILED_FROM", 0 if compiled else 10**12)
    rng = np.random.default_rng(11)
    q = rng.uniform(-50.0, 1500.0, 700)
    periods = tuple(rng.uniform(0.05, 400.0, 37))
    ref = 123.4
    x = harmonic_kernel.harmonic_columns(q, periods, ref, 3)
    w = 2.0 * np.pi / np.asarray(periods)
    assert x.shape == (700, 37, 6)
    for h in range(1, 4):
        ph, ph0 = np.outer(q, h * w), h * w * ref
        np.testing.assert_allclose(x[:, :, 2 * h - 2], np.cos(ph) - np.cos(ph0), rtol=0, atol=1e-12)
        np.testing.assert_allclose(x[:, :, 2 * h - 1], np.sin(ph) - np.sin(ph0), rtol=0, atol=1e-12)
