"""thermal: every thermal term of the model, in one place.

* :mod:`.roles` — the temperature role names (``T_x`` … ``T_air``), defined once;
* :mod:`.expansion` — the machine's scale and workpiece expansion (:class:`Thermal`) and the
  effects that correct it;
* :mod:`.distortion` — bending with a temperature gradient, squareness drift;
* :mod:`.lag` — the first-order lag filter, the thermal-lag effect and the typed
  :class:`SignalFilter` contract the grid writes and the daemon applies.

Units: temperatures °C, expansion µm/(m·°C), angles µrad, time s.
"""

from __future__ import annotations

from .distortion import SquarenessDriftEffect, ThermalGradientEffect
from .expansion import ScaleExpansionEffect, TemperatureEffect, Thermal, WorkpieceExpansionEffect
from .lag import (
    FIRST_ORDER_LAG,
    FirstOrderLag,
    SignalFilter,
    ThermalLagEffect,
    lag_filter,
    signal_filters,
)
from .roles import (
    AIR,
    BOTTOM,
    LAGGED_ROLES,
    SCALE_ROLES,
    STRUCTURE_ROLES,
    TEMPERATURE_ROLES,
    TOP,
    WORKPIECE,
    is_temperature,
    scale_role,
)

__all__ = [
    "AIR",
    "BOTTOM",
    "FIRST_ORDER_LAG",
    "LAGGED_ROLES",
    "SCALE_ROLES",
    "STRUCTURE_ROLES",
    "TEMPERATURE_ROLES",
    "TOP",
    "WORKPIECE",
    "FirstOrderLag",
    "ScaleExpansionEffect",
    "SignalFilter",
    "SquarenessDriftEffect",
    "TemperatureEffect",
    "Thermal",
    "ThermalGradientEffect",
    "ThermalLagEffect",
    "WorkpieceExpansionEffect",
    "is_temperature",
    "lag_filter",
    "scale_role",
    "signal_filters",
]
