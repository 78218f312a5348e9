"""Straightness criteria: the reference line removed from a measured straightness profile.

A straightness measurement gives, along positions ``s_mm`` of a line, deviations ``e_um``
perpendicular to it. What is reported as "the straightness error" depends on the reference line
removed first (paper 000_…, appendix A.2: least squares, end points fit, minimum separation):

- ``least_squares``: the least-squares line of ``e`` on ``s``;
- ``end_points``: the line through the first and last point (smallest and largest ``s``);
- ``min_zone``: the minimum-zone line, the mid-line of the pair of parallel lines of minimum
  separation that enclose every point (ISO 12780 MZLI). The separation is measured along ``e``
  (the deviation direction), the metrology convention, so the problem is scale-free in ``s``.

The straightness value is the peak-to-valley of the residuals about the criterion's line; the
min-zone value is, by definition, the smallest over all lines. The min-zone solution here is
exact: the zone width ``w(k) = max(e − k·s) − min(e − k·s)`` is a convex, piecewise-linear
function of the slope ``k`` whose breakpoints are the edge slopes of the upper and lower convex
hulls of the points, so its minimum is attained at one of those slopes and every one is tried.
"""

from __future__ import annotations

from typing import Final

import numpy as np
from numpy.typing import ArrayLike, NDArray

__all__ = [
    "CRITERIA",
    "END_POINTS",
    "LEAST_SQUARES",
    "MIN_ZONE",
    "apply_criterion",
    "check_criterion",
    "reference_line",
    "straightness_um",
]

LEAST_SQUARES: Final = "least_squares"
END_POINTS: Final = "end_points"
MIN_ZONE: Final = "min_zone"
#: The allowed criterion names, as used by ``criterion = "…"`` in machine.toml (docs/formats.md §1).
CRITERIA: Final[tuple[str, ...]] = (LEAST_SQUARES, END_POINTS, MIN_ZONE)


def check_criterion(criterion: str) -> str:
    """Return ``criterion`` if it is one of :data:`CRITERIA`, else raise a ValueError naming it."""
    if criterion not in CRITERIA:
        raise ValueError(
            f"unknown straightness criterion {criterion!r}: allowed are {', '.join(CRITERIA)}"
        )
    return criterion


def _check_profile(s_mm: ArrayLike, e_um: ArrayLike) -> tuple[NDArray[np.float64], ...]:
    s = np.asarray(s_mm, dtype=float)
    e = np.asarray(e_um, dtype=float)
    if s.ndim != 1 or e.shape != s.shape:
        raise ValueError(
            f"positions and deviations must be 1-D arrays of one length, got shapes "
            f"{s.shape} and {e.shape}"
        )
    if not (np.all(np.isfinite(s)) and np.all(np.isfinite(e))):
        raise ValueError("positions and deviations must be finite (no NaN or inf)")
    if s.size < 2 or np.ptp(s) == 0.0:
        raise ValueError(
            f"a straightness line needs at least two distinct positions, got {np.unique(s).size}"
        )
    return s, e


def _half_hull(s: NDArray[np.float64], e: NDArray[np.float64], sign: float) -> NDArray[np.int_]:
    """Indices (in ``s`` order) of the lower hull (sign=+1) or upper hull (sign=−1).

    Andrew's monotone chain on points already sorted by ``s`` then ``e``.
    """
    hull: list[int] = []
    for i in range(s.size):
        while len(hull) >= 2:
            o, a = hull[-2], hull[-1]
            cross = (s[a] - s[o]) * (e[i] - e[o]) - (e[a] - e[o]) * (s[i] - s[o])
            if sign * cross > 0.0:
                break
            hull.pop()
        hull.append(i)
    return np.asarray(hull, dtype=int)


def _hull_edge_slopes(s: NDArray[np.float64], e: NDArray[np.float64]) -> NDArray[np.float64]:
    order = np.lexsort((e, s))
    s_sorted, e_sorted = s[order], e[order]
    # positions closer than 1e-12 of the span are one position (a gap of 1e-308 mm would
    # give a slope of 1e308 µm/mm: no reference line, an overflow)
    tol = 1e-12 * max(float(s_sorted[-1] - s_sorted[0]), 1e-300)
    slopes = []
    for sign in (1.0, -1.0):
        idx = _half_hull(s_sorted, e_sorted, sign)
        ds = np.diff(s_sorted[idx])
        de = np.diff(e_sorted[idx])
        keep = ds > tol  # vertical edges (equal positions) carry no slope breakpoint
        slopes.append(de[keep] / ds[keep])
    return np.unique(np.concatenate(slopes))


def _zone_widths(
    s: NDArray[np.float64], e: NDArray[np.float64], slopes: NDArray[np.float64]
) -> NDArray[np.float64]:
    resid = e[None, :] - slopes[:, None] * s[None, :]
    return resid.max(axis=1) - resid.min(axis=1)


def reference_line(s_mm: ArrayLike, e_um: ArrayLike, criterion: str) -> tuple[float, float]:
    """Reference line of a straightness profile under ``criterion``.

    Args:
        s_mm: positions along the line, mm, shape (N,), at least two distinct.
        e_um: straightness deviations at those positions, µm, shape (N,).
        criterion: one of :data:`CRITERIA`.

    Returns:
        ``(slope_um_per_mm, intercept_um)``: the line ``e = slope·s + intercept``. For
        ``min_zone`` it is the mid-line of the minimum zone, so the residuals span ±width/2.
    """
    check_criterion(criterion)
    s, e = _check_profile(s_mm, e_um)
    if criterion == LEAST_SQUARES:
        s_c = s - s.mean()
        slope = float(np.dot(s_c, e - e.mean()) / np.dot(s_c, s_c))
        return slope, float(e.mean() - slope * s.mean())
    if criterion == END_POINTS:
        lo, hi = s == s.min(), s == s.max()
        e_lo, e_hi = float(e[lo].mean()), float(e[hi].mean())
        slope = (e_hi - e_lo) / float(s.max() - s.min())
        return slope, e_lo - slope * float(s.min())
    slopes = _hull_edge_slopes(s, e)
    widths = _zone_widths(s, e, slopes)
    slope = float(slopes[int(np.argmin(widths))])
    resid = e - slope * s
    return slope, float(0.5 * (resid.max() + resid.min()))


def apply_criterion(s_mm: ArrayLike, e_um: ArrayLike, criterion: str) -> NDArray[np.float64]:
    """Residual deviations (µm) after removing the criterion's reference line, shape (N,)."""
    slope, intercept = reference_line(s_mm, e_um, criterion)
    s, e = _check_profile(s_mm, e_um)
    return e - (slope * s + intercept)


def straightness_um(s_mm: ArrayLike, e_um: ArrayLike, criterion: str) -> float:
    """Straightness value (µm): peak-to-valley of the residuals about the criterion's line."""
    resid = apply_criterion(s_mm, e_um, criterion)
    return float(resid.max() - resid.min())
