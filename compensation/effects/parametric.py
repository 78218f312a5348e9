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

    def shortest_wavelength_mm(self) -> dict[str, float]:
        """A Legendre shape of order n has n zeros over the span: wavelength ≈ 2·span/n."""
        n = max(self.orders, default=0)
        if self.component in SQUARENESS or n < 1:
            return {}
        return {self.component[-1]: 2.0 * abs(self.span_mm[1] - self.span_mm[0]) / n}

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
def _shape_or_one(
    q_mm: FloatArray, ref_mm: float, span_mm: tuple[float, float], order: int
) -> FloatArray:
    """``P_k(s) − P_k(s_ref)`` for k ≥ 1, and 1 for k = 0 (a uniform part)."""
    if order == 0:
        return np.ones(np.shape(q_mm))
    return legendre_shape(q_mm, ref_mm, span_mm, order)


class CouplingEffect(Effect):
    """A parametric error of one axis that also varies with another axis' position (non-rigid
    body: load shift, bridge twist):
    ``Σ_j Σ_k c_jk (P_j(s_b) − P_j(s_b,ref))·S_k(s_a)`` added to ``component`` of axis a (µm or
    µrad), b = ``varies_with``, ``S_0 = 1`` (a part uniform along a: the carriage of a tilts by the
    same amount everywhere as b moves — a bridge twist) and ``S_k = P_k(s_a) − P_k(s_a,ref)``
    (a part growing along a). ``orders`` are the k (default 1, 2), ``with_orders`` the j
    (default 1: linear in b); coefficients are ordered j-major (for each j, every k).
    ``offset`` (µm or µrad) is the coupled error's value at the reference point and ``along``
    the coefficients ``a_k`` of the part ``Σ a_k (P_k(s_a) − P_k(s_a,ref))`` it has at b's
    reference position: a twist that grows with b from a point other than b's reference is
    already there (as a tilt, or a tilt growing along a) where b is at its reference."""

    cause: ClassVar[str] = "coupling"
    ORDERS: ClassVar[tuple[int, ...]] = (1, 2)

    def __init__(
        self,
        component: str,
        varies_with: str,
        coefficients: Sequence[float],
        span_mm: tuple[float, float],
        span_with_mm: tuple[float, float],
        orders: Sequence[int] | None = None,
        with_orders: Sequence[int] = (1,),
        offset: float = 0.0,
        along: Sequence[float] = (),
    ) -> None:
        c = parse_component(component)
        self.along = read_floats(along, "along")
        self.offset = float(offset)
        if not math.isfinite(self.offset):
            raise ValueError(f"coupling: offset must be finite, got {offset!r}")
        self.component = c.name
        self.varies_with = read_axis(varies_with, "varies_with")
        if self.varies_with == c.axis:
            raise ValueError(f"coupling: {component} cannot vary with its own axis")
        self.orders = tuple(int(k) for k in (self.ORDERS if orders is None else orders))
        self.with_orders = tuple(int(j) for j in with_orders)
        if any(k < 0 for k in self.orders) or any(j < 1 for j in self.with_orders):
            raise ValueError("coupling: orders must be ≥ 0 and with_orders ≥ 1")
        n = len(self.orders) * len(self.with_orders)
        self.coefficients = read_floats(coefficients, "coefficients", n)
        self.span_mm = span_mm
        self.span_with_mm = span_with_mm

    def modify_errors(self, ctx: EvalContext) -> None:
        a = AXIS_INDEX[self.component[-1]]
        b = AXIS_INDEX[self.varies_with]
        total = np.full(ctx.n, self.offset)
        for k, c in enumerate(self.along, start=1):
            total += c * legendre_shape(ctx.q_mm[:, a], float(ctx.reference_mm[a]), self.span_mm, k)
        i = 0
        for j in self.with_orders:
            sb = legendre_shape(ctx.q_mm[:, b], float(ctx.reference_mm[b]), self.span_with_mm, j)
            for k in self.orders:
                sa = _shape_or_one(ctx.q_mm[:, a], float(ctx.reference_mm[a]), self.span_mm, k)
                total += self.coefficients[i] * sb * sa
                i += 1
        add_to_component(ctx, self.component, total)

    def _names(self) -> list[str]:
        return [
            f"legendre_{k}" if self.with_orders == (1,) else f"legendre_{j}_{k}"
            for j in self.with_orders
            for k in self.orders
        ]

    def to_table(self) -> dict[str, Any]:
        return {
            "cause": self.cause,
            "component": self.component,
            "varies_with": self.varies_with,
            "span_mm": list(self.span_mm),
            "span_with_mm": list(self.span_with_mm),
            "orders": list(self.orders),
            "with_orders": list(self.with_orders),
            "coefficients": list(self.coefficients),
            "offset": self.offset,
            "along": list(self.along),
        }

    def describe(self) -> dict[str, Any]:
        return {
            "cause": self.cause,
            "component": self.component,
            "varies_with": self.varies_with,
            "parameters": {
                **dict(zip(self._names(), self.coefficients, strict=True)),
                "offset_at_reference": self.offset,
                **{f"along_{k}": c for k, c in enumerate(self.along, start=1)},
            },
        }

    @classmethod
    def from_table(cls, t: Mapping[str, Any]) -> CouplingEffect:
        orders = [int(v) for v in read_floats(t.get("orders", cls.ORDERS), "orders")]
        with_orders = [int(v) for v in read_floats(t.get("with_orders", [1]), "with_orders")]
        return cls(
            str(t.get("component")),
            read_str(t, "varies_with"),
            read_floats(t.get("coefficients"), "coefficients", len(orders) * len(with_orders)),
            read_span(t.get("span_mm"), "span_mm"),
            read_span(t.get("span_with_mm"), "span_with_mm"),
            orders,
            with_orders,
            read_number(t, "offset", 0.0),
            read_floats(t.get("along", []), "along"),
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
    position, P ``period_mm``) plus optional harmonics ``a_n·cos(2πnq/P) + b_n·sin(2πnq/P)``
    (n = 2, 3, … in order: ``harmonics_um = [[a_2, b_2], [a_3, b_3], …]``), minus the value at
    the reference point."""

    cause: ClassVar[str] = "periodic"

    def __init__(
        self,
        axis: str,
        period_mm: float,
        a_cos_um: float,
        b_sin_um: float,
        harmonics_um: Sequence[Sequence[float]] = (),
    ) -> None:
        self.axis = read_axis(axis)
        if not (math.isfinite(period_mm) and period_mm > 0):
            raise ValueError(f"period_mm must be finite and > 0, got {period_mm}")
        self.period_mm = float(period_mm)
        self.a_cos_um = float(a_cos_um)
        self.b_sin_um = float(b_sin_um)
        self.harmonics_um = [tuple(read_floats(h, "harmonics_um", 2)) for h in harmonics_um]

    def shape(
        self, q_mm: FloatArray, ref_mm: float, harmonic: int = 1
    ) -> tuple[FloatArray, FloatArray]:
        """(cos, sin) of harmonic n at ``q_mm``, each minus its value at ``ref_mm``."""
        w = 2.0 * math.pi * harmonic / self.period_mm
        q = np.asarray(q_mm, dtype=float)
        return np.cos(w * q) - math.cos(w * ref_mm), np.sin(w * q) - math.sin(w * ref_mm)

    def shortest_wavelength_mm(self) -> dict[str, float]:
        """The period of the highest harmonic."""
        return {self.axis: self.period_mm / (1 + len(self.harmonics_um))}

    def modify_errors(self, ctx: EvalContext) -> None:
        k = AXIS_INDEX[self.axis]
        ref = float(ctx.reference_mm[k])
        c, s = self.shape(ctx.q_mm[:, k], ref)
        ctx.errors[:, k, k] += self.a_cos_um * c + self.b_sin_um * s
        for n, (a_n, b_n) in enumerate(self.harmonics_um, start=2):
            c, s = self.shape(ctx.q_mm[:, k], ref, n)
            ctx.errors[:, k, k] += a_n * c + b_n * s

    def to_table(self) -> dict[str, Any]:
        t: dict[str, Any] = {
            "cause": self.cause,
            "axis": self.axis,
            "period_mm": self.period_mm,
            "a_cos_um": self.a_cos_um,
            "b_sin_um": self.b_sin_um,
        }
        if self.harmonics_um:
            t["harmonics_um"] = [list(h) for h in self.harmonics_um]
        return t

    def describe(self) -> dict[str, Any]:
        params: dict[str, Any] = {
            "period_mm": self.period_mm,
            "amplitude_um": math.hypot(self.a_cos_um, self.b_sin_um),
            "a_cos_um": self.a_cos_um,
            "b_sin_um": self.b_sin_um,
        }
        for n, (a_n, b_n) in enumerate(self.harmonics_um, start=2):
            params[f"harmonic_{n}_amplitude_um"] = math.hypot(a_n, b_n)
        return {
            "cause": self.cause,
            "axis": self.axis,
            "period_mm": self.period_mm,
            "parameters": params,
        }

    @classmethod
    def from_table(cls, t: Mapping[str, Any]) -> PeriodicEffect:
        harmonics = t.get("harmonics_um", [])
        if not isinstance(harmonics, list):
            raise ValueError(f"harmonics_um must be a list of [a, b] pairs, got {harmonics!r}")
        return cls(
            read_str(t, "axis"),
            read_number(t, "period_mm"),
            read_number(t, "a_cos_um"),
            read_number(t, "b_sin_um"),
            harmonics,
        )


for _cls in (ParametricEffect, CouplingEffect, ReversalEffect, PeriodicEffect):
    register_effect(_cls.cause, _cls.from_table)
