"""Effects on the parametric model itself (docs/formats.md §4 causes ``parametric``, ``coupling``,
``reversal``, ``periodic``): smooth corrections of the 21 errors, their dependence on another
axis, the direction of travel and cyclic errors along an axis.

Each effect is a physically meaningful term with few parameters, linear in its amplitude
parameters (the diagnosis fits them by linear least squares) and linear in the runtime signals it
declares through :meth:`Effect.signals`. Shapes along an axis use Legendre polynomials
``P_k(s)`` of the normalised position ``s = 2·(q − lo)/(hi − lo) − 1 ∈ [−1, 1]`` over the axis
span ``[lo, hi]`` (mm), referred to the machine's reference point (every term vanishes there,
like the parametric tables). ``reversal`` reads the signals ``dir_<axis>`` (+1/−1; 0 = unknown,
the mean of both directions).

Units: positions mm, linear errors µm, angles and squareness µrad.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from typing import Any, ClassVar

import numpy as np
from numpy.polynomial import legendre

from ..parametric_errors import AXIS_INDEX, SQUARENESS, TABLE_COMPONENTS, parse_component
from .base import (
    Effect,
    EvalContext,
    FloatArray,
    add_to_component,
    read_axis,
    read_floats,
    read_number,
    read_span,
    read_str,
    register_effect,
    signal_or,
)

__all__ = [
    "CouplingEffect",
    "ParametricEffect",
    "PeriodicEffect",
    "ReversalEffect",
    "default_orders",
    "legendre_shape",
    "normalised",
]


def normalised(q_mm: FloatArray, span_mm: tuple[float, float]) -> FloatArray:
    """``s = 2·(q − lo)/(hi − lo) − 1``: position normalised to [−1, 1] over the span."""
    lo, hi = span_mm
    return 2.0 * (np.asarray(q_mm, dtype=float) - lo) / (hi - lo) - 1.0


def legendre_shape(
    q_mm: FloatArray, ref_mm: float, span_mm: tuple[float, float], order: int
) -> FloatArray:
    """``P_k(s(q)) − P_k(s(ref))``: Legendre polynomial of order k, zero at the reference."""
    c = np.zeros(order + 1)
    c[order] = 1.0
    ref = float(legendre.legval(normalised(np.array([ref_mm]), span_mm), c)[0])
    return np.asarray(legendre.legval(normalised(q_mm, span_mm), c) - ref, dtype=float)


def default_orders(component: str) -> list[int]:
    """Legendre orders of a smooth table correction: positional 1–4, straightness 2–4 (its
    slope belongs to the squareness), angular 1–3, squareness a constant (order 0)."""
    if component in SQUARENESS:
        return [0]
    c = parse_component(component)
    if c.is_positional:
        return [1, 2, 3, 4]
    if c.is_straightness:
        return [2, 3, 4]
    return [1, 2, 3]


# ----------------------------------------------------------------------------- parametric
class ParametricEffect(Effect):
    """A parametric table (or a squareness) off by a smooth shape: ``Σ c_k (P_k(s) − P_k(s_ref))``
    (µm or µrad) for the orders in ``orders``; a squareness gets the constant ``c_0``."""

    cause: ClassVar[str] = "parametric"

    def __init__(
        self,
        component: str,
        coefficients: Sequence[float],
        span_mm: tuple[float, float] = (0.0, 1.0),
        orders: Sequence[int] | None = None,
    ) -> None:
        if component not in TABLE_COMPONENTS and component not in SQUARENESS:
            raise ValueError(
                f"component must be dx_x … ez_z or alpha/beta1/beta2, got {component!r}"
            )
        self.component = component
        self.orders = list(orders) if orders is not None else default_orders(component)
        self.coefficients = [float(c) for c in coefficients]
        if len(self.coefficients) != len(self.orders):
            raise ValueError(
                f"{len(self.orders)} coefficients expected (orders {self.orders}), "
                f"got {len(self.coefficients)}"
            )
        self.span_mm = span_mm

    def value(self, q_axis_mm: FloatArray, ref_mm: float) -> FloatArray:
        """The correction (µm or µrad) at positions of the component's own axis."""
        out = np.zeros(np.shape(q_axis_mm))
        for k, c in zip(self.orders, self.coefficients, strict=True):
            out = out + (c if k == 0 else c * legendre_shape(q_axis_mm, ref_mm, self.span_mm, k))
        return out

    def modify_errors(self, ctx: EvalContext) -> None:
        if self.component in SQUARENESS:
            add_to_component(ctx, self.component, np.full(ctx.n, self.coefficients[0]))
            return
        k = AXIS_INDEX[self.component[-1]]
        add_to_component(
            ctx, self.component, self.value(ctx.q_mm[:, k], float(ctx.reference_mm[k]))
        )

    def to_table(self) -> dict[str, Any]:
        return {
            "cause": self.cause,
            "component": self.component,
            "span_mm": list(self.span_mm),
            "orders": list(self.orders),
            "coefficients": list(self.coefficients),
        }

    def describe(self) -> dict[str, Any]:
        return {
            "cause": self.cause,
            "component": self.component,
            "parameters": {
                f"legendre_{k}": c for k, c in zip(self.orders, self.coefficients, strict=True)
            },
        }

    @classmethod
    def from_table(cls, t: Mapping[str, Any]) -> ParametricEffect:
        comp = t.get("component")
        if comp not in TABLE_COMPONENTS and comp not in SQUARENESS:
            raise ValueError(
                f"parametric: component must be dx_x … ez_z or alpha/beta1/beta2, got {comp!r}"
            )
        orders = [int(o) for o in read_floats(t.get("orders", default_orders(comp)), "orders")]
        return cls(
            comp,
            read_floats(t.get("coefficients"), "coefficients", len(orders)),
            read_span(t.get("span_mm", (0.0, 1.0)), "span_mm"),
            orders,
        )


