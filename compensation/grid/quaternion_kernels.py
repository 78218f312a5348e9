"""The compiled quaternion algebra of the correction grid's kernels (numba): product, exp, log,
Slerp and the Squad segment with its control points, on scalars (no arrays, no allocation).

Quaternions are (w, x, y, z). :func:`qexp`/:func:`qlog` follow the paper's convention
(``exp([0, θn]) = [cos θ, sin θ n]``) and switch to truncated series below θ = 10⁻² (or
|v|/w < 10⁻²) whose truncation error is < 10⁻²⁰ relative, i.e. they are exact in double
precision, not small-angle approximations; error rotations are µrad…mrad, so the fast branch
is the one normally taken. :func:`qexp_series`/:func:`qlog_series` are the series alone, for
callers that know every angle is below the limit (:data:`SERIES_LIMIT2`).
"""

from __future__ import annotations

import math

from ..jit import njit_cached

__all__ = [
    "FASTMATH",
    "SERIES_LIMIT2",
    "qexp",
    "qexp_series",
    "qlog",
    "qlog_series",
    "qmul",
    "slerp",
    "squad4",
]

SERIES_LIMIT2 = 1e-4  # θ² (or (|v|/w)²) below which the series branch is used
#: LLVM fast-math flags of every grid kernel. No "nnan"/"ninf": inputs are sanitised, but IEEE
#: specials stay safe.
FASTMATH = {"nsz", "arcp", "contract", "afn", "reassoc"}


@njit_cached(error_model="numpy", fastmath=FASTMATH)
def qmul(aw, ax, ay, az, bw, bx, by, bz):  # type: ignore[no-untyped-def]
    return (
        aw * bw - ax * bx - ay * by - az * bz,
        aw * bx + ax * bw + ay * bz - az * by,
        aw * by - ax * bz + ay * bw + az * bx,
        aw * bz + ax * by - ay * bx + az * bw,
    )


@njit_cached(error_model="numpy", fastmath=FASTMATH)
def qexp(vx, vy, vz):  # type: ignore[no-untyped-def]
    t2 = vx * vx + vy * vy + vz * vz
    if t2 < SERIES_LIMIT2:
        c = 1.0 - t2 / 2.0 * (1.0 - t2 / 12.0 * (1.0 - t2 / 30.0 * (1.0 - t2 / 56.0)))
        sc = 1.0 - t2 / 6.0 * (1.0 - t2 / 20.0 * (1.0 - t2 / 42.0 * (1.0 - t2 / 72.0)))
    else:
        t = math.sqrt(t2)
        c = math.cos(t)
        sc = math.sin(t) / t
    return (c, sc * vx, sc * vy, sc * vz)


@njit_cached(error_model="numpy", fastmath=FASTMATH)
def qlog(w, x, y, z):  # type: ignore[no-untyped-def]
    s2 = x * x + y * y + z * z
    if w > 0.0 and s2 < SERIES_LIMIT2 * w * w:
        u = s2 / (w * w)  # tan²θ; atan(√u)/√u as a series
        f = (
            1.0 + u * (-1.0 / 3.0 + u * (1.0 / 5.0 + u * (-1.0 / 7.0 + u * (1.0 / 9.0 - u / 11.0))))
        ) / w
    else:
        s = math.sqrt(s2)
        f = math.atan2(s, w) / s if s > 0.0 else 0.0
    return (f * x, f * y, f * z)


@njit_cached(error_model="numpy", fastmath=FASTMATH)
def qexp_series(vx, vy, vz):  # type: ignore[no-untyped-def]
    """``qexp`` without the branch: valid (exact) only for θ² < SERIES_LIMIT2."""
    t2 = vx * vx + vy * vy + vz * vz
    c = 1.0 - t2 / 2.0 * (1.0 - t2 / 12.0 * (1.0 - t2 / 30.0 * (1.0 - t2 / 56.0)))
    sc = 1.0 - t2 / 6.0 * (1.0 - t2 / 20.0 * (1.0 - t2 / 42.0 * (1.0 - t2 / 72.0)))
    return (c, sc * vx, sc * vy, sc * vz)


@njit_cached(error_model="numpy", fastmath=FASTMATH)
def qlog_series(w, x, y, z):  # type: ignore[no-untyped-def]
    """``qlog`` without the branch: valid (exact) only for w > 0, (|v|/w)² < SERIES_LIMIT2."""
    iw = 1.0 / w
    u = (x * x + y * y + z * z) * iw * iw
    f = (
        1.0 + u * (-1.0 / 3.0 + u * (1.0 / 5.0 + u * (-1.0 / 7.0 + u * (1.0 / 9.0 - u / 11.0))))
    ) * iw
    return (f * x, f * y, f * z)


