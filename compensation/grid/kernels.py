"""Compiled evaluation kernels of :class:`compensation.grid.CorrectionGrid` (numba).

Why numba: the rotation part is a tensor-product Squad (16 Squad segments along x, 4 along y,
1 along z, each a few quaternion log/exp) and the translation part a tricubic B-spline (64
coefficients per component). In numpy this means dozens of temporary (N, 4) arrays per point
batch and ~1 ms of interpreter overhead for a single point; compiled, one point costs ~2 µs and
the batch runs in parallel. An on-disk cache keeps the JIT cost out of later processes where one
is writable (:func:`..jit.njit_cached`; a read-only install without a home compiles in every
process); the grid warms the kernels up when it is constructed, so the first correction is not
the slow one.

Quaternions are (w, x, y, z). ``_qexp``/``_qlog`` follow the paper's convention
(``exp([0, θn]) = [cos θ, sin θ n]``) and switch to truncated series below θ = 10⁻² (or
|v|/w < 10⁻²) whose truncation error is < 10⁻²⁰ relative, i.e. they are exact in double
precision, not small-angle approximations; error rotations are µrad…mrad, so the fast branch
is the one normally taken.
"""

from __future__ import annotations

import math

import numpy as np
from numba import prange

from ..jit import kernel_cache_dir, njit_cached

SERIES_LIMIT2 = 1e-4  # θ² (or (|v|/w)²) below which the series branch is used
_FAST = {
    "nsz",
    "arcp",
    "contract",
    "afn",
    "reassoc",
}  # no "nnan"/"ninf": inputs are sanitised, but keep IEEE specials safe


@njit_cached(error_model="numpy", fastmath=_FAST)
def _qmul(aw, ax, ay, az, bw, bx, by, bz):  # type: ignore[no-untyped-def]
    return (
        aw * bw - ax * bx - ay * by - az * bz,
        aw * bx + ax * bw + ay * bz - az * by,
        aw * by - ax * bz + ay * bw + az * bx,
        aw * bz + ax * by - ay * bx + az * bw,
    )


@njit_cached(error_model="numpy", fastmath=_FAST)
def _qexp(vx, vy, vz):  # type: ignore[no-untyped-def]
    t2 = vx * vx + vy * vy + vz * vz
    if t2 < SERIES_LIMIT2:
        c = 1.0 - t2 / 2.0 * (1.0 - t2 / 12.0 * (1.0 - t2 / 30.0 * (1.0 - t2 / 56.0)))
        sc = 1.0 - t2 / 6.0 * (1.0 - t2 / 20.0 * (1.0 - t2 / 42.0 * (1.0 - t2 / 72.0)))
    else:
        t = math.sqrt(t2)
        c = math.cos(t)
        sc = math.sin(t) / t
    return (c, sc * vx, sc * vy, sc * vz)


@njit_cached(error_model="numpy", fastmath=_FAST)
def _qlog(w, x, y, z):  # type: ignore[no-untyped-def]
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


@njit_cached(error_model="numpy", fastmath=_FAST)
def _qexp_series(vx, vy, vz):  # type: ignore[no-untyped-def]
    """``_qexp`` without the branch: valid (exact) only for θ² < SERIES_LIMIT2."""
    t2 = vx * vx + vy * vy + vz * vz
    c = 1.0 - t2 / 2.0 * (1.0 - t2 / 12.0 * (1.0 - t2 / 30.0 * (1.0 - t2 / 56.0)))
    sc = 1.0 - t2 / 6.0 * (1.0 - t2 / 20.0 * (1.0 - t2 / 42.0 * (1.0 - t2 / 72.0)))
    return (c, sc * vx, sc * vy, sc * vz)


@njit_cached(error_model="numpy", fastmath=_FAST)
def _qlog_series(w, x, y, z):  # type: ignore[no-untyped-def]
    """``_qlog`` without the branch: valid (exact) only for w > 0, (|v|/w)² < SERIES_LIMIT2."""
    iw = 1.0 / w
    u = (x * x + y * y + z * z) * iw * iw
    f = (
        1.0 + u * (-1.0 / 3.0 + u * (1.0 / 5.0 + u * (-1.0 / 7.0 + u * (1.0 / 9.0 - u / 11.0))))
    ) * iw
    return (f * x, f * y, f * z)


