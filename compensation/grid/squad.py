"""Squad: spherical cubic interpolation through a sequence of unit quaternions.

Quaternions are arrays (…, 4) in order **(w, x, y, z)**. Keyframes ``q_0 … q_{n-1}`` sit at
equally spaced parameters; segment ``i`` joins ``q_i`` and ``q_{i+1}`` for ``h ∈ [0, 1]``:

    Squad(q_i, q_{i+1}, s_i, s_{i+1}, h)
        = Slerp(Slerp(q_i, q_{i+1}, h), Slerp(s_i, s_{i+1}, h), 2h(1 − h))

with the inner control points (Shoemake; Dam et al. 1998, eq. 6.14; the seed paper §6)

    s_i = q_i ⊗ exp(−(log(q_i⁻¹ q_{i+1}) + log(q_i⁻¹ q_{i−1})) / 4).

**Boundary rules** (``boundary=``):

* ``"reflect"``: ``s_0 = q_0`` and ``s_{n-1} = q_{n-1}``. This equals the formula above with
  reflected phantom keyframes ``q_{−1} = q_0 q_1⁻¹ q_0`` and ``q_n = q_{n-1} q_{n-2}⁻¹ q_{n-1}``,
  and is the rule numpy-quaternion's ``quaternion.squad`` uses (its ``A[0] = R_in[0]``,
  ``B[-2] = R_in[-1]``), so both give the same curve on uniform spacing. Its end segments are
  only second-order accurate.
* ``"quadratic"`` (the correction grid's rule): the phantom keyframe is extrapolated with a
  parabola in the tangent space at the end keyframe, ``v_{−1} = v_2 − 3 v_1`` with
  ``v_k = log(q_0⁻¹ q_k)``, which gives ``s_0 = q_0 exp((2 v_1 − v_2) / 4)`` (and the mirror
  image at the other end). Needs n ≥ 3; the end segments become as accurate as the interior
  (measured in ``docs/interpolation.md``: ~10× smaller boundary error on a 20-node axis).

The keyframes must be sign-continuous (``q_i · q_{i+1} ≥ 0``); :func:`squad_control_points`
checks this. Squad hits its keyframes, stays on the unit sphere and is C¹ at the keyframes
(for uniform spacing), see ``tests/test_squad.py``.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike, NDArray

from . import quaternion as qt

__all__ = ["squad", "squad_control_points", "squad_evaluate", "squad_sequence"]

FloatArray = NDArray[np.float64]


def squad_control_points(q_keys: ArrayLike, axis: int = 0, boundary: str = "reflect") -> FloatArray:
    """Inner control points ``s_i`` (same shape) of keyframes ``q_keys`` along ``axis``.

    ``q_keys`` is (…, 4), order (w, x, y, z), sign-continuous along ``axis`` (which counts
    the non-quaternion axes). ``boundary``: ``"reflect"`` or ``"quadratic"`` (module doc).
    """
    if boundary not in ("reflect", "quadratic"):
        raise ValueError(f"boundary must be 'reflect' or 'quadratic', got {boundary!r}")
    q = np.asarray(q_keys, dtype=np.float64)
    if q.shape[-1] != 4 or q.ndim < 2:
        raise ValueError(f"keyframes need shape (n, ..., 4), got {q.shape}")
    q = np.moveaxis(q, axis % (q.ndim - 1), 0)
    n = q.shape[0]
    if n >= 2:
        dots = np.sum(q[1:] * q[:-1], axis=-1)
        if np.any(dots < 0.0):
            raise ValueError(
                "keyframes are not sign-continuous (q_i · q_(i+1) < 0); "
                "call quaternion.make_continuous first"
            )
    s = q.copy()
    if n >= 3:
        qi = q[1:-1]
        qi_inv = qt.conjugate(qi)
        lp = qt.log(qt.multiply(qi_inv, q[2:]))
        lm = qt.log(qt.multiply(qi_inv, q[:-2]))
        s[1:-1] = qt.multiply(qi, qt.exp(-0.25 * (lp + lm)))
        if boundary == "quadratic":
            for end, nxt, nxt2 in ((0, 1, 2), (n - 1, n - 2, n - 3)):
                inv = qt.conjugate(q[end])
                v1 = qt.log(qt.multiply(inv, q[nxt]))
                v2 = qt.log(qt.multiply(inv, q[nxt2]))
                s[end] = qt.multiply(q[end], qt.exp(0.25 * (2.0 * v1 - v2)))
    return np.moveaxis(s, 0, axis % (q.ndim - 1))


def squad_evaluate(
    q_i: ArrayLike, q_ip1: ArrayLike, s_i: ArrayLike, s_ip1: ArrayLike, h: ArrayLike
) -> FloatArray:
    """One Squad segment at parameter ``h ∈ [0, 1]``; all quaternions (…, 4), (w, x, y, z)."""
    hh = np.asarray(h, dtype=np.float64)
    outer = qt.slerp(q_i, q_ip1, hh)
    inner = qt.slerp(s_i, s_ip1, hh)
    return qt.slerp(outer, inner, 2.0 * hh * (1.0 - hh))


def squad(q_keys: ArrayLike, u: ArrayLike, boundary: str = "reflect") -> FloatArray:
    """Evaluate the Squad curve through keyframes (n, 4) at parameters ``u`` (m,) → (m, 4).

    Keyframe ``i`` sits at ``u = i`` (uniform spacing, ``0 ≤ u ≤ n − 1``); order (w, x, y, z).
    Parameters outside ``[0, n − 1]`` raise (no extrapolation).
    """
    q = np.asarray(q_keys, dtype=np.float64)
    uu = np.atleast_1d(np.asarray(u, dtype=np.float64))
    n = q.shape[0]
    if n < 2:
        raise ValueError(f"Squad needs at least 2 keyframes, got {n}")
    if np.any(~np.isfinite(uu)) or np.any(uu < 0.0) or np.any(uu > n - 1):
        raise ValueError(f"Squad parameters must lie in [0, {n - 1}], got {uu.min()}..{uu.max()}")
    s = squad_control_points(q, boundary=boundary if n >= 3 else "reflect")
    i = np.clip(np.floor(uu).astype(np.intp), 0, n - 2)
    h = uu - i
    return squad_evaluate(q[i], q[i + 1], s[i], s[i + 1], h)


def squad_sequence(
    q_keys: ArrayLike, samples_per_segment: int, boundary: str = "reflect"
) -> FloatArray:
    """Densely sample the Squad curve: ``samples_per_segment`` points per segment plus the end."""
    q = np.asarray(q_keys, dtype=np.float64)
    n = q.shape[0]
    u = np.linspace(0.0, n - 1, (n - 1) * samples_per_segment + 1)
    return squad(q, u, boundary)
