"""The parts of a machine description besides its errors: working volume, probe and the
arm-deflection terms (docs/formats.md §1; the thermal data is :class:`.thermal.Thermal`). Units:
positions mm, arm terms µrad/m.

They sit below both :mod:`.machine` (which evaluates them) and :mod:`.formats.machine_toml`
(which parses them), so neither has to import the other's module to build a machine.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

FloatArray = NDArray[np.float64]


@dataclass(frozen=True)
class Volume:
    """Working volume (mm), the reference point all parametric errors refer to, default steps."""

    lower_mm: FloatArray
    upper_mm: FloatArray
    reference_mm: FloatArray
    steps: tuple[int, int, int] | None = None

    def contains(self, points_mm: FloatArray, tol_mm: float = 1e-9) -> NDArray[np.bool_]:
        p = np.asarray(points_mm, dtype=float)
        return np.all((p >= self.lower_mm - tol_mm) & (p <= self.upper_mm + tol_mm), axis=-1)

    def nodes(self, steps: tuple[int, int, int]) -> tuple[FloatArray, FloatArray, FloatArray]:
        """Node coordinates along x, y, z for ``steps`` nodes per axis (paper: "13 steps")."""
        return tuple(  # type: ignore[return-value]
            np.linspace(self.lower_mm[k], self.upper_mm[k], int(steps[k])) for k in range(3)
        )


@dataclass(frozen=True)
class Probe:
    """The stylus: tip offset ``(Xp, Yp, Zp)`` mm and random probing error (2σ) µm.

    ``offset_mm`` is the default stylus of every function that takes ``stylus_mm=None``.
    """

    offset_mm: FloatArray  # stylus tip offset (Xp, Yp, Zp)
    random_um: float = 0.0  # random probing error (2σ)


@dataclass(frozen=True)
class ArmDeflection:
    """The φ terms of the horizontal-arm models (not rigid-body; see docs/seed-equations.md).

    ``phi1`` µrad per m of arm travel: a load-dependent tilt (MH1: ΔX += φ1·x·z; MH2: ΔY += φ1·y·z);
    ``phi2`` µrad per m: the arm's droop curvature (MH1: ΔZ −= φ2·x²/2; MH2: ΔZ += φ2·y²/2).
    """

    phi1: float = 0.0
    phi2: float = 0.0
