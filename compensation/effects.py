"""Concrete effects (FORMATS.md §4 causes) that plug into :mod:`compensation.effects_base`.

Each effect is a physically meaningful term with few parameters, linear in its amplitude
parameters (the diagnosis fits them by linear least squares) and linear in the runtime signals it
declares through :meth:`Effect.signals` (so a correction grid can hold one sensitivity grid per
signal). Shapes along an axis use Legendre polynomials ``P_k(s)`` of the normalised position
``s = 2·(q − lo)/(hi − lo) − 1 ∈ [−1, 1]`` over the axis span ``[lo, hi]`` (mm), referred to the
machine's reference point (every term vanishes there, like the parametric tables).

Units: positions mm, linear errors µm, angles and squareness µrad, temperatures °C, time s.

Signals the grid/daemon must supply (besides the machine's ``T_x`` …):

* ``thermal_gradient``: ``T_top``, ``T_bottom``;
* ``scale_expansion``: ``T_<axis>``; ``workpiece_expansion``: ``T_wp``;
  ``squareness_drift``: its ``temperature`` (default ``T_air``);
* ``reversal``: ``dir_<axis>`` (+1/−1; 0 = unknown, the mean of both directions);
* ``probe_lobing``: six derived signals ``lobe<k>_c_x`` … ``lobe<k>_s_z`` computed from the probing
  direction by :func:`lobing_signals` (``nx``, ``ny``, ``nz`` are converted automatically when
  given to :meth:`Machine.volumetric_error`);
* ``thermal_lag``: no new signal: with a time signal ``t`` the effect filters ``T_x``, ``T_y``,
  ``T_z`` itself; without ``t`` the temperatures given are taken as already filtered, which is
  what a daemon does with :class:`FirstOrderLag` (one per sensor) before using the grid.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from typing import Any, ClassVar

import numpy as np
from numpy.polynomial import legendre

from .components import AXES, AXIS_INDEX, SQUARENESS, TABLE_COMPONENTS, parse_component
from .effects_base import Effect, EvalContext, FloatArray, register_effect

__all__ = [
    "CouplingEffect",
    "FirstOrderLag",
    "ParametricEffect",
    "PeriodicEffect",
    "ProbeLobingEffect",
    "ReversalEffect",
    "ScaleExpansionEffect",
    "SquarenessDriftEffect",
    "ThermalGradientEffect",
    "ThermalLagEffect",
    "WorkpieceExpansionEffect",
    "default_orders",
    "lag_filter",
    "legendre_shape",
    "lobing_signals",
]

LAGGED_SIGNALS: tuple[str, ...] = ("T_x", "T_y", "T_z")


# ----------------------------------------------------------------------------- helpers
def _axis(value: Any, what: str = "axis") -> str:
    if value not in AXES:
        raise ValueError(f"{what} must be one of x, y, z, got {value!r}")
    return str(value)


def _required_str(table: Mapping[str, Any], key: str) -> str:
    """``table[key]`` as a string; a missing (or null) key is a ValueError naming the key."""
    value = table.get(key)
    if value is None:
        raise ValueError(f"{key} is required")
    if not isinstance(value, str):
        raise ValueError(f"{key} must be a string, got {value!r}")
    return value


def _span(value: Any, what: str) -> tuple[float, float]:
    try:
        lo, hi = (float(v) for v in value)
    except (TypeError, ValueError):
        raise ValueError(f"{what} must be [lo, hi] in mm, got {value!r}") from None
    if not hi > lo:
        raise ValueError(f"{what} must have hi > lo, got {value!r}")
    return lo, hi


def _floats(value: Any, what: str, n: int | None = None) -> list[float]:
    try:
        out = [float(v) for v in value]
    except (TypeError, ValueError):
        raise ValueError(f"{what} must be a list of numbers, got {value!r}") from None
    if n is not None and len(out) != n:
        raise ValueError(f"{what} must have {n} values, got {len(out)}")
    if not all(math.isfinite(v) for v in out):
        raise ValueError(f"{what} must be finite, got {value!r}")
    return out


def _number(table: Mapping[str, Any], key: str, default: float | None = None) -> float:
    if key not in table:
        if default is None:
            raise ValueError(f"missing key {key!r}")
        return default
    try:
        v = float(table[key])
    except (TypeError, ValueError):
        raise ValueError(f"{key} must be a number, got {table[key]!r}") from None
    if not math.isfinite(v):
        raise ValueError(f"{key} must be finite, got {v}")
    return v


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


def _add_component(ctx: EvalContext, component: str, value: FloatArray) -> None:
    if component in SQUARENESS:
        ctx.squareness_urad[:, SQUARENESS.index(component)] += value
    else:
        c = parse_component(component)
        ctx.errors[:, AXIS_INDEX[c.axis], c.slot] += value


def _signal(ctx: EvalContext, name: str, default: float) -> FloatArray:
    v = ctx.signals.get(name)
    return np.full(ctx.n, default) if v is None else np.asarray(v, dtype=float)


class _TemperatureEffect(Effect):
    """Base of effects driven by a temperature: ``reference_C`` is the neutral value their
    signals report (the machine's thermal reference, stored in the table; default 20 °C)."""

    reference_C: float = 20.0

    def _with_reference(self, t: Mapping[str, Any]) -> Any:
        self.reference_C = _number(t, "reference_C", 20.0)
        return self

    def _table(self, **items: Any) -> dict[str, Any]:
        return {"cause": self.cause, **items, "reference_C": self.reference_C}


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
            _add_component(ctx, self.component, np.full(ctx.n, self.coefficients[0]))
            return
        k = AXIS_INDEX[self.component[-1]]
        _add_component(ctx, self.component, self.value(ctx.q_mm[:, k], float(ctx.reference_mm[k])))

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
        orders = [int(o) for o in _floats(t.get("orders", default_orders(comp)), "orders")]
        return cls(
            comp,
            _floats(t.get("coefficients"), "coefficients", len(orders)),
            _span(t.get("span_mm", (0.0, 1.0)), "span_mm"),
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
        self.varies_with = _axis(varies_with, "varies_with")
        if self.varies_with == c.axis:
            raise ValueError(f"coupling: {component} cannot vary with its own axis")
        self.coefficients = _floats(coefficients, "coefficients", len(self.ORDERS))
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
        _add_component(ctx, self.component, sb * shape)

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
            _required_str(t, "varies_with"),
            _floats(t.get("coefficients"), "coefficients", len(cls.ORDERS)),
            _span(t.get("span_mm"), "span_mm"),
            _span(t.get("span_with_mm"), "span_with_mm"),
        )


# ----------------------------------------------------------------------------- thermal
class ThermalGradientEffect(_TemperatureEffect):
    """An axis bends with the temperature difference ``ΔT = T_top − T_bottom``: uniform curvature
    ``κ = g·ΔT`` (g in µrad/(m·°C)) in the vertical plane (z: in the x-z plane), i.e. an angular
    error ``g·ΔT·u`` and the consistent straightness ``∓g·ΔT·u²/2`` (u in m from the reference)."""

    cause: ClassVar[str] = "thermal_gradient"
    #: axis → (angular slot, straightness slot, sign of the straightness)
    _PLANE: ClassVar[dict[str, tuple[int, int, float]]] = {
        "x": (4, 2, -1.0),  # pitch ey_x, dz_x = −∫ey
        "y": (3, 2, 1.0),  # ex_y, dz_y = +∫ex
        "z": (4, 0, 1.0),  # ey_z, dx_z = +∫ey
    }

    def __init__(self, axis: str, curvature_urad_per_m_C: float) -> None:
        self.axis = _axis(axis)
        self.curvature = float(curvature_urad_per_m_C)

    def signals(self) -> dict[str, float]:
        return {"T_top": self.reference_C, "T_bottom": self.reference_C}

    def modify_errors(self, ctx: EvalContext) -> None:
        k = AXIS_INDEX[self.axis]
        dt = _signal(ctx, "T_top", ctx.reference_C) - _signal(ctx, "T_bottom", ctx.reference_C)
        u_m = ctx.u_mm[:, k] / 1000.0
        ang, lin, sign = self._PLANE[self.axis]
        ctx.errors[:, k, ang] += self.curvature * dt * u_m
        ctx.errors[:, k, lin] += sign * self.curvature * dt * u_m**2 / 2.0

    def to_table(self) -> dict[str, Any]:
        return self._table(axis=self.axis, curvature_urad_per_m_C=self.curvature)

    def describe(self) -> dict[str, Any]:
        return {
            "cause": self.cause,
            "axis": self.axis,
            "parameters": {"curvature_urad_per_m_C": self.curvature},
        }

    @classmethod
    def from_table(cls, t: Mapping[str, Any]) -> ThermalGradientEffect:
        return cls(_required_str(t, "axis"), _number(t, "curvature_urad_per_m_C"))._with_reference(
            t
        )


def lag_filter(t_s: FloatArray, temp_C: FloatArray, time_constant_s: float) -> FloatArray:
    """First-order lag ``τ·dy/dt = T − y`` of samples ``temp_C`` at times ``t_s`` (any order),
    exact for a piecewise-linear input, starting in equilibrium (``y_0 = T_0``)."""
    t = np.asarray(t_s, dtype=float)
    x = np.asarray(temp_C, dtype=float)
    order = np.argsort(t, kind="stable")
    ts, xs = t[order], x[order]
    h = np.diff(ts)
    a = np.exp(-h / time_constant_s)
    with np.errstate(divide="ignore", invalid="ignore"):
        ramp = np.where(h > 0, 1.0 - time_constant_s / h * (1.0 - a), 0.0)
    y = np.empty_like(xs)
    if len(xs):
        y[0] = xs[0]
    for i in range(1, len(xs)):
        y[i] = a[i - 1] * y[i - 1] + (1 - a[i - 1]) * xs[i - 1] + (xs[i] - xs[i - 1]) * ramp[i - 1]
    out = np.empty_like(y)
    out[order] = y
    return out


class FirstOrderLag:
    """Streaming form of :func:`lag_filter` for a daemon: ``update(t_s, temp_C)`` → lagged °C."""

    def __init__(self, time_constant_s: float) -> None:
        self.time_constant_s = float(time_constant_s)
        self._last: tuple[float, float, float] | None = None  # t, input, output

    def update(self, t_s: float, temp_C: float) -> float:
        if self._last is None:
            self._last = (t_s, temp_C, temp_C)
            return temp_C
        t0, x0, y0 = self._last
        h = t_s - t0
        if h <= 0:
            return y0
        a = math.exp(-h / self.time_constant_s)
        y = a * y0 + (1 - a) * x0 + (temp_C - x0) * (1.0 - self.time_constant_s / h * (1.0 - a))
        self._last = (t_s, temp_C, y)
        return y

    def value_at(self, t_s: float) -> float:
        """The lagged value at ``t_s`` (s) without a new sample: the input held at its last
        value since then (°C). Before any sample: NaN."""
        if self._last is None:
            return math.nan
        t0, x0, y0 = self._last
        h = t_s - t0
        if h <= 0:
            return y0
        return x0 + (y0 - x0) * math.exp(-h / self.time_constant_s)


class ThermalLagEffect(Effect):
    """The structure's effective temperature follows the measured scale temperatures with a
    first-order lag: ``T_eff = T + w·(lag_τ(T) − T)`` for ``T_x``, ``T_y``, ``T_z`` (needs the
    time signal ``t``; without it the temperatures are taken as already filtered)."""

    cause: ClassVar[str] = "thermal_lag"

    def __init__(self, time_constant_s: float, fraction: float = 1.0) -> None:
        if not time_constant_s > 0:
            raise ValueError(f"time_constant_s must be > 0, got {time_constant_s}")
        self.time_constant_s = float(time_constant_s)
        self.fraction = float(fraction)

    def transform_signals(self, ctx: EvalContext) -> None:
        t = ctx.signals.get("t")
        if t is None:
            return
        for name in LAGGED_SIGNALS:
            temp = ctx.signals.get(name)
            if temp is not None:
                lagged = lag_filter(t, temp, self.time_constant_s)
                ctx.signals[name] = temp + self.fraction * (lagged - temp)

    def to_table(self) -> dict[str, Any]:
        return {
            "cause": self.cause,
            "time_constant_s": self.time_constant_s,
            "fraction": self.fraction,
        }

    def describe(self) -> dict[str, Any]:
        return {
            "cause": self.cause,
            "time_constant_s": self.time_constant_s,
            "parameters": {"time_constant_s": self.time_constant_s, "fraction": self.fraction},
        }

    @classmethod
    def from_table(cls, t: Mapping[str, Any]) -> ThermalLagEffect:
        return cls(_number(t, "time_constant_s"), _number(t, "fraction", 1.0))


class ScaleExpansionEffect(_TemperatureEffect):
    """An axis' effective expansion coefficient is off by ``delta`` µm/(m·°C):
    ``delta·(T_axis − T_ref)·u/1000`` µm added to that axis' error component."""

    cause: ClassVar[str] = "scale_expansion"

    def __init__(self, axis: str, delta_expansion: float) -> None:
        self.axis = _axis(axis)
        self.delta = float(delta_expansion)

    def signals(self) -> dict[str, float]:
        return {f"T_{self.axis}": self.reference_C}

    def add_direct(self, ctx: EvalContext) -> None:
        k = AXIS_INDEX[self.axis]
        dt = _signal(ctx, f"T_{self.axis}", ctx.reference_C) - ctx.reference_C
        ctx.direct_um[:, k] += self.delta * dt * ctx.u_mm[:, k] / 1000.0

    def to_table(self) -> dict[str, Any]:
        return self._table(axis=self.axis, delta_expansion=self.delta)

    def describe(self) -> dict[str, Any]:
        return {
            "cause": self.cause,
            "axis": self.axis,
            "parameters": {"delta_expansion_um_per_m_C": self.delta},
        }

    @classmethod
    def from_table(cls, t: Mapping[str, Any]) -> ScaleExpansionEffect:
        return cls(_required_str(t, "axis"), _number(t, "delta_expansion"))._with_reference(t)


class WorkpieceExpansionEffect(_TemperatureEffect):
    """Workpiece expansion about its fixture point wrong or missing: ``−delta·(T_wp − T_ref)·
    (q − fixture)/1000`` µm (delta µm/(m·°C), added to the machine's own workpiece term)."""

    cause: ClassVar[str] = "workpiece_expansion"

    def __init__(self, delta_expansion: float, fixture_mm: Sequence[float]) -> None:
        self.delta = float(delta_expansion)
        self.fixture_mm = _floats(fixture_mm, "fixture_mm", 3)

    def signals(self) -> dict[str, float]:
        return {"T_wp": self.reference_C}

    def add_direct(self, ctx: EvalContext) -> None:
        dt = _signal(ctx, "T_wp", ctx.reference_C) - ctx.reference_C
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
            _number(t, "delta_expansion"), t.get("fixture_mm", (0.0, 0.0, 0.0))
        )._with_reference(t)


