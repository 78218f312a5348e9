"""The interpolation data of a correction grid: sign-continuous node quaternions, the Squad
control data along x, and the tensor-product not-a-knot cubic spline coefficients of the
translations (µm) and of the per-signal sensitivity grids (µm, µrad per signal unit).

Quaternions (w, x, y, z); node coordinates mm. The compiled kernels (:mod:`.kernels`) evaluate
these tables; :class:`.correction_grid.CorrectionGrid` computes them once when constructed.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np
from numpy.typing import ArrayLike, NDArray
from scipy.interpolate import make_interp_spline

from . import quaternion as qt
from .kernels import KernelTables, SplineTables
from .quaternion_kernels import SERIES_LIMIT2
from .squad import squad_control_points

__all__ = ["interpolation_tables", "make_grid_continuous"]

FloatArray = NDArray[np.float64]


def make_grid_continuous(q_grid: ArrayLike) -> FloatArray:
    """Sign-continuous node quaternions (nx, ny, nz, 4), order (w, x, y, z).

    Fixes node (0, 0, 0) to w ≥ 0, then propagates along x on the first line, along y on
    the first plane and along z everywhere, so that every neighbour pair along every axis
    has a non-negative dot product; raises ``ValueError`` if the rotation changes so fast
    between neighbours that this is impossible (dot < 0.5, i.e. > 120° apart).
    """
    q = np.array(q_grid, dtype=np.float64, copy=True)
    if q[0, 0, 0, 0] < 0:
        q[0, 0, 0] *= -1
    q[:, 0, 0] = qt.make_continuous(q[:, 0, 0], axis=0)
    q[:, :, 0] = qt.make_continuous(q[:, :, 0], axis=1)
    q = qt.make_continuous(q, axis=2)
    for axis in range(3):
        a = np.moveaxis(q, axis, 0)
        if a.shape[0] > 1 and np.min(np.sum(a[1:] * a[:-1], axis=-1)) < 0.5:
            raise ValueError(
                "node rotations differ by more than 120° between neighbours along axis "
                f"{'xyz'[axis]}: the grid is far too coarse for this rotation field"
            )
    return q


def knots_and_spans(nodes: FloatArray) -> tuple[FloatArray, NDArray[np.int64]]:
    """Not-a-knot cubic knot vector of ``nodes`` and the knot span of every cell."""
    spl = make_interp_spline(nodes, np.zeros_like(nodes), k=3)
    knots = np.ascontiguousarray(spl.t, dtype=np.float64)
    mids = 0.5 * (nodes[:-1] + nodes[1:])
    spans = np.searchsorted(knots, mids, side="right").astype(np.int64) - 1
    return knots, spans


def interpolation_tables(
    q: FloatArray,
    translation_um: FloatArray,
    sensitivity_translation_um: FloatArray,
    sensitivity_rotation_urad: FloatArray,
    axes: Sequence[FloatArray],
) -> KernelTables:
    """What the kernels read of a grid's node data (sign-continuous unit quaternions ``q``,
    the translations and sensitivity grids) on node ``axes`` (mm): the Squad control data along
    x and the tensor spline coefficients (:class:`.kernels.KernelTables`)."""
    steps = q.shape[:3]
    sx = squad_control_points(q, axis=0, boundary="quadratic")
    wq = np.zeros((*steps, 3))
    ws = np.zeros((*steps, 3))
    wq[:-1] = qt.log(qt.multiply(qt.conjugate(q[:-1]), q[1:]))
    ws[:-1] = qt.log(qt.multiply(qt.conjugate(sx[:-1]), sx[1:]))
    comps = [translation_um]
    for s in range(sensitivity_translation_um.shape[0]):
        comps += [sensitivity_translation_um[s], sensitivity_rotation_urad[s]]
    coef = np.concatenate(comps, axis=-1)
    for axis in range(3):
        spline = make_interp_spline(axes[axis], coef, k=3, axis=axis)
        coef = np.moveaxis(spline.c, 0, axis)  # BSpline puts the spline axis first
    knots, spans = zip(*(knots_and_spans(a) for a in axes), strict=True)
    # half-angle bound of every x-stage relative rotation (see kernels, "small")
    d_qs = np.linalg.norm(qt.log(qt.multiply(qt.conjugate(q), sx)), axis=-1).max()
    bound = np.linalg.norm(wq, axis=-1).max() + d_qs + np.linalg.norm(ws, axis=-1).max()
    lo = np.array([a[0] for a in axes])
    spline = SplineTables(
        lo,
        np.array([(steps[k] - 1) / (axes[k][-1] - lo[k]) for k in range(3)]),
        np.array(steps, dtype=np.int64),
        *knots,
        *spans,
    )
    return KernelTables(
        spline,
        np.ascontiguousarray(coef),
        np.ascontiguousarray(q),
        np.ascontiguousarray(sx),
        wq,
        ws,
        np.ascontiguousarray(np.concatenate([q, sx, wq, ws], axis=-1)),
        bool(bound * bound < SERIES_LIMIT2),
    )
