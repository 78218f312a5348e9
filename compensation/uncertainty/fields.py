"""Smooth random functions along an axis: the calibration error of a whole parametric table.

A table's calibration error is not independent from node to node: the instrument that measured
it (a laser interferometer, an autocollimator, a straightedge) errs smoothly along the axis.
It is drawn here as a zero-mean, unit-variance **Gaussian process with squared-exponential
correlation** ``ρ(Δq) = exp(−Δq²/(2ℓ²))`` (ℓ = ``correlation_mm``), then scaled by the standard
uncertainty profile (:mod:`.model`). Why this and not a random polynomial: the process is
stationary (a random polynomial's variance depends on where along the axis one is, largest at
the ends), infinitely smooth, has one interpretable parameter (over how many mm the error stays
alike: about the calibration targets' spacing) and scaled by u(q) its standard deviation is
exactly u(q) everywhere, i.e. consistent with the stated u by construction.

Sampling (vectorised over trials): a Karhunen–Loève expansion on a mesh of the span (spacing
≤ ℓ/8) keeps the eigenmodes down to 10⁻¹² of the largest (the squared-exponential spectrum
falls off faster than exponentially, so a few dozen modes suffice); a position off the mesh gets
its features by the Nyström extension (the kriging predictor from the mesh), renormalised to unit
variance. Covariances are then exact to ≈ 10⁻⁶; a sample is ``ξ @ F(q)ᵀ`` with ξ standard
normal (trials × modes). Positions mm.
"""

from __future__ import annotations

import functools
import math

import numpy as np
from numpy.typing import NDArray

__all__ = ["MAX_MESH", "SquaredExponentialBasis", "squared_exponential_basis"]

FloatArray = NDArray[np.float64]
MAX_MESH = 1601  # mesh points of one basis (ℓ/8 spacing up to a span of 200 ℓ)
_EIGEN_FLOOR = 1e-12  # modes below this fraction of the largest eigenvalue are dropped


class SquaredExponentialBasis:
    """Karhunen–Loève features of a unit-variance squared-exponential process on ``[lo, hi]`` mm.

    ``features(q)`` (Q, M): rows of unit norm, ``features(a) @ features(b)ᵀ ≈ ρ(a − b)``.
    Positions outside the span are clamped (the table's end value holds there too).
    """

    def __init__(self, lo_mm: float, hi_mm: float, correlation_mm: float) -> None:
        if not (math.isfinite(lo_mm) and math.isfinite(hi_mm) and hi_mm >= lo_mm):
            raise ValueError(f"span must be finite and increasing, got [{lo_mm}, {hi_mm}]")
        if not (math.isfinite(correlation_mm) and correlation_mm > 0):
            raise ValueError(f"correlation_mm must be finite and > 0, got {correlation_mm}")
        self.lo_mm, self.hi_mm, self.correlation_mm = float(lo_mm), float(hi_mm), correlation_mm
        span = self.hi_mm - self.lo_mm
        if span <= 1e-9 * max(1.0, abs(self.hi_mm)):
            self._mesh = np.array([self.lo_mm])
            self._proj = np.ones((1, 1))
            return
        m = int(min(MAX_MESH, max(33, math.ceil(8.0 * span / correlation_mm) + 1)))
        self._mesh = np.linspace(self.lo_mm, self.hi_mm, m)
        k = self._kernel(self._mesh, self._mesh)
        w, v = np.linalg.eigh(k)
        order = np.argsort(w)[::-1]
        w, v = w[order], v[:, order]
        keep = w > _EIGEN_FLOOR * w[0]
        # Nyström/kriging features: f(q) = k(q, mesh) · V · diag(w^-1/2)
        self._proj = v[:, keep] / np.sqrt(w[keep])

    def _kernel(self, a: FloatArray, b: FloatArray) -> FloatArray:
        d = (a[:, None] - b[None, :]) / self.correlation_mm
        return np.exp(-0.5 * d * d)

    @property
    def modes(self) -> int:
        return int(self._proj.shape[1])

    def features(self, q_mm: FloatArray) -> FloatArray:
        """(Q, M) unit-norm features at positions ``q_mm`` (Q,) mm."""
        q = np.clip(np.asarray(q_mm, dtype=float).reshape(-1), self.lo_mm, self.hi_mm)
        f = self._kernel(q, self._mesh) @ self._proj
        norm = np.linalg.norm(f, axis=1, keepdims=True)
        return f / np.where(norm > 0, norm, 1.0)

    def sample(self, q_mm: FloatArray, n_trials: int, rng: np.random.Generator) -> FloatArray:
        """(n_trials, Q) draws of the unit-variance process at ``q_mm``."""
        f = self.features(q_mm)
        return rng.standard_normal((n_trials, f.shape[1])) @ f.T


@functools.lru_cache(maxsize=128)
def squared_exponential_basis(
    lo_mm: float, hi_mm: float, correlation_mm: float
) -> SquaredExponentialBasis:
    """A cached :class:`SquaredExponentialBasis` (the eigen-decomposition is the costly part)."""
    return SquaredExponentialBasis(lo_mm, hi_mm, correlation_mm)
