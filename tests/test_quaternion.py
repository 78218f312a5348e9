"""Unit quaternions (w, x, y, z) against scipy Rotation/Slerp and numpy-quaternion."""

from __future__ import annotations

import numpy as np
import pytest
import quaternion as npq
from hypothesis import given, settings
from hypothesis import strategies as st
from hypothesis.extra.numpy import arrays
from scipy.spatial.transform import Rotation, Slerp

from cmm_comp.compensation.grid import quaternion as qt

RNG_SEED = 20240517


def _rots(n: int, seed: int = RNG_SEED) -> Rotation:
    return Rotation.random(n, rng=np.random.default_rng(seed))


def test_matrix_round_trip_against_scipy() -> None:
    rot = _rots(500)
    q = qt.quaternion_from_scipy(rot)
    np.testing.assert_allclose(qt.matrix_from_quaternion(q), rot.as_matrix(), atol=1e-14)
    q_back = qt.quaternion_from_matrix(rot.as_matrix())
    np.testing.assert_allclose(q_back, qt.canonical(q), atol=1e-14)
    assert np.all(q_back[:, 0] >= 0.0)


def test_matrix_near_180_degrees_uses_stable_branch() -> None:
    # trace ≈ −1: the paper's formula (divide by 4s, s from the trace) is singular here
    rotvec = np.array([[np.pi - 1e-9, 0, 0], [0, np.pi, 0], [0, 0, np.pi], [1, 1, 1]])
    rotvec[3] *= np.pi / np.sqrt(3)
    rot = Rotation.from_rotvec(rotvec)
    q = qt.quaternion_from_matrix(rot.as_matrix())
    np.testing.assert_allclose(qt.matrix_from_quaternion(q), rot.as_matrix(), atol=1e-14)


def test_multiply_matches_scipy_composition_and_numpy_quaternion() -> None:
    a, b = _rots(200, 1), _rots(200, 2)
    qa, qb = qt.quaternion_from_scipy(a), qt.quaternion_from_scipy(b)
    prod = qt.multiply(qa, qb)
    np.testing.assert_allclose(
        qt.canonical(prod), qt.canonical(qt.quaternion_from_scipy(a * b)), atol=1e-14
    )
    ref = npq.as_float_array(npq.as_quat_array(qa) * npq.as_quat_array(qb))
    np.testing.assert_allclose(prod, ref, atol=1e-15)
    # matrix of a product is the product of matrices (active, pre-multiplication)
    np.testing.assert_allclose(
        qt.matrix_from_quaternion(prod), a.as_matrix() @ b.as_matrix(), atol=1e-14
    )


def test_rotvec_and_rotate_against_scipy() -> None:
    rot = _rots(300, 3)
    rv = rot.as_rotvec()
    q = qt.quaternion_from_rotvec(rv)
    np.testing.assert_allclose(
        qt.canonical(q), qt.canonical(qt.quaternion_from_scipy(rot)), atol=1e-14
    )
    np.testing.assert_allclose(qt.rotvec_from_quaternion(q), rv, atol=1e-12)
    v = np.random.default_rng(4).normal(size=(300, 3))
    np.testing.assert_allclose(qt.rotate(q, v), rot.apply(v), atol=1e-13)


def test_tiny_rotation_vectors_are_exact_to_rounding() -> None:
    rv = np.array([[1e-6, -2e-6, 3e-7], [1e-12, 0, 0], [0, 0, 0]])
    q = qt.quaternion_from_rotvec(rv)
    np.testing.assert_allclose(qt.rotvec_from_quaternion(q), rv, rtol=1e-12, atol=1e-30)
    np.testing.assert_allclose(
        qt.matrix_from_quaternion(q), Rotation.from_rotvec(rv).as_matrix(), atol=1e-17
    )


def test_log_exp_against_numpy_quaternion() -> None:
    q = qt.quaternion_from_scipy(_rots(100, 5))
    ref = npq.as_float_array(np.log(npq.as_quat_array(q)))
    np.testing.assert_allclose(qt.log(q), ref[:, 1:], atol=1e-13)
    np.testing.assert_allclose(ref[:, 0], 0.0, atol=1e-13)
    v = np.random.default_rng(6).normal(size=(100, 3))
    ref_exp = npq.as_float_array(np.exp(npq.as_quat_array(np.c_[np.zeros(100), v])))
    np.testing.assert_allclose(qt.exp(v), ref_exp, atol=1e-13)


