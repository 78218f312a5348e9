"""The parametrisation of the identified errors: each error function as a linear combination of
basis functions whose evaluation is *exactly* what ``machine.toml`` evaluates when the result
is written back, so a machine written by ``calibrate`` reproduces its own fit.

* ``spline``: the values at equally spaced nodes over the axis' travel; between them the
  not-a-knot cubic spline through the values (what a tabulated ``[errors.*]`` table is,
  :class:`..tables.ErrorTable`), which is linear in the values: basis ``CubicSpline(nodes, I)``.
* ``polynomial``: Legendre polynomials of the normalised position (well conditioned), written as
  the power series ``polynomial = [c0, c1, …]`` in the position (mm).
* reversal (positional tables): half reversal values at the same nodes, interpolated linearly
  (the file's ``reversal`` key); with polynomials a ``reversal`` effect ``dir·(h0 + h1·s)``.

Linear errors are referred to the reference point (the lower corner): their value there is
fixed at zero (a constant linear error is a rigid translation no data can see). Angular errors
and squareness are free. :meth:`FunctionBasis.curvature` gives the roughness penalty
``L³·∫f''²`` (L the span) of the smoothness prior. Units: positions mm, values µm or µrad.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.polynomial import legendre
from numpy.typing import NDArray
from scipy.interpolate import CubicSpline

from ..parametric_errors import AXES, SQUARENESS, parse_component
from ..uncertainty.model import table_class

__all__ = ["FunctionBasis", "Layout"]

FloatArray = NDArray[np.float64]


#: power p of the end weight (1 − s²)^p of the roughness penalty (:func:`end_weight`)
END_WEIGHT_POWER = 1.0


def end_weight(nodes_mm: FloatArray) -> FloatArray:
    """(M − 1,) the weight of each node interval in the third-derivative penalty: the mean of
    ``(1 − s²)^p`` over the interval (s the position normalised to −1…1 over the travel,
    p = :data:`END_WEIGHT_POWER`), scaled so that its mean over the travel is 1 (a cubic keeps
    the roughness it has unweighted).

    The weight of the Legendre series' own Sturm–Liouville form: it lets a function change
    faster towards the ends of the travel than in the middle, as low-order curves do (a
    polynomial's derivatives are largest at the ends) — and as the fit must allow where its
    data stop short of the ends (a laser run from 3 %, a plate's edge): with a uniform weight,
    the smoothness prior extrapolated the middle's smoothness to the ends and U there was too
    small (docs/calibration.md §3, §8.1)."""
    span = float(nodes_mm[-1] - nodes_mm[0])
    g, gw = np.polynomial.legendre.leggauss(6)  # exact for (1 − s²)^p, p ≤ 5 integer
    lo, h = nodes_mm[:-1, None], np.diff(nodes_mm)[:, None]
    s = 2.0 * (lo + (g + 1.0) / 2.0 * h - nodes_mm[0]) / span - 1.0
    w = np.sum(gw / 2.0 * np.clip(1.0 - s**2, 0.0, None) ** END_WEIGHT_POWER, axis=1)
    return np.asarray(w / (np.sum(w * h[:, 0]) / span), dtype=float)


@dataclass(frozen=True)
class FunctionBasis:
    """One identified function: component ``name`` (or ``reversal:<name>``) of ``axis`` in
    ``slot`` (0–5: dx dy dz ex ey ez) with parameters ``start:start+size`` of θ."""

    name: str
    axis: int
    slot: int
    kind: str  # positional | straightness | angular | reversal
    basis: str  # spline | polynomial | hat | linear
    lo_mm: float
    hi_mm: float
    nodes_mm: FloatArray | None
    order: int
    fixed_reference: bool
    start: int
    size: int

    @property
    def cols(self) -> slice:
        return slice(self.start, self.start + self.size)

    @property
    def is_reversal(self) -> bool:
        return self.kind == "reversal"

    @property
    def component(self) -> str:
        return self.name.removeprefix("reversal:")

    def _s(self, q_mm: FloatArray) -> FloatArray:
        return 2.0 * (np.asarray(q_mm, float) - self.lo_mm) / (self.hi_mm - self.lo_mm) - 1.0

    def full_matrix(self, q_mm: FloatArray) -> FloatArray:
        """(N, M) basis at positions ``q_mm``, including a fixed reference column."""
        q = np.asarray(q_mm, dtype=float).reshape(-1)
        if self.basis == "spline":
            assert self.nodes_mm is not None
            qc = np.clip(q, self.nodes_mm[0], self.nodes_mm[-1])
            m = len(self.nodes_mm)
            return np.asarray(CubicSpline(self.nodes_mm, np.eye(m), bc_type="not-a-knot")(qc))
        if self.basis == "hat":
            assert self.nodes_mm is not None
            m = len(self.nodes_mm)
            return np.column_stack([np.interp(q, self.nodes_mm, np.eye(m)[j]) for j in range(m)])
        if self.basis == "linear":  # reversal effect h0 + h1·s
            return np.column_stack([np.ones_like(q), self._s(q)])
        s = self._s(q)
        return np.column_stack(
            [legendre.legval(s, np.eye(self.order + 1)[k]) for k in range(self.order + 1)]
        )

    def matrix(self, q_mm: FloatArray) -> FloatArray:
        """(N, size) basis of the free parameters at ``q_mm`` (value = matrix @ θ[cols])."""
        full = self.full_matrix(q_mm)
        if not self.fixed_reference:
            return full
        if self.basis == "spline":
            return full[:, 1:]  # the first node is the reference (the lower corner)
        ref = self.full_matrix(np.array([self.lo_mm]))
        return (full - ref)[:, 1:]  # Legendre P_k(s) − P_k(s_ref), k ≥ 1

    def full_values(self, params: FloatArray) -> FloatArray:
        """Node values (spline, hat) or Legendre coefficients (polynomial) incl. the fixed ones."""
        p = np.asarray(params, dtype=float)
        if not self.fixed_reference:
            return p.copy()
        if self.basis == "spline":
            return np.concatenate([[0.0], p])
        ref = self.full_matrix(np.array([self.lo_mm]))[0]
        c0 = -float(ref[1:] @ p)  # the constant that makes the value zero at the reference
        return np.concatenate([[c0], p])

    def power_series(self, params: FloatArray) -> FloatArray:
        """Polynomial basis only: coefficients c0, c1, … of the value in the position q (mm)."""
        coef = self.full_values(params)
        series = legendre.Legendre(coef, domain=[self.lo_mm, self.hi_mm])
        return np.asarray(series.convert(kind=np.polynomial.Polynomial).coef, dtype=float)

    def curvature(self, order: int = 2) -> FloatArray:
        """(size, size) roughness penalty ``L^(2·order−1)·∫ (d^order f / dq^order)² dq`` of the
        free parameters: order 2 the curvature (straight lines are free), order 3 the change of
        curvature (parabolas are free), for a spline weighted towards the travel's ends by
        :func:`end_weight`; zero for polynomials (their order is the smoothness)."""
        if self.basis in ("polynomial", "linear") or self.nodes_mm is None:
            return np.zeros((self.size, self.size))
        nodes = self.nodes_mm
        m = len(nodes)
        h = np.diff(nodes)
        span = float(nodes[-1] - nodes[0])
        if self.basis == "spline":
            d2 = np.asarray(CubicSpline(nodes, np.eye(m), bc_type="not-a-knot")(nodes, 2))
            if order == 3:  # the third derivative is constant on each interval
                d3 = (d2[1:] - d2[:-1]) / h[:, None]
                k = d3.T @ np.diag(h * end_weight(nodes)) @ d3
            else:
                q = np.zeros((m, m))  # the integral of a piecewise linear f'' squared (exact)
                for i, hi in enumerate(h):
                    q[i, i] += hi / 3.0
                    q[i + 1, i + 1] += hi / 3.0
                    q[i, i + 1] += hi / 6.0
                    q[i + 1, i] += hi / 6.0
                k = d2.T @ q @ d2
        else:  # hat (piecewise linear): squared second differences
            if m < 3:
                return np.zeros((self.size, self.size))
            d = np.zeros((m - 2, m))
            for i in range(m - 2):
                d[i, i : i + 3] = np.array([1.0, -2.0, 1.0]) / (h[i] * h[i + 1])
            k = d.T @ np.diag(0.5 * (h[:-1] + h[1:])) @ d
            order = 2
        k = k * span ** (2 * order - 1)
        return k[1:, 1:] if self.fixed_reference else k


class Layout:
    """Where each identified function and squareness sits in the parameter vector θ (machine
    part): ``functions`` and ``squareness`` (name → index). Built from the plan's volume and
    fit settings, the components to identify and the axes with a reversal to estimate."""

    def __init__(
        self,
        lower_mm: FloatArray,
        upper_mm: FloatArray,
        *,
        basis: str,
        nodes: tuple[int, int, int],
        order: tuple[int, int, int],
        components: tuple[str, ...],
        reversal_axes: tuple[int, ...] = (),
    ) -> None:
        self.lower_mm = np.asarray(lower_mm, dtype=float)
        self.upper_mm = np.asarray(upper_mm, dtype=float)
        self.basis = basis
        functions: list[FunctionBasis] = []
        start = 0
        for name in components:
            if name in SQUARENESS:
                continue
            comp = parse_component(name)
            k = AXES.index(comp.axis)
            fn = self._function(name, k, comp.slot, table_class(name), basis, nodes, order, start)
            functions.append(fn)
            start += fn.size
        for k in reversal_axes:
            name = f"d{AXES[k]}_{AXES[k]}"
            rb = "hat" if basis == "spline" else "linear"
            fn = self._function(f"reversal:{name}", k, k, "reversal", rb, nodes, order, start)
            functions.append(fn)
            start += fn.size
        self.functions = tuple(functions)
        self.squareness = {
            name: start + j for j, name in enumerate(n for n in SQUARENESS if n in components)
        }
        self.n = start + len(self.squareness)

    def _function(
        self,
        name: str,
        k: int,
        slot: int,
        kind: str,
        basis: str,
        nodes: tuple[int, int, int],
        order: tuple[int, int, int],
        start: int,
    ) -> FunctionBasis:
        lo, hi = float(self.lower_mm[k]), float(self.upper_mm[k])
        fixed = kind in ("positional", "straightness")
        node_pos = np.linspace(lo, hi, nodes[k]) if basis in ("spline", "hat") else None
        if basis in ("spline", "hat"):
            size = nodes[k] - (1 if fixed else 0)
        elif basis == "linear":
            size = 2
        else:
            size = order[k] + (0 if fixed else 1)
        return FunctionBasis(
            name=name,
            axis=k,
            slot=slot,
            kind=kind,
            basis=basis,
            lo_mm=lo,
            hi_mm=hi,
            nodes_mm=node_pos,
            order=order[k],
            fixed_reference=fixed,
            start=start,
            size=size,
        )

    def function(self, name: str) -> FunctionBasis | None:
        for fn in self.functions:
            if fn.name == name:
                return fn
        return None

    def errors(
        self, theta: FloatArray, q_mm: FloatArray, direction: FloatArray | None = None
    ) -> tuple[FloatArray, FloatArray]:
        """(N, 3, 6) parametric errors and (3,) squareness (µm, µrad) at indicated ``q_mm``;
        ``direction`` (N, 3) the last direction of travel per axis (±1, 0 unknown)."""
        q = np.asarray(q_mm, dtype=float)
        out = np.zeros((q.shape[0], 3, 6))
        for fn in self.functions:
            values = fn.matrix(q[:, fn.axis]) @ theta[fn.cols]
            if fn.is_reversal:
                if direction is None:
                    continue
                values = values * direction[:, fn.axis]
            out[:, fn.axis, fn.slot] += values
        return out, self.squareness_values(theta)

    def squareness_values(self, theta: FloatArray) -> FloatArray:
        """(3,) α, β1, β2 (µrad) of θ (zero when not identified)."""
        sq = np.zeros(3)
        for j, name in enumerate(SQUARENESS):
            if name in self.squareness:
                sq[j] = theta[self.squareness[name]]
        return sq

    def blocks(
        self, q_mm: FloatArray, direction: FloatArray | None = None
    ) -> list[tuple[FunctionBasis, FloatArray]]:
        """Each function with its (N, size) basis at ``q_mm`` (reversal times the direction)."""
        q = np.asarray(q_mm, dtype=float)
        out = []
        for fn in self.functions:
            m = fn.matrix(q[:, fn.axis])
            if fn.is_reversal:
                if direction is None:
                    continue
                m = m * direction[:, fn.axis : fn.axis + 1]
            out.append((fn, m))
        return out
