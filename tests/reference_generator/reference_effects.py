"""What the reference instrument adds to its reading: reading − true position, in µm.

Each effect is a function of the true position the instrument looks at, r (mm, in the axis frame:
the reference's raw reading mapped linearly onto the axis, so a law in the raw reading is the same
law in r with other constants), and of the time the instrument took the sample (s). They travel
with the *reference's* coordinates: a backlash moves the carriage, and with it the sensor's
target, so between directions such an error shifts by the reversal in axis coordinates.

* :class:`ReferenceRipple` — a periodic nonlinearity of the sensor: constant period (a glass
  scale's or an interferometer's periodic nonlinearity) or a chirp following the triangulation
  distance law p(r) = p_c·((r − r0)/(r_c − r0))² (the period grows with the square of the
  distance from the sensor's optical centre r0; r_c the centre of the travel);
* :class:`ReferenceNonlinearity` — a smooth linearity error of the sensor;
* :class:`ReferenceScale` — a cosine error (the beam at an angle θ to the axis reads
  (r − r_p)·cos θ: −θ²/2 per unit length) or a gain error (sensor calibration, wavelength):
  s·(r − r_p);
* :class:`ReferenceDrift` — the reading drifts in time, the same at every position (the sensor's
  mount or electronics warming up).

The latency between the two streams is not an additive term here: the generator samples the
carriage at the reference's true sampling instant (:mod:`.case`).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from .shapes import SmoothCurve, TimeCurve

FloatArray = NDArray[np.float64]


@dataclass(frozen=True)
class ReferenceRipple:
    """A(r)·sin(φ(r)) + h2·A(r)·sin(2φ(r) + φ2) with dφ/dr = 2π/p(r).

    ``law``: ``constant`` (p = p_c) or ``triangulation`` (p(r) = p_c·((r − r0)/(r_c − r0))²);
    A(r) = A_c·(1 + g·(r − r_c)/h), h the half travel (the ripple's amplitude changes along the
    range, 4–35 µm on the ESS record).
    """

    law: str
    period_c_mm: float
    centre_mm: float
    r0_mm: float
    half_travel_mm: float
    amplitude_c_um: float
    amplitude_slope: float
    phase: float
    h2: float
    phase2: float

    @property
    def family(self) -> str:
        return f"ripple_{self.law}"

    def local_period_mm(self, r: FloatArray) -> FloatArray:
        r = np.asarray(r, dtype=float)
        if self.law == "constant":
            return np.full_like(r, self.period_c_mm)
        return self.period_c_mm * ((r - self.r0_mm) / (self.centre_mm - self.r0_mm)) ** 2

    def phase_at(self, r: FloatArray) -> FloatArray:
        """φ(r) − φ0, radians (closed form of ∫ 2π/p(r) dr from r_c)."""
        r = np.asarray(r, dtype=float)
        if self.law == "constant":
            return 2 * np.pi * (r - self.centre_mm) / self.period_c_mm
        dc = self.centre_mm - self.r0_mm
        return 2 * np.pi * dc**2 / self.period_c_mm * (1.0 / dc - 1.0 / (r - self.r0_mm))

    def amplitude_um(self, r: FloatArray) -> FloatArray:
        u = (np.asarray(r, dtype=float) - self.centre_mm) / self.half_travel_mm
        return self.amplitude_c_um * (1.0 + self.amplitude_slope * u)

    def error_um(self, r: FloatArray, t: FloatArray) -> FloatArray:
        phi = self.phase_at(r) + self.phase
        a = self.amplitude_um(r)
        return a * np.sin(phi) + self.h2 * a * np.sin(2 * phi + self.phase2)

    def period_at_ends_mm(self) -> tuple[float, float]:
        ends = np.array(
            [self.centre_mm - self.half_travel_mm, self.centre_mm + self.half_travel_mm]
        )
        lo, hi = self.local_period_mm(ends)
        return float(lo), float(hi)

    def describe(self) -> dict[str, object]:
        lo, hi = self.period_at_ends_mm()
        return {
            "effect": "reference_ripple",
            "law": self.law,
            "period_mm": round(self.period_c_mm, 6),
            "period_at_ends_mm": [round(lo, 6), round(hi, 6)],
            "r0_mm": round(self.r0_mm, 4) if self.law == "triangulation" else None,
            "centre_mm": round(self.centre_mm, 4),
            "amplitude_um": round(self.amplitude_c_um * (1 + abs(self.amplitude_slope)), 4),
            "second_harmonic": round(self.h2, 3),
        }


@dataclass(frozen=True)
class ReferenceNonlinearity:
    curve: SmoothCurve
    family: str = "smooth_reference"

    def error_um(self, r: FloatArray, t: FloatArray) -> FloatArray:
        return self.curve(r)

    def describe(self) -> dict[str, object]:
        return {"effect": "reference_nonlinearity", **self.curve.describe()}


@dataclass(frozen=True)
class ReferenceScale:
    """s (µm/m) × (r − r_p) (mm) / 1000; ``kind`` cosine (s = −(1 − cos θ)·1e6) or gain."""

    kind: str
    scale_um_per_m: float
    pivot_mm: float
    angle_mrad: float | None
    family: str = "reference_scale"

    def error_um(self, r: FloatArray, t: FloatArray) -> FloatArray:
        return self.scale_um_per_m * (np.asarray(r) - self.pivot_mm) / 1000.0

    def describe(self) -> dict[str, object]:
        return {
            "effect": "reference_scale",
            "kind": self.kind,
            "scale_um_per_m": round(self.scale_um_per_m, 3),
            "cosine_angle_mrad": None if self.angle_mrad is None else round(self.angle_mrad, 4),
        }


def cosine_scale_um_per_m(angle_mrad: float) -> float:
    """The cosine error of a beam at θ to the axis, µm per m (exact, negative)."""
    return -(1.0 - np.cos(angle_mrad * 1e-3)) * 1e6


@dataclass(frozen=True)
class ReferenceDrift:
    """``size_um`` (peak-to-valley over the session) × a slow curve in time; position-free."""

    size_um: float
    curve: TimeCurve
    family: str = "reference_drift"

    def error_um(self, r: FloatArray, t: FloatArray) -> FloatArray:
        return self.size_um * self.curve(t)

    def describe(self) -> dict[str, object]:
        return {
            "effect": "reference_drift",
            "size_um": round(self.size_um, 4),
            **self.curve.describe(),
        }


@dataclass(frozen=True)
class Latency:
    """The reference's timestamps are late by ``latency_s`` (> 0): its sample stamped t was
    taken at t − latency. At constant velocity v the error is −v·latency."""

    latency_s: float
    family: str = "latency"

    def describe(self) -> dict[str, object]:
        return {"effect": "latency", "latency_ms": round(self.latency_s * 1000, 4)}


REFERENCE_EFFECTS = (ReferenceRipple, ReferenceNonlinearity, ReferenceScale, ReferenceDrift)
