"""The volumetric model split into what one-axis compensation tables can carry.

A controller table corrects one output axis by a function of one input axis (and SINUMERIK adds
products of two tables). Over the working volume (uniform measure) the model error of output k,
``e_k(x, y, z, dirs)`` µm at a fixed tool and the reference temperatures, splits into orthogonal
parts (a functional ANOVA):

* the mean, and the *main effects* ``m_a(q_a)`` (zero-mean functions of one axis) — exactly the
  least-squares optimum of a sum of one-axis tables, fitted here as linear-interpolation tables
  on the format's points (:func:`.splines.project`);
* the two-axis *interactions* ``m_ab(q_a, q_b)`` (Abbe arm × angular error terms): their best
  products of two tables come from a singular value decomposition in the tables' own inner
  product (rank 1, 2, … terms, each orthogonal to the rest);
* the direction-dependent part: the model is linear in the signals ``dir_<axis>`` (±1), so
  ``e = e0 + Σ_a dir_a·r_a``; the main effect of ``r_a`` along axis a is what a table selected by
  the direction of axis a can carry;
* the rest (three-axis terms, interactions beyond the ranks kept) no table can carry.

Energies are mean squares over the volume (µm²) computed by quadrature; the residual a user is
told is measured afterwards by evaluating the written tables exactly as the controller does.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from scipy.linalg import cho_factor, cho_solve, solve_triangular

from ..machine import Machine
from ..parametric_errors import AXES
from .splines import FloatArray, Knots, axis_nodes, coarser, evaluate, mass_matrix, project

__all__ = ["Decomposition", "Interaction", "decompose", "direction_axes", "model_error_um"]

#: Nodes per averaged axis: composite 3-point Gauss on this many pieces of the travel.
_AVERAGE_PIECES = 4
_PAIR_AVERAGE_PIECES = 2
#: Two-axis terms are smooth (an angular error times an arm): they are fitted on at most this many
#: points per axis (every r-th point of the table), then read at every point of the table.
_PAIR_MAX_POINTS = 121


@dataclass
class Interaction:
    """One product term ``u(q_a)·v(q_b)`` µm (u µm, v unitless) of output ``k``; ``energy`` µm²."""

    a: int
    b: int
    k: int
    rank: int
    u: FloatArray  # values at the points of axis a
    v: FloatArray  # values at the points of axis b
    energy: float


@dataclass
class Decomposition:
    """The parts of the model error over the volume, fitted on ``knots`` (one set per axis)."""

    knots: tuple[Knots, Knots, Knots]
    lower_mm: FloatArray
    upper_mm: FloatArray
    direction_axes: list[int]
    mean_um: FloatArray  # (3,) per output
    main_values: list[list[FloatArray]]  # [k][a] values at axis a's points, µm, zero mean
    main_energy: FloatArray  # (3, 3) µm²
    dir_values: dict[int, list[FloatArray]]  # [a][k] values (µm) of the part ∝ dir_a
    dir_energy: dict[int, FloatArray]  # [a] (3,) µm²
    interactions: list[Interaction] = field(default_factory=list)
    pair_energy: dict[tuple[int, int, int], float] = field(default_factory=dict)  # (a, b, k) µm²


def direction_axes(machine: Machine) -> list[int]:
    """Axes whose direction of travel the model depends on (signal ``dir_<axis>``)."""
    signals = machine.runtime_signals()
    return [k for k, name in enumerate(AXES) if f"dir_{name}" in signals]


def model_error_um(
    machine: Machine,
    points_mm: FloatArray,
    tool_mm: FloatArray,
    dirs: Mapping[int, float] | None = None,
    temps_C: Mapping[str, float] | None = None,
) -> FloatArray:
    """The model's volumetric error (N, 3) µm at indicated points for the tool, with direction
    signals ``dirs`` (axis → ±1, 0 = unknown/mean); ValueError if the model is not finite."""
    inputs: dict[str, Any] = {f"dir_{AXES[a]}": float(d) for a, d in (dirs or {}).items()}
    err = machine.volumetric_error(points_mm, stylus_mm=tool_mm, temps_C=temps_C, inputs=inputs)
    if not np.all(np.isfinite(err)):
        bad = np.asarray(points_mm)[~np.all(np.isfinite(err), axis=1)][0]
        raise ValueError(
            f"the machine model gives a non-finite error at {bad.tolist()} mm: check its tables"
        )
    return err


def _average_nodes(lo: float, hi: float, pieces: int) -> tuple[FloatArray, FloatArray]:
    x01, w01 = np.polynomial.legendre.leggauss(3)
    x01, w01 = (x01 + 1) / 2, w01 / 2
    edges = np.linspace(lo, hi, pieces + 1)
    nodes = (edges[:-1, None] + np.diff(edges)[:, None] * x01[None, :]).ravel()
    weights = np.tile(w01, pieces) / pieces
    return nodes, weights


def _grid(axes_nodes: list[FloatArray]) -> FloatArray:
    mesh = np.meshgrid(*axes_nodes, indexing="ij")
    return np.stack([m.ravel() for m in mesh], axis=1)


def _marginal(
    machine: Machine,
    a: int,
    knots: Knots,
    lo: FloatArray,
    hi: FloatArray,
    tool: FloatArray,
    dirs: Mapping[int, float],
    temps: Mapping[str, float] | None,
) -> tuple[FloatArray, FloatArray, FloatArray]:
    """Nodes and weights along a and the mean of the error over the two other axes (N_a, 3)."""
    nodes_a, w_a = axis_nodes(knots, lo[a], hi[a], 3)
    per_axis: list[FloatArray] = []
    weights: list[FloatArray] = []
    for j in range(3):
        if j == a:
            per_axis.append(nodes_a)
            weights.append(np.ones(1))
        else:
            n, w = _average_nodes(lo[j], hi[j], _AVERAGE_PIECES)
            per_axis.append(n)
            weights.append(w)
    err = model_error_um(machine, _grid(per_axis), tool, dirs, temps)
    err = err.reshape(len(per_axis[0]), len(per_axis[1]), len(per_axis[2]), 3)
    other = [j for j in range(3) if j != a]
    w_other = np.multiply.outer(weights[other[0]], weights[other[1]])
    moved = np.moveaxis(err, a, 0)  # (N_a, n_o1, n_o2, 3) in the order of `other`
    return nodes_a, w_a, np.einsum("iopk,op->ik", moved, w_other)


def _pair(
    machine: Machine,
    a: int,
    b: int,
    knots: tuple[Knots, Knots, Knots],
    lo: FloatArray,
    hi: FloatArray,
    tool: FloatArray,
    temps: Mapping[str, float] | None,
    ranks: int,
) -> tuple[list[Interaction], FloatArray]:
    """Product terms (up to ``ranks`` per output) of the (a, b) interaction of every output, and
    the whole interaction's mean square per output (direction signals at 0)."""
    c = 3 - a - b
    ka, kb = coarser(knots[a], _PAIR_MAX_POINTS), coarser(knots[b], _PAIR_MAX_POINTS)
    na, wa = axis_nodes(ka, lo[a], hi[a], 2)
    nb, wb = axis_nodes(kb, lo[b], hi[b], 2)
    nc, wc = _average_nodes(lo[c], hi[c], _PAIR_AVERAGE_PIECES)
    nodes: list[FloatArray] = [np.empty(0)] * 3
    nodes[a], nodes[b], nodes[c] = na, nb, nc
    err = model_error_um(machine, _grid(nodes), tool, None, temps)
    err = err.reshape(len(nodes[0]), len(nodes[1]), len(nodes[2]), 3)
    f = np.einsum("abck,c->abk", np.transpose(err, (a, b, c, 3)), wc)  # (Na, Nb, 3)
    # double centring with the quadrature weights: the pure (a, b) interaction
    row = np.einsum("abk,b->ak", f, wb)
    col = np.einsum("abk,a->bk", f, wa)
    tot = np.einsum("ak,a->k", row, wa)
    f = f - row[:, None, :] - col[None, :, :] + tot[None, None, :]
    ba, ma_sparse = mass_matrix(ka, na, wa)
    bb, mb_sparse = mass_matrix(kb, nb, wb)
    ma, mb = ma_sparse.toarray(), mb_sparse.toarray()
    la = np.linalg.cholesky(ma)
    lb = np.linalg.cholesky(mb)
    fa, fb = cho_factor(ma), cho_factor(mb)
    out: list[Interaction] = []
    totals = np.zeros(3)
    for k in range(3):
        rhs = np.asarray((bb.T @ (ba.T @ (wa[:, None] * f[:, :, k] * wb[None, :])).T).T)
        coef = cho_solve(fb, cho_solve(fa, rhs).T).T  # Ma⁻¹ rhs Mb⁻¹
        x = la.T @ coef @ lb
        u_s, s, vt = np.linalg.svd(x, full_matrices=False)
        totals[k] = float(np.sum(s**2))
        for r in range(min(ranks, len(s))):
            u = solve_triangular(la.T, u_s[:, r] * s[r], lower=False)
            v = solve_triangular(lb.T, vt[r, :], lower=False)
            # the coarse points are every r-th table point: the same function at every point
            u = evaluate(ka, u, knots[a].positions())
            v = evaluate(kb, v, knots[b].positions())
            out.append(Interaction(a=a, b=b, k=k, rank=r + 1, u=u, v=v, energy=float(s[r] ** 2)))
    return out, totals


