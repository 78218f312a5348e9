"""Compiled evaluation kernels of :class:`compensation.grid.CorrectionGrid` (numba).

Why numba: the rotation part is a tensor-product Squad (16 Squad segments along x, 4 along y,
1 along z, each a few quaternion log/exp) and the translation part a tricubic B-spline (64
coefficients per component). In numpy this means dozens of temporary (N, 4) arrays per point
batch and ~1 ms of interpreter overhead for a single point; compiled, one point costs ~2 µs and
the batch runs in parallel. An on-disk cache keeps the JIT cost out of later processes where one
is writable (:func:`..jit.njit_cached`; a read-only install without a home compiles in every
process); the grid warms the serial kernel up when it is constructed, so the first reading is
not the slow one (the thread-pool kernel, for batches of ``PARALLEL_MIN`` points or more, on
its first batch: the daemon never calls it).

The kernels take their tables as two structured arguments, :class:`KernelTables` (with its
:class:`SplineTables`), built once per grid (:mod:`.interpolation`), and the outputs as one
tuple. They are passed as plain tuples (:meth:`KernelTables.args`): numba types a tuple of
arrays in its C dispatcher, a NamedTuple in Python (measured: ~4 µs more per call, more than
half the single-reading path). Quaternions are (w, x, y, z); the algebra is in
:mod:`.quaternion_kernels`.
"""

from __future__ import annotations

import math
from typing import Any, NamedTuple

import numpy as np
from numba import prange
from numpy.typing import NDArray

from ..jit import kernel_cache_dir, njit_cached
from .quaternion_kernels import (
    FASTMATH,
    qexp,
    qexp_series,
    qlog_series,
    qmul,
    slerp,
    squad4,
)

__all__ = [
    "KernelTables",
    "SplineTables",
    "basis3",
    "eval_parallel",
    "eval_serial",
    "kernels_cache_dir",
    "locate",
]

FloatArray = NDArray[np.float64]
IntArray = NDArray[np.int64]


class SplineTables(NamedTuple):
    """Where a point falls in the grid and its tricubic B-spline basis (the correction's and
    U's spline alike): first node ``lo`` (3,) mm, ``inv_d`` (3,) nodes per mm, ``shape`` (3,)
    node counts, per axis the knot vector ``t*`` and the knot span ``span*`` of every cell."""

    lo: FloatArray
    inv_d: FloatArray
    shape: IntArray
    tx: FloatArray
    ty: FloatArray
    tz: FloatArray
    spanx: IntArray
    spany: IntArray
    spanz: IntArray


class KernelTables(NamedTuple):
    """Everything the correction kernels read of a grid: the spline geometry, ``coef`` (nx, ny,
    nz, 3 + 6·S) the spline coefficients of the translation (µm) and of every signal's
    sensitivities (µm, µrad per unit), the node quaternions ``q`` and Squad control points
    ``sx`` along x (nx, ny, nz, 4), ``wq``/``ws`` the logs of successive ``q``/``sx`` along x
    (nx, ny, nz, 3), ``node`` the four side by side (nx, ny, nz, 14) for the series branch, and
    ``small``: every x-stage relative rotation is within the series branch."""

    spline: SplineTables
    coef: FloatArray
    q: FloatArray
    sx: FloatArray
    wq: FloatArray
    ws: FloatArray
    node: FloatArray
    small: bool

    def args(self) -> tuple[Any, ...]:
        """The tables as the kernels take them: plain (nested) tuples (module docstring)."""
        return (tuple(self.spline), *self[1:])


@njit_cached(error_model="numpy", fastmath=FASTMATH)
def locate(v, lo, inv_d, n):  # type: ignore[no-untyped-def]
    """Cell index (0 … n − 2) and fraction along one axis of coordinate ``v`` (mm)."""
    u = (v - lo) * inv_d
    i = int(math.floor(u))  # noqa: RUF046 (explicit int for numba typing)
    if i < 0:
        i = 0
    elif i > n - 2:
        i = n - 2
    return i, u - i


@njit_cached(error_model="numpy", fastmath=FASTMATH)
def basis3(t, span, x, out, left, right):  # type: ignore[no-untyped-def]
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


