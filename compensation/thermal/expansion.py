"""Thermal expansion: the machine's own scale and workpiece terms (docs/formats.md §1 ``[thermal]``)
and the effects that correct them (docs/formats.md §4 ``scale_expansion``, ``workpiece_expansion``).

Scale term of axis j: ``α_j·(T_j − T_ref)·(q_j − ref_j)/1000`` µm (α µm/(m·°C), q and ref mm);
workpiece term: ``−α_wp·(T_wp − T_ref)·(q − fixture)/1000`` µm. Temperatures °C by role
(:mod:`.roles`); ``T_ref`` the machine's thermal reference.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any, ClassVar

import numpy as np
from numpy.typing import NDArray

from ..effects.base import (
    Effect,
    EvalContext,
    read_axis,
    read_floats,
    read_number,
    read_str,
    register_effect,
    signal_or,
)
from ..parametric_errors import AXES, AXIS_INDEX
from .roles import WORKPIECE, scale_role

__all__ = [
    "ScaleExpansionEffect",
    "TemperatureEffect",
    "Thermal",
    "WorkpieceExpansionEffect",
]

FloatArray = NDArray[np.float64]


@dataclass(frozen=True)
class Thermal:
    """The machine's thermal data: reference °C, scale expansion coefficients per axis and the
    workpiece's (µm/(m·°C)), and the workpiece fixture point (mm; None = the reference point)."""

    reference_C: float = 20.0
    expansion: FloatArray = field(default_factory=lambda: np.zeros(3))  # µm/(m·°C) per axis scale
    workpiece_expansion: float | None = None  # µm/(m·°C)
    workpiece_fixture_mm: FloatArray | None = None

    def runtime_signals(self) -> dict[str, float]:
        """Temperature roles the built-in terms read, with their reference (°C)."""
        out: dict[str, float] = {}
        for k, axis in enumerate(AXES):
            if self.expansion[k] != 0.0:
                out[scale_role(axis)] = self.reference_C
        if self.workpiece_expansion:
            out[WORKPIECE] = self.reference_C
        return out

    def add_expansion(self, ctx: EvalContext) -> None:
        """Add the scale and workpiece expansion terms (µm) to ``ctx.direct_um``; the workpiece
        expands about its fixture point (default: the machine's reference point)."""
        ref_c = self.reference_C
        for k, axis in enumerate(AXES):
            alpha = self.expansion[k]
            if alpha:
                dt = ctx.signals[scale_role(axis)] - ref_c
                ctx.direct_um[:, k] += alpha * dt * ctx.u_mm[:, k] / 1000.0
        if self.workpiece_expansion:
            fixture = (
                self.workpiece_fixture_mm
                if self.workpiece_fixture_mm is not None
                else ctx.reference_mm
            )
            dt = ctx.signals[WORKPIECE] - ref_c
            ctx.direct_um -= self.workpiece_expansion * dt[:, None] * (ctx.q_mm - fixture) / 1000.0


class TemperatureEffect(Effect):
    """Base of effects driven by a temperature: ``reference_C`` is the neutral value their
    signals report (the machine's thermal reference, stored in the table; default 20 °C)."""

    reference_C: float = 20.0

    def _with_reference(self, t: Mapping[str, Any]) -> Any:
        self.reference_C = read_number(t, "reference_C", 20.0)
        return self

    def _table(self, **items: Any) -> dict[str, Any]:
        return {"cause": self.cause, **items, "reference_C": self.reference_C}


# ----------------------------------------------------------------------------- thermal


class ScaleExpansionEffect(TemperatureEffect):
    """An axis' effective expansion coefficient is off by ``delta`` µm/(m·°C):
    ``delta·(T_axis − T_ref)·(q − fixed)/1000`` µm added to that axis' error component, the
    scale expanding about the point where it is fixed to the structure (``fixed_at_mm``, a
    position along the axis; None: the machine's reference point)."""

    cause: ClassVar[str] = "scale_expansion"

    def __init__(self, axis: str, delta_expansion: float, fixed_at_mm: float | None = None) -> None:
        self.axis = read_axis(axis)
        self.delta = float(delta_expansion)
        if fixed_at_mm is not None and not np.isfinite(fixed_at_mm):
            raise ValueError(f"fixed_at_mm must be a finite position (mm), got {fixed_at_mm}")
        self.fixed_at_mm = None if fixed_at_mm is None else float(fixed_at_mm)

    def signals(self) -> dict[str, float]:
        return {scale_role(self.axis): self.reference_C}

    def add_direct(self, ctx: EvalContext) -> None:
        k = AXIS_INDEX[self.axis]
        dt = signal_or(ctx, scale_role(self.axis), ctx.reference_C) - ctx.reference_C
        arm = ctx.u_mm[:, k] if self.fixed_at_mm is None else ctx.q_mm[:, k] - self.fixed_at_mm
        ctx.direct_um[:, k] += self.delta * dt * arm / 1000.0

    def to_table(self) -> dict[str, Any]:
        extra = {} if self.fixed_at_mm is None else {"fixed_at_mm": self.fixed_at_mm}
        return self._table(axis=self.axis, delta_expansion=self.delta, **extra)

    def describe(self) -> dict[str, Any]:
        params: dict[str, Any] = {"delta_expansion_um_per_m_C": self.delta}
        if self.fixed_at_mm is not None:
            params["fixed_at_mm"] = self.fixed_at_mm
        return {"cause": self.cause, "axis": self.axis, "parameters": params}

    @classmethod
    def from_table(cls, t: Mapping[str, Any]) -> ScaleExpansionEffect:
        fixed = read_number(t, "fixed_at_mm") if "fixed_at_mm" in t else None
        return cls(read_str(t, "axis"), read_number(t, "delta_expansion"), fixed)._with_reference(t)


class WorkpieceExpansionEffect(TemperatureEffect):
    """Workpiece expansion about its fixture point wrong or missing: ``−delta·(T_wp − T_ref)·
    (q − fixture)/1000`` µm (delta µm/(m·°C), added to the machine's own workpiece term)."""

    cause: ClassVar[str] = "workpiece_expansion"

    def __init__(self, delta_expansion: float, fixture_mm: Sequence[float]) -> None:
        self.delta = float(delta_expansion)
        self.fixture_mm = read_floats(fixture_mm, "fixture_mm", 3)

    def signals(self) -> dict[str, float]:
        return {WORKPIECE: self.reference_C}

    def add_direct(self, ctx: EvalContext) -> None:
        dt = signal_or(ctx, WORKPIECE, ctx.reference_C) - ctx.reference_C
        ctx.direct_um -= (
            self.delta * dt[:, None] * (ctx.q_mm - np.asarray(self.fixture_mm)) / 1000.0
        )

    def to_table(self) -> dict[str, Any]:
        return self._table(delta_expansion=self.delta, fixture_mm=list(self.fixture_mm))

    def describe(self) -> dict[str, Any]:
        return {
            "cause": self.cause,
            "parameters": {
                "delta_expansion_um_per_m_C": self.delta,
                "fixture_mm": list(self.fixture_mm),
            },
        }

    @classmethod
    def from_table(cls, t: Mapping[str, Any]) -> WorkpieceExpansionEffect:
        return cls(
            read_number(t, "delta_expansion"), t.get("fixture_mm", (0.0, 0.0, 0.0))
        )._with_reference(t)


for _cls in (ScaleExpansionEffect, WorkpieceExpansionEffect):
    register_effect(_cls.cause, _cls.from_table)
