"""What the reference instrument gets wrong (docs/formats.md §4, ``source: reference``).

Every calibration has two instruments: the machine and the reference that measured it (a laser
interferometer, a triangulation sensor, a tracker, with its mounting, timestamps and
environment). The reference's own errors appear in the observed error ``(ref − indicated)·1000``
exactly like machine errors, but they belong to the reference: compensation must not correct
them. These effects describe them; they act on the reference's reading ``r`` (``ref_<axis>``,
mm, the machine frame), on time or on velocity, never on the machine, so they have no hooks on
the machine model (``compensable`` False, ``source`` "reference") and ``extend`` never writes
them.

* :class:`ReferenceRippleEffect` (``reference_ripple``): a cyclic nonlinearity locked to the
  reading, with its period law (:class:`~cmm_comp.compensation.effects.PeriodLaw`).
* :class:`ReferenceNonlinearityEffect` (``reference_nonlinearity``): a smooth nonlinearity of
  the reading, ``Σ c_k·P_k(s(r))``.
* :class:`LatencyEffect` (``latency``): the reference's timestamps late by τ: ``−v·τ`` µm.
* :class:`ReferenceScaleEffect` (``reference_scale``): ``k·(r − r_c)/1000`` µm (cosine
  misalignment, wavelength/environment).
* :class:`ReferenceDriftEffect` (``reference_drift``): ``Σ o_k·P_k(τ)`` µm, the same at every
  position.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from typing import Any, ClassVar

import numpy as np
from numpy.polynomial import legendre

from ..effects import Effect, PeriodLaw
from ..effects.periodic import Term, amplitude_um

__all__ = [
    "LatencyEffect",
    "ReferenceDriftEffect",
    "ReferenceEffect",
    "ReferenceNonlinearityEffect",
    "ReferenceRippleEffect",
    "ReferenceScaleEffect",
]


class ReferenceEffect(Effect):
    """Base: an error of the reference instrument on ``axis`` (no hooks on the machine)."""

    compensable: ClassVar[bool] = False
    source: ClassVar[str] = "reference"

    def __init__(self, axis: str) -> None:
        self.axis = axis

    def parameters(self) -> dict[str, Any]:
        return {}

    def keys(self) -> dict[str, Any]:
        return {}

    def describe(self) -> dict[str, Any]:
        return {
            "cause": self.cause,
            "axis": self.axis,
            **self.keys(),
            "parameters": self.parameters(),
        }

    def to_table(self) -> dict[str, Any]:
        d = self.describe()
        return {**{k: v for k, v in d.items() if k != "parameters"}, **d["parameters"]}


class ReferenceRippleEffect(ReferenceEffect):
    """Cyclic nonlinearity of the reference locked to its reading: ``Σ_n Σ_j P_j(s)·(a_nj·cos nφ(r)
    + b_nj·sin nφ(r))`` µm (the terms of :mod:`cmm_comp.compensation.effects.periodic`), s the
    reading normalised over ``span_mm``."""

    cause: ClassVar[str] = "reference_ripple"

    def __init__(
        self, axis: str, law: PeriodLaw, terms: Sequence[Term], span_mm: tuple[float, float]
    ) -> None:
        super().__init__(axis)
        self.law = law
        self.terms = list(terms)
        self.span_mm = span_mm

    def keys(self) -> dict[str, Any]:
        return {"law": self.law.kind, "period_mm": self.law.period_mm}

    def parameters(self) -> dict[str, Any]:
        first = [t for t in self.terms if t[0] == 1 and t[1] == 0]
        a, b = (first[0][2], first[0][3]) if first else (0.0, 0.0)
        out: dict[str, Any] = {
            "period_mm": self.law.period_mm,
            "amplitude_um": amplitude_um(self.terms, self.law, self.span_mm),
            "a_cos_um": a,
            "b_sin_um": b,
            "harmonics": max(t[0] for t in self.terms),
            "envelope_order": max(t[1] for t in self.terms),
        }
        out.update(self.law.describe(self.span_mm))
        out["span_mm"] = list(self.span_mm)
        return out


class ReferenceNonlinearityEffect(ReferenceEffect):
    """Smooth nonlinearity of the reference's reading: ``Σ c_k·P_k(s(r))`` µm, s the reading
    normalised over ``span_mm``."""

    cause: ClassVar[str] = "reference_nonlinearity"

    def __init__(
        self,
        axis: str,
        coefficients: Sequence[float],
        orders: Sequence[int],
        span_mm: tuple[float, float],
    ) -> None:
        super().__init__(axis)
        self.coefficients = [float(c) for c in coefficients]
        self.orders = [int(k) for k in orders]
        self.span_mm = span_mm

    def curve_um(self, r_mm: Any) -> Any:
        lo, hi = self.span_mm
        s = 2.0 * (np.asarray(r_mm, dtype=float) - lo) / (hi - lo) - 1.0
        c = np.zeros(max(self.orders) + 1)
        for k, v in zip(self.orders, self.coefficients, strict=True):
            c[k] = v
        return legendre.legval(s, c)

    def parameters(self) -> dict[str, Any]:
        curve = self.curve_um(np.linspace(*self.span_mm, 201))
        out: dict[str, Any] = {
            f"legendre_{k}": c for k, c in zip(self.orders, self.coefficients, strict=True)
        }
        out["peak_to_peak_um"] = float(np.ptp(curve))
        out["span_mm"] = list(self.span_mm)
        return out


class LatencyEffect(ReferenceEffect):
    """A time offset τ between the two streams: the reference's sample stamped t was taken at
    t − τ, so it reads the position the axis had then: ``−v·τ`` µm (v mm/s, τ ms)."""

    cause: ClassVar[str] = "latency"

    def __init__(self, axis: str, latency_ms: float) -> None:
        super().__init__(axis)
        self.latency_ms = float(latency_ms)

    def parameters(self) -> dict[str, Any]:
        return {"latency_ms": self.latency_ms}


class ReferenceScaleEffect(ReferenceEffect):
    """A scale term of the reference: ``k·(r − centre)/1000`` µm, k µm/m. A cosine misalignment
    by an angle θ makes the reference read short, k = −10⁶·(1 − cos θ) ≈ −10⁶·θ²/2."""

    cause: ClassVar[str] = "reference_scale"

    def __init__(self, axis: str, scale_um_per_m: float, centre_mm: float) -> None:
        super().__init__(axis)
        self.scale_um_per_m = float(scale_um_per_m)
        self.centre_mm = float(centre_mm)

    def parameters(self) -> dict[str, Any]:
        out: dict[str, Any] = {"scale_um_per_m": self.scale_um_per_m, "centre_mm": self.centre_mm}
        if self.scale_um_per_m < 0:
            out["cosine_angle_mrad"] = 1e3 * math.acos(max(1.0 + 1e-6 * self.scale_um_per_m, -1))
        return out


class ReferenceDriftEffect(ReferenceEffect):
    """The reference's reading drifts in time, the same at every position: ``Σ_{k≥1} o_k·P_k(τ)``
    µm, τ the time normalised over ``t_span_s``."""

    cause: ClassVar[str] = "reference_drift"

    def __init__(self, axis: str, t_span_s: tuple[float, float], offset_um: Sequence[float]):
        super().__init__(axis)
        self.t_span_s = t_span_s
        self.offset_um = [float(v) for v in offset_um]

    def parameters(self) -> dict[str, Any]:
        lo, hi = self.t_span_s
        tau = np.linspace(-1.0, 1.0, 201)
        curve = legendre.legval(tau, [0.0, *self.offset_um])
        return {
            "offset_range_um": float(np.ptp(curve)),
            "t_span_s": [lo, hi],
            "offset_um": list(self.offset_um),
        }
