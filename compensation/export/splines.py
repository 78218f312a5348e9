"""Equidistant interpolation points and the piecewise-linear functions a controller builds on them.

Every controller format here stores a compensation table as values at equidistant positions of
one input axis and interpolates linearly between them, holding the end value beyond the ends
(SINUMERIK K3, LinuxCNC's motion module; TwinCAT's behaviour beyond the ends is not documented
and never used: tables cover the whole travel). :class:`Knots` is such a set of positions,
:func:`hat_matrix` the interpolation weights, :func:`project` the least-squares (L2) fit of a
sampled function by such a table over the axis travel. Positions mm; values in any unit.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray
from scipy import sparse
from scipy.sparse.linalg import spsolve

FloatArray = NDArray[np.float64]

__all__ = [
    "Knots",
    "axis_nodes",
    "coarser",
    "evaluate",
    "hat_matrix",
    "make_knots",
    "mass_matrix",
    "project",
]

#: Gauss-Legendre nodes on [0, 1] and their weights (n = 2 and 3).
_GAUSS = {
    n: ((np.polynomial.legendre.leggauss(n)[0] + 1) / 2, np.polynomial.legendre.leggauss(n)[1] / 2)
    for n in (2, 3)
}


@dataclass(frozen=True)
class Knots:
    """``count`` equidistant positions ``start_mm + i·step_mm`` along machine axis ``axis`` (0…2)."""

    axis: int
    start_mm: float
    step_mm: float
    count: int

    @property
    def end_mm(self) -> float:
        return self.start_mm + (self.count - 1) * self.step_mm

    def positions(self) -> FloatArray:
        return self.start_mm + self.step_mm * np.arange(self.count, dtype=float)


def make_knots(axis: int, lo_mm: float, hi_mm: float, count: int, quantum_mm: float) -> Knots:
    """``count`` points from ``lo_mm`` with a step that is a multiple of ``quantum_mm`` (the
    format's position resolution) and reaches at least ``hi_mm``."""
    if count < 2:
        raise ValueError(f"a table needs at least 2 points, got {count}")
    raw = (hi_mm - lo_mm) / (count - 1)
    step = max(1, math.ceil(raw / quantum_mm - 1e-9)) * quantum_mm  # ≥ 1 quantum: never 0
    step = round(step / quantum_mm) * quantum_mm
    return Knots(axis=axis, start_mm=float(lo_mm), step_mm=float(step), count=int(count))


def _cells(knots: Knots, q_mm: FloatArray) -> tuple[NDArray[np.intp], FloatArray]:
    q = np.clip(np.asarray(q_mm, dtype=float), knots.start_mm, knots.end_mm)
    s = (q - knots.start_mm) / knots.step_mm
    i = np.clip(np.floor(s).astype(np.intp), 0, knots.count - 2)
    return i, s - i


def hat_matrix(knots: Knots, q_mm: FloatArray) -> sparse.csr_matrix:
    """(N, count) sparse weights of linear interpolation between the points, the end values held
    beyond the ends: ``table(q) = hat_matrix(knots, q) @ values``."""
    i, t = _cells(knots, q_mm)
    n = len(i)
    rows = np.concatenate([np.arange(n), np.arange(n)])
    cols = np.concatenate([i, i + 1])
    return sparse.csr_matrix((np.concatenate([1.0 - t, t]), (rows, cols)), shape=(n, knots.count))


def evaluate(knots: Knots, values: FloatArray, q_mm: FloatArray) -> FloatArray:
    """The table's value at axis positions ``q_mm`` (linear interpolation, end values held)."""
    i, t = _cells(knots, q_mm)
    v = np.asarray(values, dtype=float)
    return (1.0 - t) * v[i] + t * v[i + 1]


def coarser(knots: Knots, max_count: int) -> Knots:
    """``knots`` itself, or every r-th point (the last one reaching at least the same end) so
    that at most ``max_count`` remain."""
    if knots.count <= max_count:
        return knots
    r = math.ceil((knots.count - 1) / (max_count - 1))
    count = math.ceil((knots.count - 1) / r) + 1
    return Knots(knots.axis, knots.start_mm, knots.step_mm * r, count)


def axis_nodes(
    knots: Knots, lo_mm: float, hi_mm: float, per_interval: int
) -> tuple[FloatArray, FloatArray]:
    """Quadrature over [lo, hi] for functions that are smooth between the points: Gauss-Legendre
    nodes (``per_interval`` = 2 or 3) in every piece between consecutive points (and the volume
    ends); weights sum to 1 (the mean over the travel)."""
    cuts = knots.positions()
    cuts = cuts[(cuts > lo_mm) & (cuts < hi_mm)]
    edges = np.concatenate([[lo_mm], cuts, [hi_mm]])
    x01, w01 = _GAUSS[per_interval]
    lengths = np.diff(edges)
    nodes = (edges[:-1, None] + lengths[:, None] * x01[None, :]).ravel()
    weights = (lengths[:, None] * w01[None, :]).ravel() / (hi_mm - lo_mm)
    return nodes, weights


def mass_matrix(
    knots: Knots, nodes: FloatArray, weights: FloatArray
) -> tuple[sparse.csr_matrix, sparse.csc_matrix]:
    """The hat matrix at ``nodes`` and the (tridiagonal) mass matrix ``Bᵀ W B`` (exact for the
    Gauss nodes of :func:`axis_nodes`: products of hats are quadratic between points)."""
    b = hat_matrix(knots, nodes)
    return b, (b.T @ sparse.diags(weights) @ b).tocsc()


def project(
    knots: Knots, nodes: FloatArray, weights: FloatArray, values: FloatArray
) -> tuple[FloatArray, float]:
    """Least-squares table (values at the points) of a function sampled at ``nodes`` and the
    mean square of the fitted table over the travel."""
    b, m = mass_matrix(knots, nodes, weights)
    rhs = b.T @ (weights * np.asarray(values, dtype=float))
    coef = np.asarray(spsolve(m, rhs), dtype=float)
    energy = float(coef @ (m @ coef))
    return coef, energy
