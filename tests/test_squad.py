"""Squad through keyframes: invariants and agreement with numpy-quaternion's ``squad``."""

from __future__ import annotations

import numpy as np
import pytest
import quaternion as npq

from cmm_comp.compensation.grid import quaternion as qt
from cmm_comp.compensation.grid.squad import squad, squad_control_points


def _keys(n: int, scale_rad: float, seed: int = 11) -> np.ndarray:
    rng = np.random.default_rng(seed)
    rotvec = np.cumsum(rng.normal(scale=scale_rad, size=(n, 3)), axis=0)
    return qt.make_continuous(qt.quaternion_from_rotvec(rotvec))


@pytest.mark.parametrize("scale", [1e-5, 1e-3, 0.4])
def test_hits_keyframes_and_stays_unit(scale: float) -> None:
    keys = _keys(7, scale)
    np.testing.assert_allclose(squad(keys, np.arange(7.0)), keys, atol=1e-15)
    u = np.linspace(0.0, 6.0, 601)
    np.testing.assert_allclose(np.linalg.norm(squad(keys, u), axis=-1), 1.0, atol=1e-15)


@pytest.mark.parametrize("scale", [1e-3, 0.4])
def test_c0_and_c1_at_keyframes(scale: float) -> None:
    keys = _keys(6, scale)
    eps = 1e-6
    for i in range(1, 5):
        left = squad(keys, [i - 2 * eps, i - eps, float(i)])
        right = squad(keys, [float(i), i + eps, i + 2 * eps])
        np.testing.assert_allclose(left[-1], right[0], atol=1e-15)  # C0
        # one-sided 2nd-order differences: derivative from the left == from the right
        d_left = (3 * left[2] - 4 * left[1] + left[0]) / (2 * eps)
        d_right = (-3 * right[0] + 4 * right[1] - right[2]) / (2 * eps)
        np.testing.assert_allclose(d_left, d_right, atol=2e-7 * scale + 1e-9)


def test_slerp_is_not_c1_so_the_c1_test_can_fail() -> None:
    keys = _keys(4, 0.4)
    eps = 1e-6
    i = 1
    d_left = qt.log(qt.multiply(qt.conjugate(keys[i - 1]), keys[i]))
    d_right = qt.log(qt.multiply(qt.conjugate(keys[i]), keys[i + 1]))
    assert np.abs(d_left - d_right).max() > 1e3 * eps


@pytest.mark.parametrize("scale", [2e-5, 2e-3, 0.3])
def test_agrees_with_numpy_quaternion_squad(scale: float) -> None:
    keys = _keys(9, scale, seed=3)
    t_in = np.arange(9.0)
    t_out = np.linspace(0.0, 7.999, 400)  # numpy-quaternion wraps at exactly t_in[-1]
    ref = npq.as_float_array(npq.squad(npq.as_quat_array(keys), t_in, t_out))
    ours = squad(keys, t_out)
    np.testing.assert_allclose(ours, ref, atol=1e-14)


def test_control_points_boundary_rule_and_sign_check() -> None:
    keys = _keys(5, 1e-3)
    s = squad_control_points(keys)
    np.testing.assert_array_equal(s[0], keys[0])
    np.testing.assert_array_equal(s[-1], keys[-1])
    # interior: Shoemake's formula written with numpy-quaternion's own log/exp
    k = npq.as_quat_array(keys)
    s2 = k[2] * np.exp(-(np.log(~k[2] * k[3]) + np.log(~k[2] * k[1])) / 4)
    np.testing.assert_allclose(s[2], npq.as_float_array(s2), atol=1e-15)
    bad = keys.copy()
    bad[2] *= -1
    with pytest.raises(ValueError, match="sign-continuous"):
        squad_control_points(bad)
    with pytest.raises(ValueError, match=r"lie in \[0, 4\]"):
        squad(keys, [4.5])


def test_quadratic_boundary_rule_is_more_accurate_at_the_ends() -> None:
    # keyframes sampled from a smooth known curve; compare the end segments
    t = np.linspace(0.0, 1.0, 9)
    rotvec = np.c_[np.sin(2 * t), np.cos(3 * t) - 1, t**2] * 1e-3
    keys = qt.quaternion_from_rotvec(rotvec)
    u = np.linspace(0.0, 1.0, 50)
    tu = u / 8.0
    exact = qt.quaternion_from_rotvec(np.c_[np.sin(2 * tu), np.cos(3 * tu) - 1, tu**2] * 1e-3)
    err = {}
    for rule in ("reflect", "quadratic"):
        q = squad(keys, u, boundary=rule)
        err[rule] = np.abs(qt.log(qt.multiply(qt.conjugate(exact), q))).max()
    assert err["quadratic"] < 0.2 * err["reflect"]
    s = squad_control_points(keys, boundary="quadratic")
    v1 = qt.log(qt.multiply(qt.conjugate(keys[0]), keys[1]))
    v2 = qt.log(qt.multiply(qt.conjugate(keys[0]), keys[2]))
    np.testing.assert_allclose(s[0], qt.multiply(keys[0], qt.exp((2 * v1 - v2) / 4)), atol=1e-16)
    with pytest.raises(ValueError, match="boundary must be"):
        squad_control_points(keys, boundary="natural")