@njit_cached(error_model="numpy", fastmath=_FAST)
def _slerp(aw, ax, ay, az, bw, bx, by, bz, h):  # type: ignore[no-untyped-def]
    rw, rx, ry, rz = _qmul(aw, -ax, -ay, -az, bw, bx, by, bz)
    lx, ly, lz = _qlog(rw, rx, ry, rz)
    ew, ex, ey, ez = _qexp(h * lx, h * ly, h * lz)
    return _qmul(aw, ax, ay, az, ew, ex, ey, ez)


@njit_cached(error_model="numpy", fastmath=_FAST)
def _ctrl(mw, mx, my, mz, cw, cx, cy, cz, pw, px, py, pz):  # type: ignore[no-untyped-def]
    """Shoemake/Dam inner control point s = c·exp(−(log(c⁻¹p) + log(c⁻¹m))/4)."""
    a = _qmul(cw, -cx, -cy, -cz, pw, px, py, pz)
    b = _qmul(cw, -cx, -cy, -cz, mw, mx, my, mz)
    l1 = _qlog(a[0], a[1], a[2], a[3])
    l2 = _qlog(b[0], b[1], b[2], b[3])
    e = _qexp(-0.25 * (l1[0] + l2[0]), -0.25 * (l1[1] + l2[1]), -0.25 * (l1[2] + l2[2]))
    return _qmul(cw, cx, cy, cz, e[0], e[1], e[2], e[3])


@njit_cached(error_model="numpy", fastmath=_FAST)
def _squad4(buf, lo_ok, hi_ok, h):  # type: ignore[no-untyped-def]
    """Squad between buf[1] and buf[2] (rows of a (4, 4) array); neighbours buf[0], buf[3].

    Shares the logarithms: with L12 = log(Q1⁻¹Q2), log(Q2⁻¹Q1) = −L12 (unit quaternions),
    s1 = Q1·exp(−(L12 + log(Q1⁻¹Q0))/4), s2 = Q2·exp(−(log(Q2⁻¹Q3) − L12)/4) and
    Slerp(Q1, Q2, h) = Q1·exp(h·L12). Without an outer neighbour the quadratic boundary rule
    of :mod:`.squad` is used (needs ≥ 4 nodes per axis, which the grid enforces).
    """
    q1w, q1x, q1y, q1z = buf[1, 0], buf[1, 1], buf[1, 2], buf[1, 3]
    q2w, q2x, q2y, q2z = buf[2, 0], buf[2, 1], buf[2, 2], buf[2, 3]
    r = _qmul(q1w, -q1x, -q1y, -q1z, q2w, q2x, q2y, q2z)
    lx, ly, lz = _qlog(r[0], r[1], r[2], r[3])
    if lo_ok:
        r0 = _qmul(q1w, -q1x, -q1y, -q1z, buf[0, 0], buf[0, 1], buf[0, 2], buf[0, 3])
        m = _qlog(r0[0], r0[1], r0[2], r0[3])
        e = _qexp(-0.25 * (lx + m[0]), -0.25 * (ly + m[1]), -0.25 * (lz + m[2]))
        s1 = _qmul(q1w, q1x, q1y, q1z, e[0], e[1], e[2], e[3])
    else:  # quadratic boundary rule: s1 = Q1·exp((2·log(Q1⁻¹Q2) − log(Q1⁻¹Q3))/4)
        r3 = _qmul(q1w, -q1x, -q1y, -q1z, buf[3, 0], buf[3, 1], buf[3, 2], buf[3, 3])
        v2 = _qlog(r3[0], r3[1], r3[2], r3[3])
        e = _qexp(0.25 * (2.0 * lx - v2[0]), 0.25 * (2.0 * ly - v2[1]), 0.25 * (2.0 * lz - v2[2]))
        s1 = _qmul(q1w, q1x, q1y, q1z, e[0], e[1], e[2], e[3])
    if hi_ok:
        r3 = _qmul(q2w, -q2x, -q2y, -q2z, buf[3, 0], buf[3, 1], buf[3, 2], buf[3, 3])
        p = _qlog(r3[0], r3[1], r3[2], r3[3])
        e = _qexp(-0.25 * (p[0] - lx), -0.25 * (p[1] - ly), -0.25 * (p[2] - lz))
        s2 = _qmul(q2w, q2x, q2y, q2z, e[0], e[1], e[2], e[3])
    else:  # quadratic boundary rule: s2 = Q2·exp((2·log(Q2⁻¹Q1) − log(Q2⁻¹Q0))/4)
        r0 = _qmul(q2w, -q2x, -q2y, -q2z, buf[0, 0], buf[0, 1], buf[0, 2], buf[0, 3])
        v2 = _qlog(r0[0], r0[1], r0[2], r0[3])
        e = _qexp(
            0.25 * (-2.0 * lx - v2[0]), 0.25 * (-2.0 * ly - v2[1]), 0.25 * (-2.0 * lz - v2[2])
        )
        s2 = _qmul(q2w, q2x, q2y, q2z, e[0], e[1], e[2], e[3])
    e = _qexp(h * lx, h * ly, h * lz)
    a = _qmul(q1w, q1x, q1y, q1z, e[0], e[1], e[2], e[3])
    b = _slerp(s1[0], s1[1], s1[2], s1[3], s2[0], s2[1], s2[2], s2[3], h)
    return _slerp(a[0], a[1], a[2], a[3], b[0], b[1], b[2], b[3], 2.0 * h * (1.0 - h))


