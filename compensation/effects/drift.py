"""Drift with time (docs/formats.md §4 cause ``drift``): an axis' positional error changes during
a session in a way no logged signal explains — typically a thermal state that was not measured
(a temperature not logged, a reference instrument warming up).

The term is ``Σ_{k=1..K} o_k·P_k(τ) + (u/1000)·Σ_{k=0..K} s_k·P_k(τ)`` µm added to the axis'
positional error, ``τ`` the session time normalised to [−1, 1] over ``t_span_s`` and ``P_k``
Legendre polynomials: an offset part ``o_k`` µm and a part growing with the distance ``u`` mm
from the reference point, ``s_k`` µm/m, as a length scale changing with an unlogged temperature
does. The scale part has a mean (k = 0: the scale was off on average over the session, as it is
when the structure is away from its reference temperature); the offset's mean is not a drift.

A drift may also change shape along the axis (``position_um``: a thermal bend, or the expansion
of a part of the structure an unlogged temperature heats): ``Σ_{k≥1} Σ_{j≥0} c_kj·P_k(τ)·P_j(s)``
µm, s the position normalised over ``span_mm``. ``describe`` names the drift's shape: ``uniform``
(the same at every position), ``expansion`` (growing linearly about a fixed point,
``fixed_point_mm``: thermal expansion about where the structure is fixed) or ``smooth``.

A drift is a *diagnosis*: it says the session's error changed with time and how much; it cannot
be compensated ahead of time (a grid has no clock of the structure's history), so ``cmm-comp
extend`` does not add it — log the temperature that drives it and a thermal cause replaces it.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from typing import Any, ClassVar

import numpy as np
from numpy.polynomial import legendre

from ..parametric_errors import AXIS_INDEX
from .base import (
    Effect,
    EvalContext,
    read_axis,
    read_floats,
    read_span,
    read_str,
    register_effect,
    signal_or,
)

__all__ = ["TIME_SIGNAL", "DriftEffect"]

#: The runtime signal carrying time (s) in measurements and effects.
TIME_SIGNAL = "t"


class DriftEffect(Effect):
    """Positional error of ``axis`` drifting with time: see the module docstring."""

    cause: ClassVar[str] = "drift"
    compensable: ClassVar[bool] = False

    def __init__(
        self,
        axis: str,
        t_span_s: tuple[float, float],
        offset_um: Sequence[float],
        scale_um_per_m: Sequence[float],
        position_um: Sequence[Sequence[float]] = (),
        span_mm: tuple[float, float] | None = None,
    ) -> None:
        self.axis = read_axis(axis)
        self.t_span_s = t_span_s
        self.position_um = [read_floats(row, "position_um") for row in position_um]
        if self.position_um and span_mm is None:
            raise ValueError("drift: position_um needs span_mm")
        if len(self.position_um) > len(offset_um):
            raise ValueError("drift: position_um has more time orders than offset_um")
        self.span_mm = span_mm
        self.offset_um = read_floats(offset_um, "offset_um")
        self.scale_um_per_m = read_floats(
            scale_um_per_m, "scale_um_per_m (orders 0…K)", len(self.offset_um) + 1
        )
        if not self.offset_um:
            raise ValueError("drift: at least one order (offset_um) is required")

    def signals(self) -> dict[str, float]:
        return {TIME_SIGNAL: 0.5 * (self.t_span_s[0] + self.t_span_s[1])}

    def time_basis(self, t_s: np.ndarray) -> np.ndarray:
        """(N, K + 1) Legendre polynomials P_0 … P_K of the normalised time."""
        lo, hi = self.t_span_s
        tau = 2.0 * (np.asarray(t_s, dtype=float) - lo) / (hi - lo) - 1.0
        return np.asarray(legendre.legvander(tau, len(self.offset_um)), dtype=float)

    def modify_errors(self, ctx: EvalContext) -> None:
        k = AXIS_INDEX[self.axis]
        mid = 0.5 * (self.t_span_s[0] + self.t_span_s[1])
        basis = self.time_basis(signal_or(ctx, TIME_SIGNAL, mid))
        u_m = ctx.u_mm[:, k] / 1000.0
        ctx.errors[:, k, k] += basis[:, 1:] @ np.asarray(self.offset_um) + u_m * (
            basis @ np.asarray(self.scale_um_per_m)
        )
        if self.position_um:
            ctx.errors[:, k, k] += self._shaped(basis, ctx.q_mm[:, k])

    def _shaped(self, time_basis: np.ndarray, q_mm: np.ndarray) -> np.ndarray:
        """``Σ_k Σ_j c_kj·P_k(τ)·P_j(s)`` (µm) at positions ``q_mm``."""
        lo, hi = self.span_mm  # type: ignore[misc]
        s = 2.0 * (np.asarray(q_mm, dtype=float) - lo) / (hi - lo) - 1.0
        out = np.zeros(len(s))
        for k, row in enumerate(self.position_um, start=1):
            out += time_basis[:, k] * legendre.legval(s, row)
        return out

    def shape(self) -> dict[str, Any]:
        """``{"shape": uniform | expansion | smooth[, "fixed_point_mm": …]}``."""
        if self.position_um:
            return {"shape": "smooth"}
        s = np.asarray(self.scale_um_per_m[1:])
        o = np.asarray(self.offset_um)
        if not np.any(s):
            return {"shape": "uniform"}
        return {"shape": "expansion", "fixed_point_u_mm": float(-1000.0 * (o @ s) / (s @ s))}

    def to_table(self) -> dict[str, Any]:
        t: dict[str, Any] = {
            "cause": self.cause,
            "axis": self.axis,
            "t_span_s": list(self.t_span_s),
            "offset_um": list(self.offset_um),
            "scale_um_per_m": list(self.scale_um_per_m),
        }
        if self.position_um:
            t["position_um"] = [list(r) for r in self.position_um]
            t["span_mm"] = list(self.span_mm)  # type: ignore[arg-type]
        return t

    def describe(self) -> dict[str, Any]:
        t = np.linspace(*self.t_span_s, 201)
        basis = self.time_basis(t)
        offset = basis[:, 1:] @ np.asarray(self.offset_um)
        scale = basis[:, 1:] @ np.asarray(self.scale_um_per_m[1:])
        params: dict[str, Any] = {
            "offset_range_um": float(np.ptp(offset)),
            "scale_range_um_per_m": float(np.ptp(scale)),
            "scale_mean_um_per_m": self.scale_um_per_m[0],
            "t_span_s": list(self.t_span_s),
            "offset_um": list(self.offset_um),
            "scale_um_per_m": list(self.scale_um_per_m),
            **self.shape(),
        }
        if self.position_um:
            params["position_um"] = [list(r) for r in self.position_um]
            params["span_mm"] = list(self.span_mm)  # type: ignore[arg-type]
            params["change_along_axis_um"] = self.change_along_axis_um()
        return {"cause": self.cause, "axis": self.axis, "parameters": params}

    def change_along_axis_um(self, points: int = 9) -> dict[str, list[float]]:
        """How much the shaped part changed from the session's start to its end, at ``points``
        positions along the span: ``{"position_mm": […], "change_um": […]}``."""
        lo, hi = self.span_mm  # type: ignore[misc]
        q = np.linspace(lo, hi, points)
        ends = self.time_basis(np.asarray(self.t_span_s, dtype=float))
        change = [
            float(v)
            for v in self._shaped(np.repeat(ends[1:2], points, 0), q)
            - self._shaped(np.repeat(ends[0:1], points, 0), q)
        ]
        return {"position_mm": [float(v) for v in q], "change_um": change}

    @classmethod
    def from_table(cls, t: Mapping[str, Any]) -> DriftEffect:
        offset = read_floats(t.get("offset_um"), "offset_um")
        rows = t.get("position_um", [])
        if not isinstance(rows, list):
            raise ValueError(f"position_um must be a list of lists of numbers, got {rows!r}")
        return cls(
            read_str(t, "axis"),
            read_span(t.get("t_span_s"), "t_span_s"),
            offset,
            read_floats(t.get("scale_um_per_m"), "scale_um_per_m (orders 0…K)", len(offset) + 1),
            rows,
            read_span(t["span_mm"], "span_mm") if "span_mm" in t else None,
        )


register_effect(DriftEffect.cause, DriftEffect.from_table)
