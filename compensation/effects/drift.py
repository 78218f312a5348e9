"""Drift with time (docs/formats.md §4 cause ``drift``): an axis' positional error changes during
a session in a way no logged signal explains — typically a thermal state that was not measured
(a temperature not logged, a reference instrument warming up).

The term is ``Σ_{k=1..K} o_k·P_k(τ) + (u/1000)·Σ_{k=0..K} s_k·P_k(τ)`` µm added to the axis'
positional error, ``τ`` the session time normalised to [−1, 1] over ``t_span_s`` and ``P_k``
Legendre polynomials: an offset part ``o_k`` µm and a part growing with the distance ``u`` mm
from the reference point, ``s_k`` µm/m, as a length scale changing with an unlogged temperature
does. The scale part has a mean (k = 0: the scale was off on average over the session, as it is
when the structure is away from its reference temperature); the offset's mean is not a drift.

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
    ) -> None:
        self.axis = read_axis(axis)
        self.t_span_s = t_span_s
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

    def to_table(self) -> dict[str, Any]:
        return {
            "cause": self.cause,
            "axis": self.axis,
            "t_span_s": list(self.t_span_s),
            "offset_um": list(self.offset_um),
            "scale_um_per_m": list(self.scale_um_per_m),
        }

    def describe(self) -> dict[str, Any]:
        t = np.linspace(*self.t_span_s, 201)
        basis = self.time_basis(t)
        offset = basis[:, 1:] @ np.asarray(self.offset_um)
        scale = basis[:, 1:] @ np.asarray(self.scale_um_per_m[1:])
        return {
            "cause": self.cause,
            "axis": self.axis,
            "parameters": {
                "offset_range_um": float(np.ptp(offset)),
                "scale_range_um_per_m": float(np.ptp(scale)),
                "scale_mean_um_per_m": self.scale_um_per_m[0],
                "t_span_s": list(self.t_span_s),
                "offset_um": list(self.offset_um),
                "scale_um_per_m": list(self.scale_um_per_m),
            },
        }

    @classmethod
    def from_table(cls, t: Mapping[str, Any]) -> DriftEffect:
        offset = read_floats(t.get("offset_um"), "offset_um")
        return cls(
            read_str(t, "axis"),
            read_span(t.get("t_span_s"), "t_span_s"),
            offset,
            read_floats(t.get("scale_um_per_m"), "scale_um_per_m (orders 0…K)", len(offset) + 1),
        )


register_effect(DriftEffect.cause, DriftEffect.from_table)
