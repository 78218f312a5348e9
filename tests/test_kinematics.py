"""The kinematic chains against the paper's appendix A.1 and against exact rigid-body algebra."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from paper_a1 import CORRECTIONS, PRINTED
from scipy.spatial.transform import Rotation

from cmm_comp.compensation.kinematics import (
    MODEL_CHAINS,
    Chain,
    exact_pose,
    first_order_error,
    first_order_jacobian,
    rotation_from_angles,
)
from cmm_comp.compensation.parametric_errors import TABLE_COMPONENTS, parse_component

SQ = ("alpha", "beta1", "beta2")


def _paper_coefficients(model: str, u: np.ndarray, p: np.ndarray, *, corrected: bool):
    """Coefficient of every error in the printed (optionally corrected) equations, arms in metres."""
    base = dict.fromkeys([*TABLE_COMPONENTS, *SQ, "phi1", "phi2"], 0.0)
    base.update(
        x=u[0] / 1e3, y=u[1] / 1e3, z=u[2] / 1e3, Xp=p[0] / 1e3, Yp=p[1] / 1e3, Zp=p[2] / 1e3
    )
    out = {}
    for i, expr in enumerate(PRINTED[model]):
        if corrected and (model, i) in CORRECTIONS:
            expr = f"({expr}) + {CORRECTIONS[(model, i)]}"
        for name in (*TABLE_COMPONENTS, *SQ):
            env = dict(base)
            env[name] = 1.0
            out[(i, name)] = eval(expr, {}, env)
    return out


def _chain_coefficients(model: str, u: np.ndarray, p: np.ndarray):
    jac, sq = first_order_jacobian(MODEL_CHAINS[model], u[None], p[None])
    out = {}
    for i in range(3):
        for name in TABLE_COMPONENTS:
            c = parse_component(name)
            out[(i, name)] = jac[0, i, "xyz".index(c.axis), c.slot]
        for j, name in enumerate(SQ):
            out[(i, name)] = sq[0, i, j]
    return out


@pytest.mark.parametrize("model", sorted(PRINTED))
def test_first_order_chain_reproduces_appendix_a1_term_by_term(model: str) -> None:
    rng = np.random.default_rng(hash(model) % 2**32)
    for _ in range(3):
        u, p = rng.uniform(-900, 900, 3), rng.uniform(-200, 200, 3)
        paper = _paper_coefficients(model, u, p, corrected=True)
        chain = _chain_coefficients(model, u, p)
        bad = {k: (paper[k], chain[k]) for k in paper if abs(paper[k] - chain[k]) > 1e-12}
        assert not bad, f"{model}: printed (corrected) vs chain differ at {bad}"


@pytest.mark.parametrize(("model", "component"), sorted(CORRECTIONS))
def test_every_documented_correction_is_a_real_disagreement(model: str, component: int) -> None:
    """The correction list is minimal: without it the printed equation disagrees with the chain."""
    u, p = np.array([300.0, 500.0, 200.0]), np.array([10.0, -20.0, -100.0])
    paper = _paper_coefficients(model, u, p, corrected=False)
    chain = _chain_coefficients(model, u, p)
    assert any(
        abs(paper[(component, n)] - chain[(component, n)]) > 1e-9 for n in (*TABLE_COMPONENTS, *SQ)
    )


def test_rotation_matches_scipy_intrinsic_xyz() -> None:
    """R = Rx·Ry·Rz (Hermann's matrix) is scipy's intrinsic 'XYZ' Euler sequence."""
    rng = np.random.default_rng(3)
    ang_urad = rng.normal(0, 2e5, (50, 3))  # up to ~0.5 rad: exactness, not small-angle
    ours = rotation_from_angles(ang_urad)
    ref = Rotation.from_euler("XYZ", ang_urad * 1e-6).as_matrix()
    np.testing.assert_allclose(ours, ref, atol=1e-14)


def _random_errors(rng: np.random.Generator, n: int, lin_um: float, ang_urad: float) -> np.ndarray:
    return np.concatenate(
        [rng.normal(0, lin_um, (n, 3, 3)), rng.normal(0, ang_urad, (n, 3, 3))], axis=2
    )


@pytest.mark.parametrize("model", sorted(MODEL_CHAINS))
def test_exact_minus_first_order_is_second_order(model: str) -> None:
    """Scaling every error by s scales (exact − first order) by s²: the difference is 2nd order."""
    rng = np.random.default_rng(7)
    n = 200
    u = rng.uniform(-1000, 1000, (n, 3))
    p = rng.uniform(-200, 200, (n, 3))
    errs = _random_errors(rng, n, 10.0, 50.0)
    sq = rng.normal(0, 20, (n, 3))
    diffs = []
    for s in (1.0, 10.0):
        rot, t = exact_pose(MODEL_CHAINS[model], u, errs * s, sq * s)
        exact = t + 1000 * np.einsum("nij,nj->ni", rot - np.eye(3), p)
        first = first_order_error(MODEL_CHAINS[model], u, errs * s, sq * s, p)
        diffs.append(np.abs(exact - first).max())
    assert (
        diffs[0] < 0.05
    )  # tens of µrad over 1 m arms: first order good to a few hundredths of a µm
    assert 60 < diffs[1] / diffs[0] < 140  # ×10 errors → ×100 difference


def _h(rot: np.ndarray, t: np.ndarray) -> np.ndarray:
    m = np.eye(4)
    m[:3, :3], m[:3, 3] = rot, t
    return m


@settings(max_examples=40, deadline=None)
@given(
    model=st.sampled_from(sorted(MODEL_CHAINS)),
    seed=st.integers(0, 2**31),
)
def test_exact_pose_equals_explicit_homogeneous_product(model: str, seed: int) -> None:
    """Oracle: the chain written out as 4×4 matrices, T_base_work⁻¹ · T_base_tip, with big errors."""
    rng = np.random.default_rng(seed)
    chain = MODEL_CHAINS[model]
    u = rng.uniform(-800, 800, 3)
    p = rng.uniform(-200, 200, 3)
    errs = _random_errors(rng, 1, 500.0, 20000.0)[0]  # large: no small-angle shortcut survives
    sq = rng.normal(0, 5000, 3)
    a, b1, b2 = sq * 1e-6
    d = {
        "x": np.array([np.cos(a), -np.sin(a), 0.0]),
        "y": np.array([0.0, 1.0, 0.0]),
        "z": np.array([-np.sin(b1) * np.cos(b2), -np.sin(b2), np.cos(b1) * np.cos(b2)]),
    }
    rots = {
        ax: Rotation.from_euler("XYZ", errs[k, 3:] * 1e-6).as_matrix() for k, ax in enumerate("xyz")
    }
    delta = {ax: errs[k, :3] / 1000 for k, ax in enumerate("xyz")}
    uu = dict(zip("xyz", u, strict=True))
    t_tool = np.eye(4)
    for ax in chain.tool:
        t_tool = t_tool @ _h(np.eye(3), uu[ax] * d[ax]) @ _h(rots[ax], delta[ax])
    t_work = np.eye(4)
    for ax in chain.workpiece:
        t_work = t_work @ _h(np.eye(3), -uu[ax] * d[ax]) @ _h(rots[ax], -delta[ax])
    tip = np.linalg.inv(t_work) @ t_tool @ np.r_[p, 1.0]
    expected_um = (tip[:3] - u - p) * 1000
    rot, t = exact_pose(chain, u[None], errs[None], sq[None])
    got = t[0] + 1000 * (rot[0] - np.eye(3)) @ p
    np.testing.assert_allclose(got, expected_um, atol=1e-7)
    # the error rotation is a proper rotation
    np.testing.assert_allclose(rot[0] @ rot[0].T, np.eye(3), atol=1e-12)
    assert np.linalg.det(rot[0]) == pytest.approx(1.0)


def test_chain_must_name_each_axis_once() -> None:
    with pytest.raises(ValueError, match="exactly once"):
        Chain(tool=("x", "y"), workpiece=("y",))


def test_cy1_lower_table_axis_is_y() -> None:
    """Section 2's text names Y twice for CY1; its equations need Y as the lower (primary) table:
    ΔX carries y·Ez(y) (own travel) and ΔZ carries −y·Ex(x) and −y·Ex(y), but ΔY has no x·Ez(y)."""
    chain = MODEL_CHAINS["CY1"]
    assert chain.workpiece == ("y", "x")
    jac, _ = first_order_jacobian(chain, np.array([[400.0, 300.0, 0.0]]), np.zeros((1, 3)))
    assert jac[0, 1, 1, 5] == 0.0  # ΔY has no x·Ez(y): X rides above Y
    assert jac[0, 0, 1, 5] == pytest.approx(0.3)  # ΔX: +y·Ez(y), arm 300 mm → 0.3 µm/µrad
