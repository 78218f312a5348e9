"""What the machine does that its description lacks: the true carriage position minus the indicated.

Each effect is a function of the axis' indicated position q (mm; what its own encoder reads —
the screw's angle or the scale's reading), the direction of its last motion d (±1) and time t (s),
returning µm of error = true − indicated (docs/conventions.md). The reference instrument sees the
carriage where it truly is, so these errors travel with the axis' coordinates.

* :class:`PositioningCurve` — a smooth positional error table (ISO 230-1 EXX) the model lacks;
* :class:`PeriodicError` — a screw pitch or scale interpolation error: a sine locked to q with a
  constant period (plus a small second harmonic);
* :class:`Reversal` — backlash: the carriage lags the drive by half the reversal on either side,
  at rest as well as moving;
* :class:`ThermalExpansion` — the axis' scale (or screw) expands about its fixed point as its
  temperature rises over the session: α·ΔT(t)·(q − q_f), zero at the fixed point.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from .shapes import SmoothCurve, TimeCurve

FloatArray = NDArray[np.float64]


@dataclass(frozen=True)
class PositioningCurve:
    curve: SmoothCurve
    family: str = "smooth"

    def error_um(self, q: FloatArray, d: FloatArray, t: FloatArray) -> FloatArray:
        return self.curve(q)

    def describe(self) -> dict[str, object]:
        return {"effect": "positioning_curve", **self.curve.describe()}


@dataclass(frozen=True)
class PeriodicError:
    """A·sin(2π·q/p + φ) + h2·A·sin(4π·q/p + φ2); p (mm) constant along the travel."""

    period_mm: float
    amplitude_um: float
    phase: float
    h2: float
    phase2: float
    family: str = "periodic"

    def error_um(self, q: FloatArray, d: FloatArray, t: FloatArray) -> FloatArray:
        w = 2 * np.pi * np.asarray(q) / self.period_mm
        a = self.amplitude_um
        return a * np.sin(w + self.phase) + self.h2 * a * np.sin(2 * w + self.phase2)

    def describe(self) -> dict[str, object]:
        return {
            "effect": "periodic",
            "period_mm": round(self.period_mm, 6),
            "amplitude_um": round(self.amplitude_um, 4),
            "second_harmonic": round(self.h2, 3),
        }


@dataclass(frozen=True)
class Reversal:
    """Error after a + approach minus error after a − approach = ``reversal_um`` (µm)."""

    reversal_um: float
    family: str = "reversal"

    def error_um(self, q: FloatArray, d: FloatArray, t: FloatArray) -> FloatArray:
        return 0.5 * self.reversal_um * np.asarray(d, dtype=float)

    def describe(self) -> dict[str, object]:
        return {"effect": "reversal", "reversal_um": round(self.reversal_um, 4)}


@dataclass(frozen=True)
class ThermalExpansion:
    """α (µm/(m·°C)) × ΔT(t) (°C, rising by ``rise_C`` over the session) × (q − q_f) (mm) / 1000."""

    alpha_um_per_m_C: float
    fixed_point_mm: float
    rise_C: float
    temperature: TimeCurve
    family: str = "thermal_drift"

    def delta_T(self, t: FloatArray) -> FloatArray:
        return self.rise_C * self.temperature(t)

    def error_um(self, q: FloatArray, d: FloatArray, t: FloatArray) -> FloatArray:
        dq = np.asarray(q) - self.fixed_point_mm
        return self.alpha_um_per_m_C * self.delta_T(t) * dq / 1000.0

    def describe(self) -> dict[str, object]:
        return {
            "effect": "thermal_expansion",
            "alpha_um_per_m_C": round(self.alpha_um_per_m_C, 3),
            "fixed_point_mm": round(self.fixed_point_mm, 4),
            "rise_C": round(self.rise_C, 3),
            **self.temperature.describe(),
        }


MACHINE_EFFECTS = (PositioningCurve, PeriodicError, Reversal, ThermalExpansion)