class SquarenessDriftEffect(_TemperatureEffect):
    """A squareness changes with temperature: ``+k·(T − T_ref)`` µrad (k µrad/°C, T the signal
    named ``temperature``, default ``T_air``)."""

    cause: ClassVar[str] = "squareness_drift"

    def __init__(self, component: str, urad_per_C: float, temperature: str = "T_air") -> None:
        if component not in SQUARENESS:
            raise ValueError(f"component must be one of alpha, beta1, beta2, got {component!r}")
        self.component = component
        self.urad_per_C = float(urad_per_C)
        self.temperature = str(temperature)

    def signals(self) -> dict[str, float]:
        return {self.temperature: self.reference_C}

    def modify_errors(self, ctx: EvalContext) -> None:
        dt = _signal(ctx, self.temperature, ctx.reference_C) - ctx.reference_C
        _add_component(ctx, self.component, self.urad_per_C * dt)

    def to_table(self) -> dict[str, Any]:
        return self._table(
            component=self.component, urad_per_C=self.urad_per_C, temperature=self.temperature
        )

    def describe(self) -> dict[str, Any]:
        return {
            "cause": self.cause,
            "component": self.component,
            "parameters": {"urad_per_C": self.urad_per_C, "temperature": self.temperature},
        }

    @classmethod
    def from_table(cls, t: Mapping[str, Any]) -> SquarenessDriftEffect:
        return cls(
            str(t.get("component")), _number(t, "urad_per_C"), str(t.get("temperature", "T_air"))
        )._with_reference(t)


