"""A room and machine temperature history of the generator's own design.

The air follows a daily cycle, a slow drift, an HVAC cycle (10–40 min) and, sometimes, a door
opening (a step that the room recovers from over 20–60 min). Every structure sensor follows the
air through its own first-order lag (:func:`first_order_lag`), plus a fixed offset:

* scales ``T_x``, ``T_y``, ``T_z``: 15–90 min;
* workpiece ``T_wp``: 10–40 min;
* ``T_top`` (above the main guideway) 5–30 min, ``T_bottom`` 1–4 h, so ``T_top − T_bottom``
  swings whenever the air does.

All signals are defined for negative times too (the machine's history before the session), so a
lag filter started well before t = 0 is in its natural state at the session's start.

Units: °C, s.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from numpy.typing import NDArray

FloatArray = NDArray[np.float64]

SIGNALS = ("T_x", "T_y", "T_z", "T_wp", "T_top", "T_bottom", "T_air")
_LAG_RANGE_S = {
    "T_x": (900.0, 5400.0),
    "T_y": (900.0, 5400.0),
    "T_z": (900.0, 5400.0),
    "T_wp": (600.0, 2400.0),
    "T_top": (300.0, 1800.0),
    "T_bottom": (3600.0, 14400.0),
}
HISTORY_S = 12 * 3600.0  # simulated history before t = 0
STEP_S = 10.0


def first_order_lag(t_s: FloatArray, x: FloatArray, tau_s: float) -> FloatArray:
    """Exact first-order lag of ``x`` (piecewise linear between samples) on any time grid.

    ``y' = (x − y)/τ``, ``y(t0) = x(t0)``; each step uses the closed form for a linear ramp of
    the input, so the result is exact whatever the spacing of ``t_s`` (s).
    """
    y = np.empty_like(x)
    y[0] = x[0]
    dt = np.diff(t_s)
    a = np.exp(-dt / tau_s)
    # y1 = x1 + a (y0 − x0) − τ (1 − a) (x1 − x0)/dt   (ramp input, exact)
    slope_term = tau_s * (1.0 - a) / np.where(dt > 0, dt, 1.0)
    for k in range(1, len(x)):
        dx = x[k] - x[k - 1]
        y[k] = x[k] + a[k - 1] * (y[k - 1] - x[k - 1]) - slope_term[k - 1] * dx
    return y


@dataclass
class TemperatureField:
    """Continuous temperature histories sampled on a fine grid from −HISTORY_S to the end."""

    grid_s: FloatArray
    air: FloatArray
    signals: dict[str, FloatArray] = field(default_factory=dict)
    description: dict[str, float] = field(default_factory=dict)

    def at(self, name: str, t_s: FloatArray) -> FloatArray:
        """Signal ``name`` (°C) at times ``t_s`` (s, may be negative down to −HISTORY_S)."""
        series = self.air if name == "T_air" else self.signals[name]
        return np.interp(t_s, self.grid_s, series)

    def lagged(self, name: str, tau_s: float, t_s: FloatArray) -> FloatArray:
        """Signal ``name`` passed through a further first-order lag τ (s), at ``t_s``."""
        series = self.air if name == "T_air" else self.signals[name]
        return np.interp(t_s, self.grid_s, first_order_lag(self.grid_s, series, tau_s))


def draw_temperatures(rng: np.random.Generator, duration_s: float) -> TemperatureField:
    """A random room/machine temperature history covering ``[−HISTORY_S, duration_s]``."""
    grid = np.arange(-HISTORY_S, duration_s + STEP_S, STEP_S)
    t0 = float(rng.uniform(19.3, 21.5))
    day_amp = float(rng.uniform(0.2, 1.0))
    day_phase = float(rng.uniform(0.0, 2 * np.pi))
    drift = float(rng.uniform(-0.3, 0.3)) / 3600.0  # °C/s
    hvac_amp = float(rng.uniform(0.05, 0.35))
    hvac_period = float(rng.uniform(600.0, 2400.0))
    hvac_phase = float(rng.uniform(0.0, 2 * np.pi))
    air = (
        t0
        + day_amp * np.sin(2 * np.pi * grid / 86400.0 + day_phase)
        + drift * np.clip(grid, -3 * 3600.0, None)
        + hvac_amp * np.sin(2 * np.pi * grid / hvac_period + hvac_phase)
    )
    desc = {
        "T0": t0,
        "day_amp": day_amp,
        "drift_C_per_h": drift * 3600,
        "hvac_amp": hvac_amp,
        "hvac_period_s": hvac_period,
    }
    if rng.random() < 0.6:  # a door opening during the session
        t_door = float(rng.uniform(0.1, 0.7)) * duration_s
        height = float(rng.choice([-1.0, 1.0]) * rng.uniform(0.4, 1.5))
        recover = float(rng.uniform(1200.0, 3600.0))
        after = grid >= t_door
        air = air + np.where(after, height * np.exp(-(grid - t_door) / recover), 0.0)
        desc.update({"door_s": t_door, "door_height_C": height, "door_recover_s": recover})
    signals: dict[str, FloatArray] = {}
    for name, (lo, hi) in _LAG_RANGE_S.items():
        tau = float(np.exp(rng.uniform(np.log(lo), np.log(hi))))
        offset = float(rng.uniform(-0.3, 0.3))
        signals[name] = first_order_lag(grid, air, tau) + offset
        desc[f"{name}_tau_s"] = tau
    return TemperatureField(grid_s=grid, air=air, signals=signals, description=desc)