# ----------------------------------------------------------------------------- coupling
class CouplingEffect(Effect):
    """A parametric error of one axis that also varies with another axis' position (non-rigid
    body: load shift, bridge twist): ``(s_b − s_b,ref)·Σ c_k (P_k(s_a) − P_k(s_a,ref))``, k = 1, 2,
    added to ``component`` of axis a (µm or µrad), where b is ``varies_with``."""

    cause: ClassVar[str] = "coupling"
    ORDERS: ClassVar[tuple[int, ...]] = (1, 2)

    def __init__(
        self,
        component: str,
        varies_with: str,
        coefficients: Sequence[float],
        span_mm: tuple[float, float],
        span_with_mm: tuple[float, float],
    ) -> None:
        c = parse_component(component)
        self.component = c.name
        self.varies_with = read_axis(varies_with, "varies_with")
        if self.varies_with == c.axis:
            raise ValueError(f"coupling: {component} cannot vary with its own axis")
        self.coefficients = read_floats(coefficients, "coefficients", len(self.ORDERS))
        self.span_mm = span_mm
        self.span_with_mm = span_with_mm

    def modify_errors(self, ctx: EvalContext) -> None:
        a = AXIS_INDEX[self.component[-1]]
        b = AXIS_INDEX[self.varies_with]
        sb = normalised(ctx.q_mm[:, b], self.span_with_mm) - normalised(
            np.array([ctx.reference_mm[b]]), self.span_with_mm
        )
        shape = np.zeros(ctx.n)
        for k, c in zip(self.ORDERS, self.coefficients, strict=True):
            shape += c * legendre_shape(ctx.q_mm[:, a], float(ctx.reference_mm[a]), self.span_mm, k)
        add_to_component(ctx, self.component, sb * shape)

    def to_table(self) -> dict[str, Any]:
        return {
            "cause": self.cause,
            "component": self.component,
            "varies_with": self.varies_with,
            "span_mm": list(self.span_mm),
            "span_with_mm": list(self.span_with_mm),
            "coefficients": list(self.coefficients),
        }

    def describe(self) -> dict[str, Any]:
        return {
            "cause": self.cause,
            "component": self.component,
            "varies_with": self.varies_with,
            "parameters": {
                f"legendre_{k}": c for k, c in zip(self.ORDERS, self.coefficients, strict=True)
            },
        }

    @classmethod
    def from_table(cls, t: Mapping[str, Any]) -> CouplingEffect:
        return cls(
            str(t.get("component")),
            read_str(t, "varies_with"),
            read_floats(t.get("coefficients"), "coefficients", len(cls.ORDERS)),
            read_span(t.get("span_mm"), "span_mm"),
            read_span(t.get("span_with_mm"), "span_with_mm"),
        )