# ----------------------------------------------------------------------------- direction
class ReversalEffect(Effect):
    """Positional error that depends on the direction of travel (backlash, hysteresis):
    ``dir·(h0 + h1·P1(s))`` µm added to the axis' positional error, ``dir`` = ±1 the last
    direction of travel (0 = unknown); the reversal value (− minus +) is ``−2·h``."""

    cause: ClassVar[str] = "reversal"

    def __init__(self, axis: str, half_step_um: Sequence[float], span_mm: tuple[float, float]):
        self.axis = _axis(axis)
        self.half_step_um = _floats(half_step_um, "half_step_um", 2)
        self.span_mm = span_mm

    def signals(self) -> dict[str, float]:
        return {f"dir_{self.axis}": 0.0}

    def modify_errors(self, ctx: EvalContext) -> None:
        k = AXIS_INDEX[self.axis]
        d = _signal(ctx, f"dir_{self.axis}", 0.0)
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
            _required_str(t, "axis"),
            _floats(t.get("half_step_um"), "half_step_um", 2),
            _span(t.get("span_mm"), "span_mm"),
        )


class PeriodicEffect(Effect):
    """Cyclic positional error along an axis: ``a·cos(2πq/P) + b·sin(2πq/P)`` µm (q the indicated
    position, P ``period_mm``), minus its value at the reference point."""

    cause: ClassVar[str] = "periodic"

    def __init__(self, axis: str, period_mm: float, a_cos_um: float, b_sin_um: float) -> None:
        self.axis = _axis(axis)
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
            _required_str(t, "axis"),
            _number(t, "period_mm"),
            _number(t, "a_cos_um"),
            _number(t, "b_sin_um"),
        )