@njit_cached(error_model="numpy", fastmath=_FAST)
def _locate(v, lo, inv_d, n):  # type: ignore[no-untyped-def]
    u = (v - lo) * inv_d
    i = int(math.floor(u))  # noqa: RUF046 (explicit int for numba typing)
    if i < 0:
        i = 0
    elif i > n - 2:
        i = n - 2
    return i, u - i


@njit_cached(error_model="numpy", fastmath=_FAST)
def _basis3(t, span, x, out, left, right):  # type: ignore[no-untyped-def]
    """The 4 non-zero cubic B-spline basis values at x in knot span ``span`` (NURBS book A2.2)."""
    out[0] = 1.0
    for j in range(1, 4):
        left[j] = x - t[span + 1 - j]
        right[j] = t[span + j] - x
        saved = 0.0
        for r in range(j):
            tmp = out[r] / (right[r + 1] + left[j - r])
            out[r] = saved + right[r + 1] * tmp
            saved = left[j - r] * tmp
        out[j] = saved


@njit_cached(error_model="numpy", fastmath=_FAST)
def _eval_range(  # type: ignore[no-untyped-def]
    start, stop, points, stylus, dev, lo, inv_d, shape,
    q, sx, wq, ws, node, small, tx, ty, tz, spanx, spany, spanz, coef, ncomp,
    out, out_q, out_t, want_pose,
):  # fmt: skip
    nx, ny, nz = shape[0], shape[1], shape[2]
    nsig = dev.shape[1]
    buf = np.empty((4, 4, 4))
    lanes = np.empty((14, 16))
    res = np.empty((4, 16))
    row = np.empty((4, 4))
    zrow = np.empty((4, 4))
    bx = np.empty(4)
    by = np.empty(4)
    bz = np.empty(4)
    acc = np.empty(ncomp)
    left = np.empty(4)
    right = np.empty(4)
    for n in range(start, stop):
        px, py, pz = points[n, 0], points[n, 1], points[n, 2]
        i, hx = _locate(px, lo[0], inv_d[0], nx)
        j, hy = _locate(py, lo[1], inv_d[1], ny)
        k, hz = _locate(pz, lo[2], inv_d[2], nz)
        # ---- rotation: Squad along x on the (≤4)×(≤4) neighbouring lines, then y, then z
        g = 2.0 * hx * (1.0 - hx)
        if small:
            # all node-to-node and node-to-control-point angles are < 0.01 rad (checked at
            # build): branch-free series over 16 lanes in structure-of-arrays form (SIMD)
            for a in range(4):
                jj = min(max(j - 1 + a, 0), ny - 1)
                for b in range(4):
                    kk = min(max(k - 1 + b, 0), nz - 1)
                    lane = 4 * a + b
                    for c in range(14):
                        lanes[c, lane] = node[i, jj, kk, c]
            for lane in range(16):
                e1 = _qexp_series(hx * lanes[8, lane], hx * lanes[9, lane], hx * lanes[10, lane])
                r1 = _qmul(
                    lanes[0, lane], lanes[1, lane], lanes[2, lane], lanes[3, lane],
                    e1[0], e1[1], e1[2], e1[3],
                )  # fmt: skip
                e2 = _qexp_series(hx * lanes[11, lane], hx * lanes[12, lane], hx * lanes[13, lane])
                r2 = _qmul(
                    lanes[4, lane], lanes[5, lane], lanes[6, lane], lanes[7, lane],
                    e2[0], e2[1], e2[2], e2[3],
                )  # fmt: skip
                rel = _qmul(r1[0], -r1[1], -r1[2], -r1[3], r2[0], r2[1], r2[2], r2[3])
                lg = _qlog_series(rel[0], rel[1], rel[2], rel[3])
                e3 = _qexp_series(g * lg[0], g * lg[1], g * lg[2])
                r = _qmul(r1[0], r1[1], r1[2], r1[3], e3[0], e3[1], e3[2], e3[3])
                for c in range(4):
                    res[c, lane] = r[c]
            for a in range(4):
                for b in range(4):
                    for c in range(4):
                        buf[a, b, c] = res[c, 4 * a + b]
        else:
            for a in range(4):
                jj = j - 1 + a
                if jj < 0 or jj >= ny:
                    continue
                for b in range(4):
                    kk = k - 1 + b
                    if kk < 0 or kk >= nz:
                        continue
                    e1 = _qexp(hx * wq[i, jj, kk, 0], hx * wq[i, jj, kk, 1], hx * wq[i, jj, kk, 2])
                    r1 = _qmul(
                        q[i, jj, kk, 0], q[i, jj, kk, 1], q[i, jj, kk, 2], q[i, jj, kk, 3],
                        e1[0], e1[1], e1[2], e1[3],
                    )  # fmt: skip
                    e2 = _qexp(hx * ws[i, jj, kk, 0], hx * ws[i, jj, kk, 1], hx * ws[i, jj, kk, 2])
                    r2 = _qmul(
                        sx[i, jj, kk, 0], sx[i, jj, kk, 1], sx[i, jj, kk, 2], sx[i, jj, kk, 3],
                        e2[0], e2[1], e2[2], e2[3],
                    )  # fmt: skip
                    r = _slerp(r1[0], r1[1], r1[2], r1[3], r2[0], r2[1], r2[2], r2[3], g)
                    for c in range(4):
                        buf[a, b, c] = r[c]
        for b in range(4):
            kk = k - 1 + b
            if kk < 0 or kk >= nz:
                continue
            for a in range(4):
                for c in range(4):
                    row[a, c] = buf[a, b, c]
            r = _squad4(row, j >= 1, j + 2 < ny, hy)
            for c in range(4):
                zrow[b, c] = r[c]
        qw, qx, qy, qz = _squad4(zrow, k >= 1, k + 2 < nz, hz)
        inv_norm = 1.0 / math.sqrt(qw * qw + qx * qx + qy * qy + qz * qz)
        qw *= inv_norm
        qx *= inv_norm
        qy *= inv_norm
        qz *= inv_norm
        # ---- translation and signal sensitivities: tricubic B-spline
        sxn, syn, szn = spanx[i], spany[j], spanz[k]
        _basis3(tx, sxn, px, bx, left, right)
        _basis3(ty, syn, py, by, left, right)
        _basis3(tz, szn, pz, bz, left, right)
        for c in range(ncomp):
            acc[c] = 0.0
        for a in range(4):
            ia = sxn - 3 + a
            for b in range(4):
                jb = syn - 3 + b
                wab = bx[a] * by[b]
                for cc in range(4):
                    kc = szn - 3 + cc
                    wgt = wab * bz[cc]
                    for c in range(ncomp):
                        acc[c] += wgt * coef[ia, jb, kc, c]
        t0, t1, t2 = acc[0], acc[1], acc[2]
        if nsig > 0 and ncomp > 3:
            ox = 0.0
            oy = 0.0
            oz = 0.0
            for s in range(nsig):
                d = dev[n, s]
                if d != 0.0:
                    base = 3 + 6 * s
                    t0 += d * acc[base]
                    t1 += d * acc[base + 1]
                    t2 += d * acc[base + 2]
                    ox += d * acc[base + 3]
                    oy += d * acc[base + 4]
                    oz += d * acc[base + 5]
            if ox != 0.0 or oy != 0.0 or oz != 0.0:
                e = _qexp(0.5e-6 * ox, 0.5e-6 * oy, 0.5e-6 * oz)  # µrad rotation vector → q
                qw, qx, qy, qz = _qmul(e[0], e[1], e[2], e[3], qw, qx, qy, qz)
        # ---- corrected = indicated + t/1000 + (R − I)·p, with (R − I)p = w·τ + u×τ, τ = 2u×p
        si = 0 if stylus.shape[0] == 1 else n
        sx_, sy_, sz_ = stylus[si, 0], stylus[si, 1], stylus[si, 2]
        tau0 = 2.0 * (qy * sz_ - qz * sy_)
        tau1 = 2.0 * (qz * sx_ - qx * sz_)
        tau2 = 2.0 * (qx * sy_ - qy * sx_)
        d0 = qw * tau0 + (qy * tau2 - qz * tau1)
        d1 = qw * tau1 + (qz * tau0 - qx * tau2)
        d2 = qw * tau2 + (qx * tau1 - qy * tau0)
        out[n, 0] = px + t0 * 1e-3 + d0
        out[n, 1] = py + t1 * 1e-3 + d1
        out[n, 2] = pz + t2 * 1e-3 + d2
        if want_pose:
            out_q[n, 0] = qw
            out_q[n, 1] = qx
            out_q[n, 2] = qy
            out_q[n, 3] = qz
            out_t[n, 0] = t0
            out_t[n, 1] = t1
            out_t[n, 2] = t2


