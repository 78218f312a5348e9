"""Thermal bending of a beam (a guideway, a bridge, a granite base) between its supports.

A temperature difference ΔT between the top and the bottom of a beam of depth h gives it a free
curvature κ_T = α·ΔT/h (it bows towards the cooler side). How much of that curvature shows as
deflection depends on how the beam is held: simply supported (anywhere: at its ends, or at the
Bessel points of a granite plate with overhangs) it takes the free curvature; a cantilever too,
from its clamp; a propped cantilever and a beam clamped at both ends resist part or all of it, so
they bend only where the gradient is not uniform. ``deflection`` solves

    w'' = κ_T(ξ) + c0 + c1·ξ    (c0 + c1·ξ: the reaction moment of the redundant supports)

on ξ ∈ [0, 1] with the boundary conditions of each support, by double integration.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray
from scipy.integrate import cumulative_trapezoid

FloatArray = NDArray[np.float64]

GRID = np.linspace(0.0, 1.0, 2001)
BESSEL = (0.2232, 0.7768)
SUPPORTS = ("simply_supported", "bessel", "cantilever", "propped", "clamped")


def _integral(f: FloatArray) -> FloatArray:
    return cumulative_trapezoid(f, GRID, initial=0.0)


def deflection(support: str, curvature: FloatArray) -> tuple[FloatArray, FloatArray]:
    """(w, w') on :data:`GRID` for the thermal curvature ``curvature`` (on the grid, 1/unit²)."""
    one = np.ones_like(GRID)
    particular = [_integral(_integral(curvature))]
    slopes = [_integral(curvature)]
    basis_w = [_integral(_integral(one)), _integral(_integral(GRID)), one, GRID]
    basis_s = [_integral(one), _integral(GRID), np.zeros_like(GRID), one]
    # unknowns: c0, c1 (redundant moments), a, b (rigid line)
    if support in ("simply_supported", "bessel"):
        at = (0.0, 1.0) if support == "simply_supported" else BESSEL
        rows = [("w", at[0]), ("w", at[1]), ("c0", None), ("c1", None)]
    elif support == "cantilever":
        rows = [("w", 0.0), ("s", 0.0), ("c0", None), ("c1", None)]
    elif support == "propped":
        rows = [("w", 0.0), ("s", 0.0), ("w", 1.0), ("m1", None)]
    elif support == "clamped":
        rows = [("w", 0.0), ("s", 0.0), ("w", 1.0), ("s", 1.0)]
    else:
        raise ValueError(f"unknown support {support!r}; allowed: {', '.join(SUPPORTS)}")
    a = np.zeros((4, 4))
    rhs = np.zeros(4)
    for i, (kind, where) in enumerate(rows):
        if kind in ("w", "s"):
            assert where is not None
            j = int(np.argmin(np.abs(GRID - where)))
            src = basis_w if kind == "w" else basis_s
            a[i] = [col[j] for col in src]
            rhs[i] = -(particular[0][j] if kind == "w" else slopes[0][j])
        elif kind == "c0":
            a[i, 0] = 1.0
        elif kind == "c1":
            a[i, 1] = 1.0
        else:  # m1: no moment at the pinned end, c0 + c1 = 0
            a[i, 0], a[i, 1] = 1.0, 1.0
    c = np.linalg.solve(a, rhs)
    w = particular[0] + sum(ci * col for ci, col in zip(c, basis_w, strict=True))
    s = slopes[0] + sum(ci * col for ci, col in zip(c, basis_s, strict=True))
    return w, s


def gradient_profile(kind: str, rng: np.random.Generator) -> tuple[FloatArray, dict[str, float]]:
    """How the top–bottom difference is spread along the beam: ``uniform``, ``local`` (a lamp or
    a window over part of it) or ``ramp`` (growing towards one end)."""
    if kind == "uniform":
        return np.ones_like(GRID), {}
    if kind == "local":
        c, w = rng.uniform(0.2, 0.8), rng.uniform(0.1, 0.25)
        return np.exp(-0.5 * ((GRID - c) / w) ** 2), {"centre": c, "width": w}
    if kind == "ramp":
        end = int(rng.integers(2))
        return (GRID if end == 0 else 1 - GRID), {"end": end}
    raise ValueError(f"unknown gradient profile {kind!r}")