# ----------------------------------------------------------------------------- probe
def lobing_signals(nx: Any, ny: Any, nz: Any, lobes: int = 3) -> dict[str, FloatArray]:
    """Derived, linear signals of an n-lobe probe term from the probing direction (unit vector).

    With ``C + iS = (nx + i·ny)^lobes`` (= ρⁿ·e^{inφ}: the azimuth harmonic, fading for vertical
    probing), returns ``lobe<n>_c_<i> = n_i·C`` and ``lobe<n>_s_<i> = n_i·S`` for i in x, y, z.
    """
    n = [np.asarray(v, dtype=float) for v in (nx, ny, nz)]
    z = (n[0] + 1j * n[1]) ** int(lobes)
    out: dict[str, FloatArray] = {}
    for i, axis in enumerate(AXES):
        out[f"lobe{lobes}_c_{axis}"] = n[i] * z.real
        out[f"lobe{lobes}_s_{axis}"] = n[i] * z.imag
    return out


class ProbeLobingEffect(Effect):
    """Error along the probing direction n varying with its azimuth φ:
    ``n·ρⁿ·(a·cos nφ + b·sin nφ)`` µm, n = ``lobes`` (3 for a kinematic 3-lobe probe)."""

    cause: ClassVar[str] = "probe_lobing"

    def __init__(self, lobes: int, a_cos_um: float, b_sin_um: float) -> None:
        if int(lobes) < 1:
            raise ValueError(f"lobes must be ≥ 1, got {lobes}")
        self.lobes = int(lobes)
        self.a_cos_um = float(a_cos_um)
        self.b_sin_um = float(b_sin_um)

    def signals(self) -> dict[str, float]:
        return {f"lobe{self.lobes}_{p}_{a}": 0.0 for p in "cs" for a in AXES}

    def transform_signals(self, ctx: EvalContext) -> None:
        if f"lobe{self.lobes}_c_x" in ctx.signals:
            return
        if all(k in ctx.signals for k in ("nx", "ny", "nz")):
            ctx.signals.update(
                lobing_signals(ctx.signals["nx"], ctx.signals["ny"], ctx.signals["nz"], self.lobes)
            )

    def add_direct(self, ctx: EvalContext) -> None:
        for i, axis in enumerate(AXES):
            c = _signal(ctx, f"lobe{self.lobes}_c_{axis}", 0.0)
            s = _signal(ctx, f"lobe{self.lobes}_s_{axis}", 0.0)
            ctx.direct_um[:, i] += self.a_cos_um * c + self.b_sin_um * s

    def to_table(self) -> dict[str, Any]:
        return {
            "cause": self.cause,
            "lobes": self.lobes,
            "a_cos_um": self.a_cos_um,
            "b_sin_um": self.b_sin_um,
        }

    def describe(self) -> dict[str, Any]:
        return {
            "cause": self.cause,
            "lobes": self.lobes,
            "parameters": {
                "amplitude_um": math.hypot(self.a_cos_um, self.b_sin_um),
                "a_cos_um": self.a_cos_um,
                "b_sin_um": self.b_sin_um,
            },
        }

    @classmethod
    def from_table(cls, t: Mapping[str, Any]) -> ProbeLobingEffect:
        return cls(int(_number(t, "lobes", 3.0)), _number(t, "a_cos_um"), _number(t, "b_sin_um"))


EFFECT_CLASSES: dict[str, Any] = {
    cls.cause: cls
    for cls in (
        ParametricEffect,
        CouplingEffect,
        ThermalGradientEffect,
        ThermalLagEffect,
        ScaleExpansionEffect,
        WorkpieceExpansionEffect,
        SquarenessDriftEffect,
        ReversalEffect,
        PeriodicEffect,
        ProbeLobingEffect,
    )
}

for _cause, _cls in EFFECT_CLASSES.items():
    register_effect(_cause, _cls.from_table)
