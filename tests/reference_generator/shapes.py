"""Smooth curves along a travel: a positioning error table or a sensor's linearity.

Two forms, both without a spectral peak (so that no honest analysis finds a period in them):
a Legendre series of low order, or a Gaussian-process draw (squared-exponential covariance, one
correlation length) on a fine grid, evaluated by a cubic spline. A finite sum of random sines is
deliberately not used: each of its lines *is* a period.

Units: positions mm, values µm.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.polynomial import legendre
from numpy.typing import NDArray
from scipy.interpolate import CubicSpline

FloatArray = NDArray[np.float64]


@dataclass(frozen=True)
class SmoothCurve:
    """A smooth function of position over [lo, hi] (held flat beyond by the spline's ends)."""

    kind: str  # legendre | gp
    lo: float
    hi: float
    nodes_mm: FloatArray
    values_um: FloatArray

    def __call__(self, pos_mm: FloatArray) -> FloatArray:
        spline = CubicSpline(self.nodes_mm, self.values_um)
        return np.asarray(spline(np.clip(pos_mm, self.nodes_mm[0], self.nodes_mm[-1])))

    def describe(self) -> dict[str, object]:
        return {"shape": self.kind, "peak_to_valley_um": round(float(np.ptp(self.values_um)), 4)}


def draw_smooth(rng: np.random.Generator, lo: float, hi: float, ptv_um: float) -> SmoothCurve:
    """A smooth curve over [lo, hi] with the given peak-to-valley (µm) over that span.

    Legendre: orders 1…n (n 2–5), coefficients decaying as 1/k, the quadratic at least a third of
    the largest. GP: correlation length 1/6 to 1/2 of the span.
    """
    nodes = np.linspace(lo, hi, 161)
    u = (nodes - lo) / (hi - lo) * 2 - 1
    if rng.random() < 0.5:
        kind = "legendre"
        order = int(rng.integers(2, 6))
        coef = np.zeros(order + 1)
        coef[1:] = rng.normal(0.0, 1.0, order) / np.arange(1, order + 1)
        coef[1] *= 0.5  # a mostly curved table (a straight one is a scale error)
        if abs(coef[2]) < np.max(np.abs(coef[1:])) / 3:
            coef[2] = np.sign(coef[2] or 1.0) * np.max(np.abs(coef[1:])) / 3
        values = legendre.legval(u, coef)
    else:
        kind = "gp"
        ell = rng.uniform(1 / 6, 1 / 2) * 2  # in u (span 2)
        cov = np.exp(-0.5 * ((u[:, None] - u[None, :]) / ell) ** 2)
        w, vec = np.linalg.eigh(cov)  # symmetric square root: the SE covariance is near singular
        values = vec @ (np.sqrt(np.clip(w, 0.0, None)) * rng.normal(size=u.size))
    values = values - values.mean()
    values *= ptv_um / np.ptp(values)
    return SmoothCurve(kind, lo, hi, nodes, values)


@dataclass(frozen=True)
class TimeCurve:
    """A slow change over the session, 0 at ``t0_s`` (s), peak-to-valley 1 over [t0, t1].

    ``linear``; ``warmup``: 1 − e^(−(t − t0)/τ) (a heating that levels off, τ 0.3–2× the
    session); ``sigmoid``: a logistic step centred in the session; ``wander``: half to one and a
    half slow cycles of a sine (an air-conditioning or day cycle seen in a short session).
    """

    kind: str
    t0_s: float
    t1_s: float
    tau_s: float
    phase: float

    def raw(self, t_s: FloatArray) -> FloatArray:
        u = (np.asarray(t_s, dtype=float) - self.t0_s) / self.tau_s
        if self.kind == "linear":
            return u
        if self.kind == "warmup":
            return 1.0 - np.exp(-u)
        if self.kind == "sigmoid":
            mid = 0.5 * (self.t1_s - self.t0_s) / self.tau_s
            return 1.0 / (1.0 + np.exp(-(u - mid)))
        return np.sin(u + self.phase) - np.sin(self.phase)  # wander

    def __call__(self, t_s: FloatArray) -> FloatArray:
        grid = np.linspace(self.t0_s, self.t1_s, 2001)
        ref = self.raw(grid)
        return (self.raw(t_s) - ref[0]) / np.ptp(ref)

    def describe(self) -> dict[str, object]:
        return {"time_shape": self.kind, "tau_s": round(self.tau_s, 2)}


def draw_time_curve(
    rng: np.random.Generator, t0_s: float, t1_s: float, kinds: tuple[str, ...]
) -> TimeCurve:
    """One of ``kinds`` over the session [t0, t1] (s)."""
    kind = str(rng.choice(kinds))
    span = t1_s - t0_s
    tau = {
        "linear": span,
        "warmup": span * rng.uniform(0.3, 2.0),
        "sigmoid": span * rng.uniform(0.08, 0.2),
        "wander": span / (np.pi * rng.uniform(1.0, 3.0)),  # 0.5–1.5 cycles in the session
    }[kind]
    return TimeCurve(kind, t0_s, t1_s, float(tau), float(rng.uniform(0, 2 * np.pi)))