def decompose(
    machine: Machine,
    tool_mm: FloatArray,
    knots: tuple[Knots, Knots, Knots],
    *,
    interaction_ranks: int = 2,
    temps_C: Mapping[str, float] | None = None,
) -> Decomposition:
    """Split the model error at ``tool_mm`` over the machine's volume (see the module text).

    ``interaction_ranks`` product terms are kept per axis pair and output (0: the pairs' sizes
    are still measured, for the report of what is left out).
    ValueError if the model is not linear in a direction signal (then no direction-selected
    table can be fitted).
    """
    lo = np.asarray(machine.volume.lower_mm, dtype=float)
    hi = np.asarray(machine.volume.upper_mm, dtype=float)
    tool = np.asarray(tool_mm, dtype=float)
    dir_axes = direction_axes(machine)
    neutral = {a: 0.0 for a in dir_axes}
    marg = [_marginal(machine, a, knots[a], lo, hi, tool, neutral, temps_C) for a in range(3)]
    means = np.array([np.einsum("ik,i->k", f, w) for _, w, f in marg])  # (axis a, output k)
    mean = means.mean(axis=0)
    main_values: list[list[FloatArray]] = [[np.empty(0)] * 3 for _ in range(3)]
    main_energy = np.zeros((3, 3))
    for a, (nodes, w, f) in enumerate(marg):
        centred = f - means[a][None, :]
        for k in range(3):
            values, energy = project(knots[a], nodes, w, centred[:, k])
            main_values[k][a] = values
            main_energy[k, a] = energy
    dir_values: dict[int, list[FloatArray]] = {}
    dir_energy: dict[int, FloatArray] = {}
    for a in dir_axes:
        nodes, w, f0 = marg[a]
        plus = _marginal(machine, a, knots[a], lo, hi, tool, {**neutral, a: 1.0}, temps_C)[2]
        minus = _marginal(machine, a, knots[a], lo, hi, tool, {**neutral, a: -1.0}, temps_C)[2]
        gap = np.max(np.abs(plus + minus - 2 * f0))
        if gap > 1e-6 + 1e-9 * np.max(np.abs(f0)):
            raise ValueError(
                f"the model is not linear in dir_{AXES[a]} (mean of both directions differs from "
                f"the unknown direction by {gap:.3g} µm): direction-selected tables cannot be fitted"
            )
        half = (plus - minus) / 2
        dir_values[a] = []
        dir_energy[a] = np.zeros(3)
        for k in range(3):
            values, energy = project(knots[a], nodes, w, half[:, k])
            dir_values[a].append(values)
            dir_energy[a][k] = energy
    interactions: list[Interaction] = []
    pair_energy: dict[tuple[int, int, int], float] = {}
    for a, b in ((0, 1), (0, 2), (1, 2)):
        terms, totals = _pair(machine, a, b, knots, lo, hi, tool, temps_C, interaction_ranks)
        interactions += terms
        pair_energy.update({(a, b, k): float(totals[k]) for k in range(3)})
    return Decomposition(
        knots=knots,
        lower_mm=lo,
        upper_mm=hi,
        direction_axes=dir_axes,
        mean_um=mean,
        main_values=main_values,
        main_energy=main_energy,
        dir_values=dir_values,
        dir_energy=dir_energy,
        interactions=interactions,
        pair_energy=pair_energy,
    )