@njit_cached(error_model="numpy", fastmath=FASTMATH)
def slerp(aw, ax, ay, az, bw, bx, by, bz, h):  # type: ignore[no-untyped-def]
    rw, rx, ry, rz = qmul(aw, -ax, -ay, -az, bw, bx, by, bz)
    lx, ly, lz = qlog(rw, rx, ry, rz)
    ew, ex, ey, ez = qexp(h * lx, h * ly, h * lz)
    return qmul(aw, ax, ay, az, ew, ex, ey, ez)


@njit_cached(error_model="numpy", fastmath=FASTMATH)
def squad4(buf, lo_ok, hi_ok, h):  # type: ignore[no-untyped-def]
    """Squad between buf[1] and buf[2] (rows of a (4, 4) array); neighbours buf[0], buf[3].

    Shares the logarithms: with L12 = log(Q1⁻¹Q2), log(Q2⁻¹Q1) = −L12 (unit quaternions),
    s1 = Q1·exp(−(L12 + log(Q1⁻¹Q0))/4), s2 = Q2·exp(−(log(Q2⁻¹Q3) − L12)/4) and
    Slerp(Q1, Q2, h) = Q1·exp(h·L12). Without an outer neighbour the quadratic boundary rule
    of :mod:`.squad` is used (needs ≥ 4 nodes per axis, which the grid enforces).
    """
    q1w, q1x, q1y, q1z = buf[1, 0], buf[1, 1], buf[1, 2], buf[1, 3]
    q2w, q2x, q2y, q2z = buf[2, 0], buf[2, 1], buf[2, 2], buf[2, 3]
    r = qmul(q1w, -q1x, -q1y, -q1z, q2w, q2x, q2y, q2z)
    lx, ly, lz = qlog(r[0], r[1], r[2], r[3])
    if lo_ok:
        r0 = qmul(q1w, -q1x, -q1y, -q1z, buf[0, 0], buf[0, 1], buf[0, 2], buf[0, 3])
        m = qlog(r0[0], r0[1], r0[2], r0[3])
        e = qexp(-0.25 * (lx + m[0]), -0.25 * (ly + m[1]), -0.25 * (lz + m[2]))
        s1 = qmul(q1w, q1x, q1y, q1z, e[0], e[1], e[2], e[3])
    else:  # quadratic boundary rule: s1 = Q1·exp((2·log(Q1⁻¹Q2) − log(Q1⁻¹Q3))/4)
        r3 = qmul(q1w, -q1x, -q1y, -q1z, buf[3, 0], buf[3, 1], buf[3, 2], buf[3, 3])
        v2 = qlog(r3[0], r3[1], r3[2], r3[3])
        e = qexp(0.25 * (2.0 * lx - v2[0]), 0.25 * (2.0 * ly - v2[1]), 0.25 * (2.0 * lz - v2[2]))
        s1 = qmul(q1w, q1x, q1y, q1z, e[0], e[1], e[2], e[3])
    if hi_ok:
        r3 = qmul(q2w, -q2x, -q2y, -q2z, buf[3, 0], buf[3, 1], buf[3, 2], buf[3, 3])
        p = qlog(r3[0], r3[1], r3[2], r3[3])
        e = qexp(-0.25 * (p[0] - lx), -0.25 * (p[1] - ly), -0.25 * (p[2] - lz))
        s2 = qmul(q2w, q2x, q2y, q2z, e[0], e[1], e[2], e[3])
    else:  # quadratic boundary rule: s2 = Q2·exp((2·log(Q2⁻¹Q1) − log(Q2⁻¹Q0))/4)
        r0 = qmul(q2w, -q2x, -q2y, -q2z, buf[0, 0], buf[0, 1], buf[0, 2], buf[0, 3])
        v2 = qlog(r0[0], r0[1], r0[2], r0[3])
        e = qexp(0.25 * (-2.0 * lx - v2[0]), 0.25 * (-2.0 * ly - v2[1]), 0.25 * (-2.0 * lz - v2[2]))
        s2 = qmul(q2w, q2x, q2y, q2z, e[0], e[1], e[2], e[3])
    e = qexp(h * lx, h * ly, h * lz)
    a = qmul(q1w, q1x, q1y, q1z, e[0], e[1], e[2], e[3])
    b = slerp(s1[0], s1[1], s1[2], s1[3], s2[0], s2[1], s2[2], s2[3], h)
    return slerp(a[0], a[1], a[2], a[3], b[0], b[1], b[2], b[3], 2.0 * h * (1.0 - h))