@njit_cached(error_model="numpy", fastmath=FASTMATH, inline="always")
def _x_stage_series(node, i, j, k, hx, lanes, res, buf):  # type: ignore[no-untyped-def]
    """Squad along x on the 4×4 node lines around cell (i, j, k) into ``buf`` (4, 4, 4), when
    all node-to-node and node-to-control-point angles are < 0.01 rad (``small``, checked at
    build): branch-free series over 16 lanes in structure-of-arrays form (SIMD); lines beyond
    the volume repeat the edge line (they are not read)."""
    ny, nz = node.shape[1], node.shape[2]
    g = 2.0 * hx * (1.0 - hx)
    for a in range(4):
        jj = min(max(j - 1 + a, 0), ny - 1)
        for b in range(4):
            kk = min(max(k - 1 + b, 0), nz - 1)
            lane = 4 * a + b
            for c in range(14):
                lanes[c, lane] = node[i, jj, kk, c]
    for lane in range(16):
        e1 = qexp_series(hx * lanes[8, lane], hx * lanes[9, lane], hx * lanes[10, lane])
        r1 = qmul(
            lanes[0, lane], lanes[1, lane], lanes[2, lane], lanes[3, lane],
            e1[0], e1[1], e1[2], e1[3],
        )  # fmt: skip
        e2 = qexp_series(hx * lanes[11, lane], hx * lanes[12, lane], hx * lanes[13, lane])
        r2 = qmul(
            lanes[4, lane], lanes[5, lane], lanes[6, lane], lanes[7, lane],
            e2[0], e2[1], e2[2], e2[3],
        )  # fmt: skip
        rel = qmul(r1[0], -r1[1], -r1[2], -r1[3], r2[0], r2[1], r2[2], r2[3])
        lg = qlog_series(rel[0], rel[1], rel[2], rel[3])
        e3 = qexp_series(g * lg[0], g * lg[1], g * lg[2])
        r = qmul(r1[0], r1[1], r1[2], r1[3], e3[0], e3[1], e3[2], e3[3])
        for c in range(4):
            res[c, lane] = r[c]
    for a in range(4):
        for b in range(4):
            for c in range(4):
                buf[a, b, c] = res[c, 4 * a + b]


@njit_cached(error_model="numpy", fastmath=FASTMATH, inline="always")
def _x_stage(q, sx, wq, ws, i, j, k, hx, buf):  # type: ignore[no-untyped-def]
    """:func:`_x_stage_series` for any angle (exact log/exp, Slerp); lines beyond the volume
    are left unset (not read)."""
    ny, nz = q.shape[1], q.shape[2]
    g = 2.0 * hx * (1.0 - hx)
    for a in range(4):
        jj = j - 1 + a
        if jj < 0 or jj >= ny:
            continue
        for b in range(4):
            kk = k - 1 + b
            if kk < 0 or kk >= nz:
                continue
            e1 = qexp(hx * wq[i, jj, kk, 0], hx * wq[i, jj, kk, 1], hx * wq[i, jj, kk, 2])
            r1 = qmul(
                q[i, jj, kk, 0], q[i, jj, kk, 1], q[i, jj, kk, 2], q[i, jj, kk, 3],
                e1[0], e1[1], e1[2], e1[3],
            )  # fmt: skip
            e2 = qexp(hx * ws[i, jj, kk, 0], hx * ws[i, jj, kk, 1], hx * ws[i, jj, kk, 2])
            r2 = qmul(
                sx[i, jj, kk, 0], sx[i, jj, kk, 1], sx[i, jj, kk, 2], sx[i, jj, kk, 3],
                e2[0], e2[1], e2[2], e2[3],
            )  # fmt: skip
            r = slerp(r1[0], r1[1], r1[2], r1[3], r2[0], r2[1], r2[2], r2[3], g)
            for c in range(4):
                buf[a, b, c] = r[c]


