"""Effects on the parametric model itself (docs/formats.md §4 causes ``parametric``, ``coupling``,
``reversal``): smooth corrections of the 21 errors, their dependence on another axis and the
direction of travel (cyclic errors along an axis: :mod:`.periodic`).

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
from collections.abc import Callable, Mapping, Sequence
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
    "ReversalEffect",
    "default_orders",
    "legendre_shape",
    "normalised",
    "slope_of",
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


#: ``EvalContext.extras`` key of a memo of the Legendre shapes evaluated at the context's points:
#: a caller evaluating several effects at the same positions (the diagnosis builds a design one
#: unit amplitude at a time) shares one dict between their contexts, so each shape is evaluated
#: once per axis position vector instead of once per effect. The memo's arrays are read-only
#: by contract (every user adds them into arrays of its own).
SHAPES = "legendre_shapes"


def shape_at(ctx: EvalContext, axis: int, span_mm: tuple[float, float], order: int) -> FloatArray:
    """``P_k(s) − P_k(s_ref)`` along ``axis`` (index) at the points of ``ctx`` (1 for order 0),
    the reference taken from ``ctx.reference_mm``; memoised in ``ctx.extras[SHAPES]`` when the
    caller put a dict there (same values as :func:`legendre_shape`, evaluated once)."""
    ref_mm = float(ctx.reference_mm[axis])
    return _memo(
        ctx,
        ("shape", axis, span_mm, order),
        lambda: _shape_or_one(ctx.q_mm[:, axis], ref_mm, span_mm, order),
    )


def _memo(
    ctx: EvalContext,
    key: tuple[str, int, tuple[float, float], int],
    compute: Callable[[], FloatArray],
) -> FloatArray:
    """``compute()``, memoised under ``key`` (kind, axis, span, order) and the axis' reference
    in ``ctx.extras[SHAPES]`` when there is such a dict (computed afresh otherwise)."""
    memo = ctx.extras.get(SHAPES)
    if memo is None:
        return compute()
    kind, axis, span_mm, order = key
    full = (kind, axis, float(ctx.reference_mm[axis]), float(span_mm[0]), float(span_mm[1]), order)
    if full not in memo:
        memo[full] = compute()
    return memo[full]  # type: ignore[no-any-return]


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
        out = np.zeros(ctx.n)  # as value(), with the shapes from the context's memo
        for order, c in zip(self.orders, self.coefficients, strict=True):
            out = out + (c if order == 0 else c * shape_at(ctx, k, self.span_mm, order))
        add_to_component(ctx, self.component, out)

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
        with_slope: bool = False,
    ) -> None:
        c = parse_component(component)
        self.slope = slope_of(c.name) if with_slope else None
        if with_slope and self.slope is None:
            raise ValueError(f"coupling: with_slope needs a straightness, got {component!r}")
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
            total += c * shape_at(ctx, a, self.span_mm, k)
        i = 0
        for j in self.with_orders:
            sb = shape_at(ctx, b, self.span_with_mm, j)
            for k in self.orders:
                total += self.coefficients[i] * sb * shape_at(ctx, a, self.span_mm, k)
                i += 1
        add_to_component(ctx, self.component, total)
        if self.slope is not None:
            angular, sign = self.slope
            add_to_component(ctx, angular, sign * self._slope_urad(ctx, a, b))

    def _slope_urad(self, ctx: EvalContext, a: int, b: int) -> FloatArray:
        """d(straightness)/d(q_a) in µrad (µm/mm · 1000) at the context's points."""
        lo, hi = self.span_mm
        scale = 2.0 / (hi - lo) * 1000.0

        def slope(k: int) -> FloatArray:
            if k == 0:
                return np.zeros(ctx.n)
            c = np.zeros(k + 1)
            c[k] = 1.0
            s = normalised(ctx.q_mm[:, a], self.span_mm)
            return np.asarray(legendre.legval(s, legendre.legder(c)), dtype=float) * scale

        def dshape(k: int) -> FloatArray:
            return _memo(ctx, ("slope", a, self.span_mm, k), lambda: slope(k))

        total = np.zeros(ctx.n)
        for k, c in enumerate(self.along, start=1):
            total += c * dshape(k)
        i = 0
        for j in self.with_orders:
            sb = shape_at(ctx, b, self.span_with_mm, j)
            for k in self.orders:
                total += self.coefficients[i] * sb * dshape(k)
                i += 1
        return total

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
            **({"with_slope": True} if self.slope is not None else {}),
        }

    def describe(self) -> dict[str, Any]:
        params: dict[str, Any] = {
            **dict(zip(self._names(), self.coefficients, strict=True)),
            "offset_at_reference": self.offset,
            **{f"along_{k}": c for k, c in enumerate(self.along, start=1)},
        }
        if self.slope is not None:
            params["carriage_follows_slope"] = self.slope[0]
        return {
            "cause": self.cause,
            "component": self.component,
            "varies_with": self.varies_with,
            "parameters": params,
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
            bool(t.get("with_slope", False)),
        )


def slope_of(straightness: str) -> tuple[str, float] | None:
    """The angular error a carriage gets from the slope of its guideway's straightness, and its
    sign: a carriage riding a rail bent by w (µm) in direction r along axis a tilts about the
    third axis c by ±dw/da — ``+`` when a → r → c is cyclic (x→y→z), ``−`` otherwise
    (``dz_x`` → ``ey_x = −dw/dx``, ``dz_y`` → ``ex_y = +dw/dy``, ``dx_z`` → ``ey_z = +dw/dz``,
    as the thermal bend of docs/formats.md §1.9). None for a positional or angular component."""
    c = parse_component(straightness)
    if not c.is_straightness:
        return None
    a, r = straightness[-1], straightness[1]
    third = next(x for x in "xyz" if x not in (a, r))
    cyclic = "xyzxy".find(a + r) >= 0
    return f"e{third}_{a}", 1.0 if cyclic else -1.0


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


for _cls in (ParametricEffect, CouplingEffect, ReversalEffect):
    register_effect(_cls.cause, _cls.from_table)
