"""One parametric error as a function of its axis' indicated position.

A table holds the systematic part (µm or µrad) as tabulated values interpolated by a cubic
spline, or as a polynomial in the axis position (the paper's "curve input"), and optionally a
random part (a 2σ band, same unit) tabulated or uniform over the span.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from numpy.typing import NDArray
from scipy.interpolate import CubicSpline

from .parametric_errors import Component

FloatArray = NDArray[np.float64]
MAX_POLYNOMIAL_ORDER = 10


@dataclass
class ErrorTable:
    """Systematic (and random) values of one component along its axis.

    ``position_mm`` and ``value`` are the table after any measurement-offset transformation and
    straightness criterion; ``source`` keeps what the user gave (for writing the file back).
    """

    component: Component
    position_mm: FloatArray | None = None
    value: FloatArray | None = None
    polynomial: FloatArray | None = None  # c0 + c1·q + … (q in mm), unit of the component
    random_2sigma: FloatArray | None = None  # at position_mm, same unit
    random_band: float | None = None  # uniform 2σ band over the span
    offset_mm: FloatArray | None = None  # where the line was measured (x, y, z)
    reversal: FloatArray | None = None  # positional tables: half reversal B_i/2 at position_mm
    criterion: str | None = None
    source: dict[str, object] = field(default_factory=dict)
    _spline: CubicSpline | None = field(default=None, init=False, repr=False)

    def __post_init__(self) -> None:
        self._rebuild()

    def _rebuild(self) -> None:
        self._spline = None
        if self.position_mm is not None and self.value is not None and len(self.position_mm) >= 2:
            self._spline = CubicSpline(self.position_mm, self.value, bc_type="not-a-knot")

    def with_values(self, value: FloatArray) -> ErrorTable:
        """A copy with new tabulated systematic values at the same positions."""
        copy = ErrorTable(
            component=self.component,
            position_mm=None if self.position_mm is None else self.position_mm.copy(),
            value=np.asarray(value, dtype=float).copy(),
            polynomial=None,
            random_2sigma=self.random_2sigma,
            random_band=self.random_band,
            offset_mm=self.offset_mm,
            reversal=self.reversal,
            criterion=self.criterion,
            source=dict(self.source),
        )
        return copy

    @property
    def span_mm(self) -> tuple[float, float] | None:
        if self.position_mm is None or len(self.position_mm) == 0:
            return None
        return float(self.position_mm[0]), float(self.position_mm[-1])

    def evaluate(self, q_mm: FloatArray) -> FloatArray:
        """Systematic value at axis positions ``q_mm``; outside a tabulated span the end value holds."""
        q = np.asarray(q_mm, dtype=float)
        if self.polynomial is not None:
            return np.polynomial.polynomial.polyval(q, self.polynomial)
        assert self.position_mm is not None and self.value is not None
        if self._spline is None:  # a single value: constant
            return np.full(q.shape, float(self.value[0]))
        qc = np.clip(q, self.position_mm[0], self.position_mm[-1])
        return np.asarray(self._spline(qc), dtype=float)

    def slope(self, q_mm: FloatArray) -> FloatArray:
        """Derivative d(value)/dq per mm at ``q_mm`` (zero outside a tabulated span)."""
        q = np.asarray(q_mm, dtype=float)
        if self.polynomial is not None:
            return np.polynomial.polynomial.polyval(
                q, np.polynomial.polynomial.polyder(self.polynomial)
            )
        if self._spline is None:
            return np.zeros(q.shape)
        assert self.position_mm is not None
        inside = (q >= self.position_mm[0]) & (q <= self.position_mm[-1])
        return np.where(inside, self._spline(q, 1), 0.0)

    def evaluate_random(self, q_mm: FloatArray) -> FloatArray:
        """Random part (2σ band, unit of the component) at ``q_mm``; zero when none is known."""
        q = np.asarray(q_mm, dtype=float)
        if self.random_band is not None:
            return np.full(q.shape, float(self.random_band))
        if self.random_2sigma is None or self.position_mm is None:
            return np.zeros(q.shape)
        return np.interp(q, self.position_mm, self.random_2sigma)

    def evaluate_reversal(self, q_mm: FloatArray) -> FloatArray:
        """Half reversal (µm) at ``q_mm``: the error after an approach in + is value + this,
        in − value − this (linear interpolation, end values held)."""
        q = np.asarray(q_mm, dtype=float)
        if self.reversal is None or self.position_mm is None:
            return np.zeros(q.shape)
        return np.interp(q, self.position_mm, self.reversal)

    @property
    def has_random(self) -> bool:
        return self.random_band is not None or self.random_2sigma is not None


def fit_polynomial(position_mm: FloatArray, value: FloatArray, order: int) -> FloatArray:
    """Least-squares polynomial coefficients (c0 first) through a few samples (paper's curve input).

    Positions are scaled internally for conditioning; ValueError if the order is out of range
    (1…10) or there are not more samples than coefficients... equal is allowed (interpolation).
    """
    if not 0 <= order <= MAX_POLYNOMIAL_ORDER:
        raise ValueError(f"polynomial order {order} is outside 0…{MAX_POLYNOMIAL_ORDER}")
    if len(position_mm) < order + 1:
        raise ValueError(
            f"a polynomial of order {order} needs at least {order + 1} samples, got {len(position_mm)}"
        )
    series = np.polynomial.Polynomial.fit(position_mm, value, order)
    return np.asarray(series.convert().coef, dtype=float)
