"""The thermal lag: the structure follows the measured temperatures with a first-order lag
(docs/formats.md §4 ``thermal_lag``), the filter itself, and the signal-filter contract by which a
correction grid tells its runtime user (the daemon) to apply that filter.

With a time signal ``t`` (s) the effect filters the scale temperatures itself; without ``t`` the
temperatures given are taken as already filtered, which is what a daemon does with
:class:`FirstOrderLag` (one per sensor) before using the grid, as the grid's
:class:`SignalFilter` list says. Temperatures °C, time s.
"""

from __future__ import annotations

import math
from collections.abc import Iterable, Mapping
from dataclasses import dataclass
from typing import Any, ClassVar

import numpy as np
from numpy.typing import NDArray

from ..effects.base import Effect, EvalContext, read_number, register_effect
from .roles import LAGGED_ROLES

__all__ = [
    "FIRST_ORDER_LAG",
    "FirstOrderLag",
    "SignalFilter",
    "ThermalLagEffect",
    "lag_filter",
    "signal_filters",
]

FloatArray = NDArray[np.float64]

#: The ``kind`` of a :class:`SignalFilter` that is a first-order lag.
FIRST_ORDER_LAG = "first_order_lag"


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
        # y_i = a_i·y_{i−1} + b_i, solved for all i at once by a parallel prefix scan over the
        # affine maps y ↦ a·y + b (log₂ n vector steps; products of a ≤ 1 never overflow)
        b = (1 - a) * xs[:-1] + np.diff(xs) * ramp
        a = a.copy()
        shift = 1
        while shift < len(a):
            b[shift:] = b[shift:] + a[shift:] * b[:-shift]
            a[shift:] = a[shift:] * a[:-shift]
            shift *= 2
        y[1:] = a * xs[0] + b
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
        for name in LAGGED_ROLES:
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
        return cls(read_number(t, "time_constant_s"), read_number(t, "fraction", 1.0))

    def signal_filter(self) -> SignalFilter:
        """The filter a runtime user must apply to the raw temperatures for a grid of this model."""
        return SignalFilter(FIRST_ORDER_LAG, LAGGED_ROLES, self.time_constant_s, self.fraction)


@dataclass(frozen=True, slots=True)
class SignalFilter:
    """A filter a runtime user must apply to raw signals before correcting with a grid.

    ``kind`` :data:`FIRST_ORDER_LAG`: feed ``T + fraction·(lag_τ(T) − T)`` for each role in
    ``signals``, the lag a first-order filter over time with ``time_constant_s`` τ (s)
    (:class:`FirstOrderLag`); the grid's sensitivities are with respect to those effective
    temperatures. In the grid file header a filter is the dict of :meth:`to_header`.
    """

    kind: str
    signals: tuple[str, ...]
    time_constant_s: float
    fraction: float = 1.0

    def effective(self, temp_C: float, lagged_C: float) -> float:
        """The temperature to feed the grid (°C) from the raw and the lagged one."""
        return temp_C + self.fraction * (lagged_C - temp_C)

    def to_header(self) -> dict[str, Any]:
        """The grid-file header form (``kind``, ``signals``, ``time_constant_s``, ``fraction``)."""
        return {
            "kind": self.kind,
            "signals": list(self.signals),
            "time_constant_s": self.time_constant_s,
            "fraction": self.fraction,
        }

    @classmethod
    def from_header(cls, spec: Mapping[str, Any]) -> SignalFilter:
        """Read the header form; ValueError/KeyError/TypeError when it is malformed."""
        return cls(
            str(spec["kind"]),
            tuple(str(s) for s in spec.get("signals", ())),
            float(spec["time_constant_s"]),
            float(spec.get("fraction", 1.0)),
        )


def signal_filters(effects: Iterable[Any]) -> list[SignalFilter]:
    """The runtime signal filters a model's effects require (a thermal lag's, a lagged
    squareness drift's). ValueError when two effects would filter one signal differently: a
    grid has one value per signal, so the model cannot be carried to run time as it stands."""
    out: list[SignalFilter] = []
    seen: dict[str, SignalFilter] = {}
    for e in effects:
        make = getattr(e, "signal_filter", None)
        spec = make() if callable(make) else None
        if spec is None:
            continue
        for role in spec.signals:
            other = seen.get(role)
            if other is not None and other != spec:
                raise ValueError(
                    f"two effects filter {role} differently (time constants "
                    f"{other.time_constant_s:g} s and {spec.time_constant_s:g} s): a grid "
                    "carries one value per signal"
                )
            seen[role] = spec
        if spec not in out:
            out.append(spec)
    return out


register_effect(ThermalLagEffect.cause, ThermalLagEffect.from_table)