# ----------------------------------------------------------------------------- direction
class ReversalEffect(Effect):
    """Positional error that depends on the direction of travel (backlash, hysteresis):
    ``dir·(h0 + h1·P1(s))`` µm added to the axis' positional error, ``dir`` = ±1 the last
    direction of travel (0 = unknown); the reversal value (− minus +) is ``−2·h``."""

    cause: ClassVar[str] = "reversal"

    def __init__(self, axis: str, half_step_um: Sequence[float], span_mm: tuple[float, float]):
        self.axis = read_axis(axis)
        self.half_step_um = read_floats(half_step_um, "half_step_um", 2)
        self.span_mm = span_mm

    def signals(self) -> dict[str, float]:
        return {f"dir_{self.axis}": 0.0}

    def modify_errors(self, ctx: EvalContext) -> None:
        k = AXIS_INDEX[self.axis]
        d = signal_or(ctx, f"dir_{self.axis}", 0.0)
        s = normalised(ctx.q_mm[:, k], self.span_mm)
        ctx.errors[:, k, k] += d * (self.half_step_um[0] + self.half_step_um[1] * s)

    def to_table(self) -> dict[str, Any]:
        return {
            "cause": self.cause,
            "axis": self.axis,
            "half_step_um": list(self.half_step_um),
            "span_mm": list(self.span_mm),
        }

    def describe(self) -> dict[str, Any]:
        return {
            "cause": self.cause,
            "axis": self.axis,
            "parameters": {
                "half_step_um": self.half_step_um[0],
                "half_step_slope_um": self.half_step_um[1],
                "reversal_mean_um": -2.0 * self.half_step_um[0],
            },
        }

    @classmethod
    def from_table(cls, t: Mapping[str, Any]) -> ReversalEffect:
        return cls(
            read_str(t, "axis"),
            read_floats(t.get("half_step_um"), "half_step_um", 2),
            read_span(t.get("span_mm"), "span_mm"),
        )


class PeriodicEffect(Effect):
    """Cyclic positional error along an axis: ``a·cos(2πq/P) + b·sin(2πq/P)`` µm (q the indicated
    position, P ``period_mm``), minus its value at the reference point."""

    cause: ClassVar[str] = "periodic"

    def __init__(self, axis: str, period_mm: float, a_cos_um: float, b_sin_um: float) -> None:
        self.axis = read_axis(axis)
        if not period_mm > 0:
            raise ValueError(f"period_mm must be > 0, got {period_mm}")
        self.period_mm = float(period_mm)
        self.a_cos_um = float(a_cos_um)
        self.b_sin_um = float(b_sin_um)

    def shape(self, q_mm: FloatArray, ref_mm: float) -> tuple[FloatArray, FloatArray]:
        w = 2.0 * math.pi / self.period_mm
        q = np.asarray(q_mm, dtype=float)
        return np.cos(w * q) - math.cos(w * ref_mm), np.sin(w * q) - math.sin(w * ref_mm)

    def modify_errors(self, ctx: EvalContext) -> None:
        k = AXIS_INDEX[self.axis]
        c, s = self.shape(ctx.q_mm[:, k], float(ctx.reference_mm[k]))
        ctx.errors[:, k, k] += self.a_cos_um * c + self.b_sin_um * s

    def to_table(self) -> dict[str, Any]:
        return {
            "cause": self.cause,
            "axis": self.axis,
            "period_mm": self.period_mm,
            "a_cos_um": self.a_cos_um,
            "b_sin_um": self.b_sin_um,
        }

    def describe(self) -> dict[str, Any]:
        return {
            "cause": self.cause,
            "axis": self.axis,
            "period_mm": self.period_mm,
            "parameters": {
                "period_mm": self.period_mm,
                "amplitude_um": math.hypot(self.a_cos_um, self.b_sin_um),
                "a_cos_um": self.a_cos_um,
                "b_sin_um": self.b_sin_um,
            },
        }

    @classmethod
    def from_table(cls, t: Mapping[str, Any]) -> PeriodicEffect:
        return cls(
            read_str(t, "axis"),
            read_number(t, "period_mm"),
            read_number(t, "a_cos_um"),
            read_number(t, "b_sin_um"),
        )


for _cls in (ParametricEffect, CouplingEffect, ReversalEffect, PeriodicEffect):
    register_effect(_cls.cause, _cls.from_table)
