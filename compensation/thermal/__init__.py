"""thermal: every thermal term of the model, in one place.

* :mod:`.roles` — the temperature role names (``T_x`` … ``T_air``), defined once;
* :mod:`.expansion` — the machine's scale and workpiece expansion (:class:`Thermal`) and the
  effects that correct it;
* :mod:`.distortion` — bending with a temperature gradient, squareness drift;
* :mod:`.lag` — the first-order lag filter, the thermal-lag effect and the typed
  :class:`SignalFilter` contract the grid writes and the daemon applies.

The role names import nothing else (the daemon's configuration and the CLI read them without
numpy); the terms are imported on first use. Units: temperatures °C, expansion µm/(m·°C), angles µrad, time s.
"""

from __future__ import annotations

import importlib
from typing import TYPE_CHECKING, Any

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

if TYPE_CHECKING:
    from .distortion import SquarenessDriftEffect, ThermalGradientEffect
    from .expansion import (
        ScaleExpansionEffect,
        TemperatureEffect,
        Thermal,
        WorkpieceExpansionEffect,
    )
    from .lag import (
        FIRST_ORDER_LAG,
        FirstOrderLag,
        SignalFilter,
        ThermalLagEffect,
        lag_filter,
        signal_filters,
    )

_LAZY = {
    "SquarenessDriftEffect": "distortion",
    "ThermalGradientEffect": "distortion",
    "ScaleExpansionEffect": "expansion",
    "TemperatureEffect": "expansion",
    "Thermal": "expansion",
    "WorkpieceExpansionEffect": "expansion",
    "FIRST_ORDER_LAG": "lag",
    "FirstOrderLag": "lag",
    "SignalFilter": "lag",
    "ThermalLagEffect": "lag",
    "lag_filter": "lag",
    "signal_filters": "lag",
}

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


def __getattr__(name: str) -> Any:
    module = _LAZY.get(name)
    if module is None:
        raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
    return getattr(importlib.import_module(f"{__name__}.{module}"), name)