@njit_cached(error_model="numpy", fastmath=FASTMATH)
def _eval_range(start, stop, tables, points, stylus, dev, outputs, ncomp, want_pose):  # type: ignore[no-untyped-def]
    """Points ``start`` … ``stop`` − 1 (arguments as :func:`eval_serial`).

    Long on purpose: the per-point arithmetic stays in one loop body, so LLVM optimises it as
    a whole (the x-stages are helpers that numba inlines). With the y/z stages, the spline sum
    and the signal terms as compiled helpers too, a point measured 3–7 % slower (serial, 50k
    points, same-process A/B against the single loop body; issue 26)."""
    spline, coef, q, sx, wq, ws, node, small = tables
    lo, inv_d, shape, tx, ty, tz, spanx, spany, spanz = spline
    out, out_q, out_t = outputs
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
        i, hx = locate(px, lo[0], inv_d[0], nx)
        j, hy = locate(py, lo[1], inv_d[1], ny)
        k, hz = locate(pz, lo[2], inv_d[2], nz)
        # rotation: Squad along x on the (≤4)×(≤4) neighbouring lines, then y, then z
        if small:
            _x_stage_series(node, i, j, k, hx, lanes, res, buf)
        else:
            _x_stage(q, sx, wq, ws, i, j, k, hx, buf)
        for b in range(4):
            kk = k - 1 + b
            if kk < 0 or kk >= nz:
                continue
            for a in range(4):
                for c in range(4):
                    row[a, c] = buf[a, b, c]
            r = squad4(row, j >= 1, j + 2 < ny, hy)
            for c in range(4):
                zrow[b, c] = r[c]
        qw, qx, qy, qz = squad4(zrow, k >= 1, k + 2 < nz, hz)
        inv_norm = 1.0 / math.sqrt(qw * qw + qx * qx + qy * qy + qz * qz)
        qw *= inv_norm
        qx *= inv_norm
        qy *= inv_norm
        qz *= inv_norm
        # translation and signal sensitivities: tricubic B-spline
        sxn, syn, szn = spanx[i], spany[j], spanz[k]
        basis3(tx, sxn, px, bx, left, right)
        basis3(ty, syn, py, by, left, right)
        basis3(tz, szn, pz, bz, left, right)
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
                e = qexp(0.5e-6 * ox, 0.5e-6 * oy, 0.5e-6 * oz)  # µrad rotation vector → q
                qw, qx, qy, qz = qmul(e[0], e[1], e[2], e[3], qw, qx, qy, qz)
        # corrected = indicated + t/1000 + (R − I)·p, with (R − I)p = w·τ + u×τ, τ = 2u×p
        si = 0 if stylus.shape[0] == 1 else n
        sx_, sy_, sz_ = stylus[si, 0], stylus[si, 1], stylus[si, 2]
        tau0 = 2.0 * (qy * sz_ - qz * sy_)
        tau1 = 2.0 * (qz * sx_ - qx * sz_)
        tau2 = 2.0 * (qx * sy_ - qy * sx_)
        out[n, 0] = px + t0 * 1e-3 + (qw * tau0 + (qy * tau2 - qz * tau1))
        out[n, 1] = py + t1 * 1e-3 + (qw * tau1 + (qz * tau0 - qx * tau2))
        out[n, 2] = pz + t2 * 1e-3 + (qw * tau2 + (qx * tau1 - qy * tau0))
        if want_pose:
            out_q[n, 0], out_q[n, 1], out_q[n, 2], out_q[n, 3] = qw, qx, qy, qz
            out_t[n, 0], out_t[n, 1], out_t[n, 2] = t0, t1, t2


@njit_cached(error_model="numpy", fastmath=FASTMATH, parallel=True)
def eval_parallel(tables, points, stylus, dev, outputs, ncomp, want_pose, chunk):  # type: ignore[no-untyped-def]
    """:func:`eval_serial` in parallel chunks of ``chunk`` points."""
    # numba's parallel loop body takes arrays, not tuples of arrays: the tuples are taken apart
    # here and put together again inside the loop (no copy)
    spline, coef, q, sx, wq, ws, node, small = tables
    lo, inv_d, shape, tx, ty, tz, spanx, spany, spanz = spline
    out, out_q, out_t = outputs
    npts = points.shape[0]
    nchunks = (npts + chunk - 1) // chunk
    for c in prange(nchunks):
        start = c * chunk
        stop = min(start + chunk, npts)
        tab = (
            (lo, inv_d, shape, tx, ty, tz, spanx, spany, spanz),
            coef,
            q,
            sx,
            wq,
            ws,
            node,
            small,
        )
        _eval_range(start, stop, tab, points, stylus, dev, (out, out_q, out_t), ncomp, want_pose)


@njit_cached(error_model="numpy", fastmath=FASTMATH)
def eval_serial(tables, points, stylus, dev, outputs, ncomp, want_pose):  # type: ignore[no-untyped-def]
    """Corrected positions of points (N, 3) mm, serially (the single-reading path).

    ``tables``: :meth:`KernelTables.args`; ``stylus`` (1 or N, 3) mm; ``dev`` (N, S) signal
    deviations from the reference; ``outputs`` = (``out`` (N, 3) corrected mm, ``out_q`` (N, 4)
    error quaternions, ``out_t`` (N, 3) µm translations), the latter two written only if
    ``want_pose``; of ``coef`` the first ``ncomp`` components are evaluated (3: no signal
    deviates from its reference).
    """
    _eval_range(0, points.shape[0], tables, points, stylus, dev, outputs, ncomp, want_pose)


def kernels_cache_dir() -> str | None:
    """Where these kernels' compiled code is cached, None when compiled anew in every process
    (no writable cache folder: :mod:`..jit`)."""
    return kernel_cache_dir(qmul)
