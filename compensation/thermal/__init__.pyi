"""Public API of ``thermal`` (read by lazy_loader: names load on first use)."""

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