def test_slerp_against_scipy_and_numpy_quaternion() -> None:
    keys = _rots(2, 7)
    h = np.linspace(0.0, 1.0, 11)
    ref = Slerp([0.0, 1.0], keys)(h)
    q0, q1 = qt.quaternion_from_scipy(keys)
    ours = qt.slerp(
        np.broadcast_to(q0, (11, 4)), np.broadcast_to(q1, (11, 4)), h, shortest_path=True
    )
    np.testing.assert_allclose(qt.matrix_from_quaternion(ours), ref.as_matrix(), atol=1e-13)
    if q0 @ q1 < 0:
        q1 = -q1
    nq = npq.as_float_array(
        np.array([npq.slerp_evaluate(npq.quaternion(*q0), npq.quaternion(*q1), t) for t in h])
    )
    np.testing.assert_allclose(ours, nq, atol=1e-13)


def test_make_continuous_removes_sign_flips() -> None:
    q = qt.quaternion_from_rotvec(np.outer(np.linspace(0, 1, 20), [1e-4, 2e-4, 0]))
    flips = np.where(np.arange(20) % 3 == 1, -1.0, 1.0)[:, None]
    fixed = qt.make_continuous(q * flips)
    np.testing.assert_array_equal(fixed, q)
    ref = npq.as_float_array(npq.unflip_rotors(npq.as_quat_array(q * flips), axis=0))
    np.testing.assert_array_equal(fixed, ref)


def test_bad_shapes_raise_with_message() -> None:
    with pytest.raises(ValueError, match="length 4"):
        qt.multiply(np.zeros(3), np.zeros(4))
    with pytest.raises(ValueError, match="zero or non-finite"):
        qt.normalize(np.zeros(4))


unit_quats = arrays(
    np.float64, (4,), elements=st.floats(-1.0, 1.0, allow_nan=False, allow_subnormal=False)
).filter(lambda a: np.linalg.norm(a) > 1e-3)


@settings(max_examples=200, deadline=None)
@given(unit_quats, unit_quats, st.floats(0.0, 1.0))
def test_properties_unit_norm_round_trips(a: np.ndarray, b: np.ndarray, h: float) -> None:
    qa, qb = qt.normalize(a), qt.normalize(b)
    assert abs(np.linalg.norm(qt.multiply(qa, qb)) - 1.0) < 1e-14
    assert abs(np.linalg.norm(qt.slerp(qa, qb, h)) - 1.0) < 1e-14
    np.testing.assert_allclose(qt.multiply(qa, qt.inverse(qa)), [1, 0, 0, 0], atol=1e-15)
    if np.any(qa[1:] != 0.0) or qa[0] > 0:  # log(−1) = π·n has no defined axis n
        np.testing.assert_allclose(qt.exp(qt.log(qa)), qa, atol=1e-14)
    back = qt.quaternion_from_matrix(qt.matrix_from_quaternion(qa))
    # q and −q are the same rotation (w = 0 makes the canonical sign ambiguous)
    assert min(np.abs(back - qa).max(), np.abs(back + qa).max()) < 1e-14
    m = qt.matrix_from_quaternion(qa)
    np.testing.assert_allclose(m.T @ m, np.eye(3), atol=1e-14)
    assert np.linalg.det(m) == pytest.approx(1.0, abs=1e-14)


@settings(max_examples=200, deadline=None)
@given(arrays(np.float64, (3,), elements=st.floats(-1.5, 1.5, allow_subnormal=False)))
def test_property_log_inverts_exp(v: np.ndarray) -> None:
    # |v| < π/2·√3 ≈ 2.6 < π: log is the principal inverse of exp
    np.testing.assert_allclose(qt.log(qt.exp(v)), v, atol=1e-13)


def test_log_exp_round_trip_near_minus_one_with_tiny_vector() -> None:
    """Found by hypothesis in CI: |v| ~ 1e-306 underflowed to 0, so log forgot the axis and
    exp(log(q)) returned +1 for q ≈ −1."""
    q = np.array([-1.0, 1.8369361e-306, 1.8369361e-306, 1.8369361e-306])
    np.testing.assert_allclose(qt.exp(qt.log(q)), q, atol=1e-14)
