"""Structural distortion with temperature (docs/formats.md §4 ``thermal_gradient``,
``squareness_drift``): axes bending with the top–bottom temperature difference, a squareness
drifting with a temperature. Temperatures °C by role (:mod:`.roles`); angles µrad.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from typing import Any, ClassVar

import numpy as np

from ..effects.base import (
    EvalContext,
    add_to_component,
    read_axis,
    read_floats,
    read_number,
    read_str,
    register_effect,
    signal_or,
)
from ..parametric_errors import AXIS_INDEX, SQUARENESS
from .expansion import TemperatureEffect
from .lag import FIRST_ORDER_LAG, SignalFilter, lag_filter
from .roles import AIR, BOTTOM, TOP

__all__ = ["SquarenessDriftEffect", "ThermalGradientEffect"]


class ThermalGradientEffect(TemperatureEffect):
    """An axis bends with the temperature difference ``ΔT = T_top − T_bottom``: uniform curvature
    ``κ = g·ΔT`` (g in µrad/(m·°C)) in the vertical plane (z: in the x-z plane). The carriage
    tilts with the local slope of the guideway: angular error ``ΔT·(g·u + h)`` and the consistent
    straightness ``∓ΔT·(g·u²/2 + h·u)`` (u in m from the reference point), where ``h``
    (µrad/°C, ``tilt_urad_per_C``) is the slope at the reference point. It encodes the boundary
    condition: a guideway simply supported at both ends of its travel bows symmetrically
    (``h = g·(u_ref − u_mid)``), one clamped at an end is a cantilever (``h = g·(u_ref −
    u_end)``), ``h = 0`` is a bend about the reference point. A scale that sits above or below
    the line about which the carriage tilts reads the tilt as a positional error too (Abbe offset
    of the scale): ``ΔT·(a·u + b)`` µm on the axis' positional error (``a`` µm/(m·°C),
    ``positional_um_per_m_C``; ``b`` µm/°C, ``positional_um_per_C``; both ∝ that height).
    A gradient that is not uniform along the beam adds ``c·u²`` to the tilt and ``∓c·u³/3`` to
    the straightness (``c`` µrad/(m²·°C), ``taper_urad_per_m2_C``); one confined to part of the
    beam (a lamp above one end, a local draught) has a curvature that varies further along it:
    ``Σ_n e_n·u^n`` (n = 3, 4, …) more on the tilt and ``∓Σ e_n·u^{n+1}/(n+1)`` on the
    straightness (``tilt_poly_urad_per_C`` = [e_3, e_4, …], µrad/(mⁿ·°C)).
    For an axis that moves the workpiece (a table) the same relation holds in the parametric
    components: its pads run over the base rail the opposite way to the axis coordinate, and the
    chain applies a table's errors with the opposite sign — the two cancel.

    ``offset_um_per_C`` (µm/°C): the guideway's deflection at the reference point itself (zero
    only when a support sits there): ``ΔT·offset`` µm added to the straightness — a table error
    is zero at the reference by calibration, a bend that changes with ΔT cannot be."""

    cause: ClassVar[str] = "thermal_gradient"
    #: axis → (angular slot, straightness slot, sign of the straightness)
    _PLANE: ClassVar[dict[str, tuple[int, int, float]]] = {
        "x": (4, 2, -1.0),  # pitch ey_x, dz_x = −∫ey
        "y": (3, 2, 1.0),  # ex_y, dz_y = +∫ex
        "z": (4, 0, 1.0),  # ey_z, dx_z = +∫ey
    }

    def __init__(
        self,
        axis: str,
        curvature_urad_per_m_C: float,
        tilt_urad_per_C: float = 0.0,
        positional_um_per_m_C: float = 0.0,
        positional_um_per_C: float = 0.0,
        taper_urad_per_m2_C: float = 0.0,
        offset_um_per_C: float = 0.0,
        tilt_poly_urad_per_C: Sequence[float] = (),
    ) -> None:
        self.offset = float(offset_um_per_C)
        self.tilt_poly = [float(v) for v in tilt_poly_urad_per_C]
        if not all(np.isfinite(v) for v in self.tilt_poly):
            raise ValueError(f"tilt_poly_urad_per_C must be finite, got {self.tilt_poly}")
        self.taper = float(taper_urad_per_m2_C)
        self.axis = read_axis(axis)
        self.curvature = float(curvature_urad_per_m_C)
        self.tilt = float(tilt_urad_per_C)
        self.positional = (float(positional_um_per_m_C), float(positional_um_per_C))

    def signals(self) -> dict[str, float]:
        return {TOP: self.reference_C, BOTTOM: self.reference_C}

    def modify_errors(self, ctx: EvalContext) -> None:
        k = AXIS_INDEX[self.axis]
        dt = signal_or(ctx, TOP, ctx.reference_C) - signal_or(ctx, BOTTOM, ctx.reference_C)
        u_m = ctx.u_mm[:, k] / 1000.0
        ang, lin, sign = self._PLANE[self.axis]
        tilt = self.curvature * u_m + self.tilt + self.taper * u_m**2
        bend = self.curvature * u_m**2 / 2.0 + self.tilt * u_m + self.taper * u_m**3 / 3.0
        for n, e in enumerate(self.tilt_poly, start=3):
            tilt = tilt + e * u_m**n
            bend = bend + e * u_m ** (n + 1) / (n + 1)
        ctx.errors[:, k, ang] += dt * tilt
        ctx.errors[:, k, lin] += sign * dt * bend + dt * self.offset
        ctx.errors[:, k, k] += dt * (self.positional[0] * u_m + self.positional[1])

    def to_table(self) -> dict[str, Any]:
        return self._table(
            axis=self.axis,
            curvature_urad_per_m_C=self.curvature,
            tilt_urad_per_C=self.tilt,
            positional_um_per_m_C=self.positional[0],
            positional_um_per_C=self.positional[1],
            taper_urad_per_m2_C=self.taper,
            offset_um_per_C=self.offset,
            **({"tilt_poly_urad_per_C": list(self.tilt_poly)} if self.tilt_poly else {}),
        )

    def describe(self) -> dict[str, Any]:
        params: dict[str, Any] = {
            "curvature_urad_per_m_C": self.curvature,
            "tilt_urad_per_C": self.tilt,
            "positional_um_per_m_C": self.positional[0],
            "positional_um_per_C": self.positional[1],
            "taper_urad_per_m2_C": self.taper,
            "offset_um_per_C": self.offset,
        }
        if self.tilt_poly:
            params["tilt_poly_urad_per_C"] = list(self.tilt_poly)
        return {"cause": self.cause, "axis": self.axis, "parameters": params}

    @classmethod
    def from_table(cls, t: Mapping[str, Any]) -> ThermalGradientEffect:
        return cls(
            read_str(t, "axis"),
            read_number(t, "curvature_urad_per_m_C"),
            read_number(t, "tilt_urad_per_C", 0.0),
            read_number(t, "positional_um_per_m_C", 0.0),
            read_number(t, "positional_um_per_C", 0.0),
            read_number(t, "taper_urad_per_m2_C", 0.0),
            read_number(t, "offset_um_per_C", 0.0),
            read_floats(t.get("tilt_poly_urad_per_C", []), "tilt_poly_urad_per_C"),
        )._with_reference(t)


class SquarenessDriftEffect(TemperatureEffect):
    """A squareness changes with temperature: ``+k·(T − T_ref)`` µrad (k µrad/°C, T the signal
    named ``temperature``, default ``T_air``).

    With ``time_constant_s`` τ > 0 the structure follows the sensor through a first-order lag
    (``τ·dT_s/dt = T − T_s``): evaluated on a time series (signal ``t`` present), the signal is
    replaced by its lagged value for every effect (:meth:`transform_signals`, as the thermal
    lag does for the scale temperatures); at run time a grid carries the same filter
    (:meth:`signal_filter`), which the daemon applies to the raw temperature."""

    cause: ClassVar[str] = "squareness_drift"

    def __init__(
        self,
        component: str,
        urad_per_C: float,
        temperature: str = AIR,
        time_constant_s: float = 0.0,
    ) -> None:
        if component not in SQUARENESS:
            raise ValueError(f"component must be one of alpha, beta1, beta2, got {component!r}")
        if not time_constant_s >= 0.0:
            raise ValueError(f"time_constant_s must be ≥ 0, got {time_constant_s}")
        self.component = component
        self.urad_per_C = float(urad_per_C)
        self.temperature = str(temperature)
        self.time_constant_s = float(time_constant_s)

    def signals(self) -> dict[str, float]:
        return {self.temperature: self.reference_C}

    def transform_signals(self, ctx: EvalContext) -> None:
        if self.time_constant_s <= 0.0:
            return
        t = ctx.signals.get("t")
        temp = ctx.signals.get(self.temperature)
        if t is None or temp is None or np.ndim(temp) == 0 or np.size(temp) < 2:
            return  # a single sample: taken as already filtered (the grid's runtime contract)
        ctx.signals[self.temperature] = lag_filter(t, temp, self.time_constant_s)

    def modify_errors(self, ctx: EvalContext) -> None:
        dt = signal_or(ctx, self.temperature, ctx.reference_C) - ctx.reference_C
        add_to_component(ctx, self.component, self.urad_per_C * dt)

    def signal_filter(self) -> SignalFilter | None:
        """The lag a runtime user applies to the raw temperature (None without a lag)."""
        if self.time_constant_s <= 0.0:
            return None
        return SignalFilter(FIRST_ORDER_LAG, (self.temperature,), self.time_constant_s, 1.0)

    def to_table(self) -> dict[str, Any]:
        extra = {"time_constant_s": self.time_constant_s} if self.time_constant_s > 0 else {}
        return self._table(
            component=self.component,
            urad_per_C=self.urad_per_C,
            temperature=self.temperature,
            **extra,
        )

    def describe(self) -> dict[str, Any]:
        params: dict[str, Any] = {"urad_per_C": self.urad_per_C, "temperature": self.temperature}
        if self.time_constant_s > 0:
            params["time_constant_s"] = self.time_constant_s
        return {"cause": self.cause, "component": self.component, "parameters": params}

    @classmethod
    def from_table(cls, t: Mapping[str, Any]) -> SquarenessDriftEffect:
        return cls(
            str(t.get("component")),
            read_number(t, "urad_per_C"),
            str(t.get("temperature", AIR)),
            read_number(t, "time_constant_s", 0.0),
        )._with_reference(t)


for _cls in (ThermalGradientEffect, SquarenessDriftEffect):
    register_effect(_cls.cause, _cls.from_table)
