"""Unit quaternions as plain float arrays, vectorised.

Every quaternion in this module (and in the project) is an array whose last axis has
length 4 in the order **(w, x, y, z)**: scalar part first. Rotations are *active*, Hamilton
convention: the rotation matrix of ``q`` maps a vector ``v`` to ``q ⊗ [0, v] ⊗ q*``, and
``matrix_from_quaternion(multiply(p, q)) == matrix_from_quaternion(p) @ matrix_from_quaternion(q)``.

``log`` and ``exp`` follow the seed paper (Hermann, §6) and Dam et al.: for
``q = [cos θ, sin θ n]``, ``log q = θ n`` (a 3-vector, the *half* rotation angle times the
axis) and ``exp`` is its inverse. The rotation vector (axis × full angle, in radians) is
``2 log q``.

scipy's ``Rotation`` stores (x, y, z, w) by default; the only conversions are
:func:`quaternion_from_scipy` and :func:`scipy_from_quaternion`, which pass
``scalar_first=True`` explicitly.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike, NDArray
from scipy.spatial.transform import Rotation

__all__ = [
    "canonical",
    "conjugate",
    "exp",
    "inverse",
    "log",
    "make_continuous",
    "matrix_from_quaternion",
    "multiply",
    "normalize",
    "quaternion_from_matrix",
    "quaternion_from_rotvec",
    "quaternion_from_scipy",
    "random_quaternion",
    "rotate",
    "rotvec_from_quaternion",
    "scipy_from_quaternion",
    "slerp",
]

FloatArray = NDArray[np.float64]


def _as_quat(q: ArrayLike) -> FloatArray:
    arr = np.asarray(q, dtype=np.float64)
    if arr.shape[-1:] != (4,):
        raise ValueError(
            f"quaternion arrays need a last axis of length 4 (w, x, y, z), got {arr.shape}"
        )
    return arr


def _as_vec(v: ArrayLike) -> FloatArray:
    arr = np.asarray(v, dtype=np.float64)
    if arr.shape[-1:] != (3,):
        raise ValueError(f"vector arrays need a last axis of length 3, got shape {arr.shape}")
    return arr


def normalize(q: ArrayLike) -> FloatArray:
    """Scale quaternions (…, 4), order (w, x, y, z), to unit norm; zero norm raises."""
    arr = _as_quat(q)
    norm = np.linalg.norm(arr, axis=-1, keepdims=True)
    if np.any(norm == 0.0) or not np.all(np.isfinite(norm)):
        raise ValueError("cannot normalise a zero or non-finite quaternion")
    return arr / norm


def multiply(p: ArrayLike, q: ArrayLike) -> FloatArray:
    """Hamilton product ``p ⊗ q`` of quaternions (…, 4), order (w, x, y, z); broadcasts."""
    a = _as_quat(p)
    b = _as_quat(q)
    pw, px, py, pz = np.moveaxis(a, -1, 0)
    qw, qx, qy, qz = np.moveaxis(b, -1, 0)
    return np.stack(
        [
            pw * qw - px * qx - py * qy - pz * qz,
            pw * qx + px * qw + py * qz - pz * qy,
            pw * qy - px * qz + py * qw + pz * qx,
            pw * qz + px * qy - py * qx + pz * qw,
        ],
        axis=-1,
    )


def conjugate(q: ArrayLike) -> FloatArray:
    """Conjugate ``[w, -v]`` of quaternions (…, 4), order (w, x, y, z)."""
    arr = _as_quat(q).copy()
    arr[..., 1:] *= -1.0
    return arr


def inverse(q: ArrayLike) -> FloatArray:
    """Multiplicative inverse ``q* / |q|²`` of quaternions (…, 4), order (w, x, y, z)."""
    arr = _as_quat(q)
    return conjugate(arr) / np.sum(arr * arr, axis=-1, keepdims=True)


def canonical(q: ArrayLike) -> FloatArray:
    """Choose the sign of each quaternion (…, 4) so that w ≥ 0 (same rotations)."""
    arr = _as_quat(q)
    sign = np.where(arr[..., :1] < 0.0, -1.0, 1.0)
    return arr * sign


def make_continuous(q: ArrayLike, axis: int = 0) -> FloatArray:
    """Flip signs along ``axis`` so that successive quaternions have a non-negative dot product.

    ``q`` and ``-q`` are the same rotation; interpolation (Slerp, Squad) needs a sequence that
    does not jump between the two covers. ``q`` is (…, 4), order (w, x, y, z); ``axis`` counts
    the leading (non-quaternion) axes. The first element along ``axis`` keeps its sign.
    For a grid, call once per axis (see :func:`compensation.grid.make_grid_continuous`).
    """
    arr = np.array(_as_quat(q), copy=True)
    if arr.ndim < 2:
        return arr
    ax = axis % (arr.ndim - 1)
    moved = np.moveaxis(arr, ax, 0)
    for i in range(1, moved.shape[0]):
        dot = np.sum(moved[i] * moved[i - 1], axis=-1, keepdims=True)
        moved[i] *= np.where(dot < 0.0, -1.0, 1.0)
    return arr


def matrix_from_quaternion(q: ArrayLike) -> FloatArray:
    """Rotation matrices (…, 3, 3) of unit quaternions (…, 4), order (w, x, y, z).

    The quaternion is normalised first, so the result is orthonormal to rounding.
    """
    w, x, y, z = np.moveaxis(normalize(q), -1, 0)
    xx, yy, zz = x * x, y * y, z * z
    xy, xz, yz = x * y, x * z, y * z
    wx, wy, wz = w * x, w * y, w * z
    rows = [
        [1.0 - 2.0 * (yy + zz), 2.0 * (xy - wz), 2.0 * (xz + wy)],
        [2.0 * (xy + wz), 1.0 - 2.0 * (xx + zz), 2.0 * (yz - wx)],
        [2.0 * (xz - wy), 2.0 * (yz + wx), 1.0 - 2.0 * (xx + yy)],
    ]
    return np.stack([np.stack(r, axis=-1) for r in rows], axis=-2)


def quaternion_from_matrix(matrix: ArrayLike) -> FloatArray:
    """Unit quaternions (…, 4), order (w, x, y, z), w ≥ 0, of rotation matrices (…, 3, 3).

    Shepperd's method: of the four candidate formulas (from 4w², 4x², 4y², 4z²) the one
    with the largest pivot is used per element, so no branch divides by a small number.
    The seed paper's formula (s from the trace) is the first branch only and fails near
    180°. The result is normalised (absorbs a slightly non-orthonormal input).
    """
    m = np.asarray(matrix, dtype=np.float64)
    if m.shape[-2:] != (3, 3):
        raise ValueError(f"rotation matrices need shape (..., 3, 3), got {m.shape}")
    m00, m11, m22 = m[..., 0, 0], m[..., 1, 1], m[..., 2, 2]
    trace = m00 + m11 + m22
    pivots = np.stack([trace, m00, m11, m22], axis=-1)
    choice = np.argmax(pivots, axis=-1)
    out = np.empty((*m.shape[:-2], 4))
    # Candidate 0: from w.  Candidates 1..3: from x, y, z.
    cands = []
    s = np.sqrt(np.maximum(1.0 + trace, 0.0)) * 2.0  # 4w
    cands.append(
        np.stack(
            [
                0.25 * s,
                (m[..., 2, 1] - m[..., 1, 2]) / np.where(s == 0, 1, s),
                (m[..., 0, 2] - m[..., 2, 0]) / np.where(s == 0, 1, s),
                (m[..., 1, 0] - m[..., 0, 1]) / np.where(s == 0, 1, s),
            ],
            axis=-1,
        )
    )
    s = np.sqrt(np.maximum(1.0 + m00 - m11 - m22, 0.0)) * 2.0  # 4x
    ss = np.where(s == 0, 1, s)
    cands.append(
        np.stack(
            [
                (m[..., 2, 1] - m[..., 1, 2]) / ss,
                0.25 * s,
                (m[..., 0, 1] + m[..., 1, 0]) / ss,
                (m[..., 0, 2] + m[..., 2, 0]) / ss,
            ],
            axis=-1,
        )
    )
    s = np.sqrt(np.maximum(1.0 - m00 + m11 - m22, 0.0)) * 2.0  # 4y
    ss = np.where(s == 0, 1, s)
    cands.append(
        np.stack(
            [
                (m[..., 0, 2] - m[..., 2, 0]) / ss,
                (m[..., 0, 1] + m[..., 1, 0]) / ss,
                0.25 * s,
                (m[..., 1, 2] + m[..., 2, 1]) / ss,
            ],
            axis=-1,
        )
    )
    s = np.sqrt(np.maximum(1.0 - m00 - m11 + m22, 0.0)) * 2.0  # 4z
    ss = np.where(s == 0, 1, s)
    cands.append(
        np.stack(
            [
                (m[..., 1, 0] - m[..., 0, 1]) / ss,
                (m[..., 0, 2] + m[..., 2, 0]) / ss,
                (m[..., 1, 2] + m[..., 2, 1]) / ss,
                0.25 * s,
            ],
            axis=-1,
        )
    )
    stacked = np.stack(cands, axis=0)
    out[...] = np.take_along_axis(stacked, choice[None, ..., None], axis=0)[0]
    return canonical(normalize(out))


def log(q: ArrayLike) -> FloatArray:
    """Quaternion logarithm ``θ n`` (…, 3) of unit quaternions ``[cos θ, sin θ n]`` (…, 4).

    Order (w, x, y, z). ``θ = atan2(|v|, w)`` is accurate for tiny and near-π angles; the
    input is assumed unit norm (its norm is ignored). ``log(q) != log(-q)``: the sign of
    ``q`` chooses θ or π − θ, which is why sequences are made continuous before Squad.
    ``log([-1, 0, 0, 0])`` (θ = π, axis undefined) returns zero.
    """
    arr = _as_quat(q)
    vec = arr[..., 1:]
    # |v| without underflow: scale by the largest component first (|v| ~ 1e-306 still has a
    # direction, and for w < 0 it decides the axis of a rotation by ≈ 2π)
    big = np.max(np.abs(vec), axis=-1)
    safe = np.where(big > 0.0, big, 1.0)
    s = big * np.linalg.norm(vec / safe[..., None], axis=-1)
    theta = np.arctan2(s, arr[..., 0])
    with np.errstate(divide="ignore", invalid="ignore"):
        factor = np.where(s > 0.0, theta / np.where(s > 0.0, s, 1.0), 1.0)
    return vec * factor[..., None]


def exp(v: ArrayLike) -> FloatArray:
    """Quaternion exponential ``[cos θ, sin θ n]`` (…, 4), order (w, x, y, z), of ``θ n`` (…, 3)."""
    vec = _as_vec(v)
    theta = np.linalg.norm(vec, axis=-1)
    sinc = np.sinc(theta / np.pi)  # sin θ / θ, exact limit 1 at θ = 0
    return np.concatenate([np.cos(theta)[..., None], vec * sinc[..., None]], axis=-1)


def quaternion_from_rotvec(rotvec_rad: ArrayLike) -> FloatArray:
    """Unit quaternions (…, 4), order (w, x, y, z), of rotation vectors (…, 3) in radians."""
    return exp(0.5 * _as_vec(rotvec_rad))


def rotvec_from_quaternion(q: ArrayLike) -> FloatArray:
    """Rotation vectors (…, 3) in radians (angle ≤ π) of unit quaternions (…, 4), (w, x, y, z)."""
    return 2.0 * log(canonical(normalize(q)))


def rotate(q: ArrayLike, v: ArrayLike) -> FloatArray:
    """Rotate vectors (…, 3) by unit quaternions (…, 4), order (w, x, y, z): ``q v q*``."""
    qq = _as_quat(q)
    vec = _as_vec(v)
    u = qq[..., 1:]
    w = qq[..., :1]
    t = 2.0 * np.cross(u, vec)
    return vec + w * t + np.cross(u, t)


def slerp(q0: ArrayLike, q1: ArrayLike, h: ArrayLike, shortest_path: bool = False) -> FloatArray:
    """Spherical linear interpolation ``q0 ⊗ exp(h · log(q0⁻¹ ⊗ q1))``, order (w, x, y, z).

    Equal to the paper's ``(q0 sin((1−h)Ω) + q1 sin(hΩ)) / sin Ω`` but well conditioned for
    the tiny angles of error rotations. ``h`` broadcasts against the leading axes. With
    ``shortest_path=False`` (the default, as Squad needs) ``q1`` is used as given; with
    ``True`` it is negated where ``q0 · q1 < 0`` (what scipy's ``Slerp`` does for rotations).
    """
    a = _as_quat(q0)
    b = _as_quat(q1)
    if shortest_path:
        b = b * np.where(np.sum(a * b, axis=-1, keepdims=True) < 0.0, -1.0, 1.0)
    hh = np.asarray(h, dtype=np.float64)[..., None]
    return multiply(a, exp(hh * log(multiply(conjugate(a), b))))


def quaternion_from_scipy(rotation: Rotation) -> FloatArray:
    """Unit quaternions (…, 4), order (w, x, y, z), of a scipy ``Rotation``."""
    return np.asarray(rotation.as_quat(scalar_first=True), dtype=np.float64)


def scipy_from_quaternion(q: ArrayLike) -> Rotation:
    """scipy ``Rotation`` of quaternions (…, 4) given in order (w, x, y, z)."""
    return Rotation.from_quat(_as_quat(q), scalar_first=True)


def random_quaternion(rng: np.random.Generator, n: int, max_angle_rad: float = np.pi) -> FloatArray:
    """``n`` random unit quaternions (n, 4), order (w, x, y, z), angle ≤ ``max_angle_rad``.

    Axis uniform on the sphere; angle uniform in [0, max_angle_rad] (not Haar-uniform).
    """
    axis = rng.normal(size=(n, 3))
    axis /= np.linalg.norm(axis, axis=-1, keepdims=True)
    angle = rng.uniform(0.0, max_angle_rad, size=(n, 1))
    return quaternion_from_rotvec(axis * angle)
