"""ISO 10360-2 length measuring error test: 7 positions × 5 lengths × 3 repetitions.

Positions are 7 measuring lines through the centre of the volume: the 4 space diagonals and
one line parallel to each axis. On each line 5 calibrated lengths (gauge blocks or step-gauge
intervals) are measured 3 times; each length is measured bidirectionally: its two end faces
are probed from opposite directions (the stylus moves along +u to touch the first face and
along −u for the second), so probing errors do not cancel. The longest length is ≥ 66 % of
the measuring line inside the volume, as the standard asks.

The measured length is the distance between the two probed end points (the controller reports
probe-radius-compensated surface points); the length measuring error is measured − reference,
and ``E0 = max |measured − reference|`` over all 105 measurements, µm.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from .programs import ProbePoint

FloatArray = NDArray[np.float64]

#: Length fractions of the usable line: 5 lengths, the longest 90 % (≥ 66 % required).
LENGTH_FRACTIONS = (0.1, 0.3, 0.5, 0.7, 0.9)
REPETITIONS = 3

_DIRECTIONS: dict[str, tuple[float, float, float]] = {
    "x": (1.0, 0.0, 0.0),
    "y": (0.0, 1.0, 0.0),
    "z": (0.0, 0.0, 1.0),
    "d1": (1.0, 1.0, 1.0),
    "d2": (-1.0, 1.0, 1.0),
    "d3": (1.0, -1.0, 1.0),
    "d4": (1.0, 1.0, -1.0),
}


@dataclass(frozen=True, slots=True)
class LengthMeasurement:
    """One measurement of a calibrated length: end points A (start face) and B."""

    position: str
    """Measuring line: x, y, z, d1..d4."""
    length_mm: float
    """Reference (calibrated) length, mm."""
    repetition: int
    a_mm: tuple[float, float, float]
    b_mm: tuple[float, float, float]
    u: tuple[float, float, float]
    """Unit vector of the line, A → B."""


def length_test(
    lower_mm: FloatArray,
    upper_mm: FloatArray,
    margin: float = 0.05,
    fractions: tuple[float, ...] = LENGTH_FRACTIONS,
    repetitions: int = REPETITIONS,
) -> list[LengthMeasurement]:
    """The 105 length measurements (7 × 5 × 3) for a working volume, mm.

    ``margin``: fraction of each axis range kept clear of the volume's faces. Lengths are
    rounded to whole mm (gauge-block-like nominal sizes).
    """
    lo, hi = np.asarray(lower_mm, float), np.asarray(upper_mm, float)
    centre = (lo + hi) / 2
    half = (hi - lo) / 2 * (1 - 2 * margin)
    out: list[LengthMeasurement] = []
    for name, d in _DIRECTIONS.items():
        u = np.asarray(d) / np.linalg.norm(d)
        with np.errstate(divide="ignore"):
            reach = np.min(np.where(np.abs(u) > 0, half / np.abs(u), np.inf))
        line = 2 * reach
        for frac in fractions:
            length = float(np.floor(frac * line))
            a = centre - u * length / 2
            b = centre + u * length / 2
            for rep in range(repetitions):
                out.append(
                    LengthMeasurement(
                        name,
                        length,
                        rep,
                        (float(a[0]), float(a[1]), float(a[2])),
                        (float(b[0]), float(b[1]), float(b[2])),
                        (float(u[0]), float(u[1]), float(u[2])),
                    )
                )
    return out


def probe_points(measurements: list[LengthMeasurement]) -> list[ProbePoint]:
    """Two probe points per measurement (A then B), bidirectional probing directions.

    Travel directions: each axis approaches A moving along +u and B along −u.
    """
    pts: list[ProbePoint] = []
    for i, m in enumerate(measurements):
        u = m.u
        fwd = tuple(int(np.sign(c)) for c in u)
        back = tuple(-s for s in fwd)
        pts.append(ProbePoint(m.a_mm, u, f"len:{i}:A", fwd))  # type: ignore[arg-type]
        neg = (-u[0], -u[1], -u[2])
        pts.append(ProbePoint(m.b_mm, neg, f"len:{i}:B", back))  # type: ignore[arg-type]
    return pts


def length_errors_um(measurements: list[LengthMeasurement], measured_mm: FloatArray) -> FloatArray:
    """Length measuring errors (measured − reference) µm, from the probed points (2N, 3) mm
    in :func:`probe_points` order."""
    m = np.asarray(measured_mm, float).reshape(len(measurements), 2, 3)
    lengths = np.linalg.norm(m[:, 1] - m[:, 0], axis=1)
    ref = np.array([x.length_mm for x in measurements])
    return (lengths - ref) * 1000.0


def e0_um(errors_um: FloatArray) -> float:
    """E0 = max |length error|, µm (NaN if any measurement is missing)."""
    e = np.asarray(errors_um, float)
    return float(np.max(np.abs(e))) if e.size and np.all(np.isfinite(e)) else float("nan")
