"""Probing programs: the points a simulated controller probes, in true (reference) coordinates.

A program is a list of :class:`ProbePoint` (true position, probing direction, label). The
programs here are random points in the volume and a ball plate; the ISO 10360-2 length test is
in :mod:`sim_controller.iso10360`. Positions in mm; probing directions are unit vectors in the
direction the stylus moves when it touches (docs/formats.md ``nx, ny, nz``).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

FloatArray = NDArray[np.float64]


@dataclass(frozen=True, slots=True)
class ProbePoint:
    """One point to probe: true position (mm), probing direction (unit vector) and labels."""

    true_mm: tuple[float, float, float]
    probe_dir: tuple[float, float, float] | None = None
    group: str = ""
    """Which feature/measurement it belongs to (e.g. ``"len:xy+:1:rep0:A"``)."""
    travel_dir: tuple[int, int, int] = (0, 0, 0)
    """Direction each axis last moved (+1/−1/0), sent with the reading."""


def _as_points(arr: FloatArray, group: str) -> list[ProbePoint]:
    return [ProbePoint((float(p[0]), float(p[1]), float(p[2])), None, group) for p in arr]


def random_points(
    lower_mm: FloatArray,
    upper_mm: FloatArray,
    n: int,
    rng: np.random.Generator,
    margin: float = 0.02,
) -> list[ProbePoint]:
    """``n`` points uniform in the volume shrunk by ``margin`` (fraction of each axis range)."""
    lo, hi = np.asarray(lower_mm, float), np.asarray(upper_mm, float)
    pad = (hi - lo) * margin
    pts = rng.uniform(lo + pad, hi - pad, (n, 3))
    return _as_points(pts, "random")


@dataclass(frozen=True)
class BallPlate:
    """A square plate of ``n × n`` balls of ``radius_mm`` at ``pitch_mm`` in the XY plane at
    height ``z_mm``, centred in X and Y; each ball is probed at 4 equator points and the pole."""

    centre_mm: tuple[float, float, float]
    n: int = 5
    pitch_mm: float = 150.0
    radius_mm: float = 10.0

    @classmethod
    def fitting(cls, lower_mm: FloatArray, upper_mm: FloatArray, n: int = 5) -> BallPlate:
        """The largest plate covering ~70 % of the smaller of the X and Y travels."""
        lo, hi = np.asarray(lower_mm, float), np.asarray(upper_mm, float)
        span = 0.7 * min(hi[0] - lo[0], hi[1] - lo[1])
        centre = (lo + hi) / 2
        z = lo[2] + 0.3 * (hi[2] - lo[2])
        return cls((float(centre[0]), float(centre[1]), float(z)), n, span / (n - 1))

    def ball_centres(self) -> FloatArray:
        """(n², 3) ball centres, mm, row by row."""
        k = (np.arange(self.n) - (self.n - 1) / 2) * self.pitch_mm
        xx, yy = np.meshgrid(k, k, indexing="xy")
        c = np.asarray(self.centre_mm)
        return np.column_stack([xx.ravel() + c[0], yy.ravel() + c[1], np.full(self.n**2, c[2])])

    def points(self) -> list[ProbePoint]:
        """5 probe points per ball: +X, −X, +Y, −Y equator and the pole (probed downwards)."""
        r = self.radius_mm
        out: list[ProbePoint] = []
        for b, c in enumerate(self.ball_centres()):
            for name, n in (
                ("px", (1.0, 0.0, 0.0)),
                ("mx", (-1.0, 0.0, 0.0)),
                ("py", (0.0, 1.0, 0.0)),
                ("my", (0.0, -1.0, 0.0)),
                ("pz", (0.0, 0.0, 1.0)),
            ):
                p = c + r * np.asarray(n)
                probe = (-n[0], -n[1], -n[2])  # the stylus moves towards the ball centre
                out.append(
                    ProbePoint((float(p[0]), float(p[1]), float(p[2])), probe, f"ball:{b}:{name}")
                )
        return out

    def centres_from(self, measured_mm: FloatArray) -> FloatArray:
        """Ball centres (n², 3) from the 5 measured points of each ball, in :meth:`points` order:
        X from the ±X pair, Y from the ±Y pair, Z from the pole minus the radius."""
        m = np.asarray(measured_mm, float).reshape(self.n**2, 5, 3)
        x = (m[:, 0, 0] + m[:, 1, 0]) / 2
        y = (m[:, 2, 1] + m[:, 3, 1]) / 2
        z = m[:, 4, 2] - self.radius_mm
        return np.column_stack([x, y, z])

    def distance_errors_um(self, measured_mm: FloatArray) -> FloatArray:
        """Errors of all ball-to-ball distances (measured − reference), µm."""
        ref = self.ball_centres()
        got = self.centres_from(measured_mm)
        i, j = np.triu_indices(len(ref), 1)
        d_ref = np.linalg.norm(ref[i] - ref[j], axis=1)
        d_got = np.linalg.norm(got[i] - got[j], axis=1)
        return (d_got - d_ref) * 1000.0