@njit_cached(error_model="numpy", fastmath=_FAST, parallel=True)
def eval_parallel(  # type: ignore[no-untyped-def]
    points, stylus, dev, lo, inv_d, shape,
    q, sx, wq, ws, node, small, tx, ty, tz, spanx, spany, spanz, coef, ncomp,
    out, out_q, out_t, want_pose, chunk,
):  # fmt: skip
    """Evaluate all points (N, 3) in parallel chunks; see :func:`eval_serial` for arguments."""
    npts = points.shape[0]
    nchunks = (npts + chunk - 1) // chunk
    for c in prange(nchunks):
        start = c * chunk
        stop = min(start + chunk, npts)
        _eval_range(
            start, stop, points, stylus, dev, lo, inv_d, shape,
            q, sx, wq, ws, node, small, tx, ty, tz, spanx, spany, spanz, coef, ncomp,
            out, out_q, out_t, want_pose,
        )  # fmt: skip


@njit_cached(error_model="numpy", fastmath=_FAST)
def eval_serial(  # type: ignore[no-untyped-def]
    points, stylus, dev, lo, inv_d, shape,
    q, sx, wq, ws, node, small, tx, ty, tz, spanx, spany, spanz, coef, ncomp,
    out, out_q, out_t, want_pose,
):  # fmt: skip
    """Evaluate points (N, 3) mm serially (the single-point path).

    ``stylus`` (1 or N, 3) mm; ``dev`` (N, S) signal deviations from reference; ``lo``,
    ``inv_d`` (3,) first node and 1/spacing; ``shape`` (3,) node counts; ``q`` node
    quaternions (w, x, y, z), ``sx`` Squad control points along x, ``wq``/``ws`` the logs of
    successive ``q``/``sx`` along x; ``tx, ty, tz`` B-spline knots and ``span*`` the knot span
    of every cell; ``coef`` (nx, ny, nz, C) spline coefficients of which the first ``ncomp``
    are evaluated. Writes ``out`` (N, 3) corrected mm and, if ``want_pose``, ``out_q`` (N, 4)
    and ``out_t`` (N, 3) µm.
    """
    _eval_range(
        0, points.shape[0], points, stylus, dev, lo, inv_d, shape,
        q, sx, wq, ws, node, small, tx, ty, tz, spanx, spany, spanz, coef, ncomp,
        out, out_q, out_t, want_pose,
    )  # fmt: skip


def kernels_cache_dir() -> str | None:
    """Where these kernels' compiled code is cached, None when compiled anew in every process
    (no writable cache folder: :mod:`..jit`)."""
    return kernel_cache_dir(_qmul)
