"""Volumetric error maps, space diagonals and 1-D line reports (paper §5.2).

Units: positions mm, errors µm. Error = true − indicated. ``stylus_mm=None`` everywhere means the
machine's probe offset (:meth:`Machine.stylus_or_probe`). A *length error* is true − indicated
length (the same convention): for a length between indicated points P1 and P2 with errors e1, e2
it is ``|P2 + e2 − P1 − e1| − |P2 − P1|`` (exact, µm).
"""

from __future__ import annotations

import csv
from collections.abc import Callable, Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from ..formats.atomic import atomic_output
from ..machine import Machine

FloatArray = NDArray[np.float64]
ProgressFn = Callable[[float], None]
DEFAULT_STEPS = (11, 11, 11)
MAX_MAP_NODES = 50_000_000
MAX_LINE_SAMPLES = 1_000_000
_CHUNK = 200_000
#: a larger |error| is no machine error (a unit mistake, a corrupt table): refused, so that the
#: lengths, norms and squares of the reports stay finite (was inf/NaN printed and written as valid)
MAX_ERROR_UM = 1e9


def _stylus(machine: Machine, stylus_mm: ArrayLike | None) -> FloatArray:
    p = machine.stylus_or_probe(stylus_mm)
    if not np.all(np.isfinite(p)):
        raise ValueError(
            f"the stylus offset (--probe) must be finite numbers (mm), got {p.tolist()}"
        )
    return p


def model_error_um(
    machine: Machine,
    points_mm: FloatArray,
    stylus_mm: FloatArray,
    temps_C: Mapping[str, Any] | None,
) -> FloatArray:
    """``machine.volumetric_error``; ValueError naming the first point whose error is not a
    finite number within ±:data:`MAX_ERROR_UM`."""
    err = machine.volumetric_error(points_mm, stylus_mm, temps_C)
    with np.errstate(invalid="ignore"):
        bad = ~np.all(np.abs(err) <= MAX_ERROR_UM, axis=1)
    if bad.any():
        i = int(np.argmax(bad))
        raise ValueError(
            f"the machine model's error at {np.asarray(points_mm)[i].tolist()} mm is "
            f"{err[i].tolist()} µm: not a finite error within ±{MAX_ERROR_UM:g} µm (check the "
            "machine description's error tables, µm and µrad, and the temperatures)"
        )
    return err


@dataclass(frozen=True)
class VolumetricMap:
    """Error at every node of the nominal grid: ``points_mm`` (N, 3), ``error_um`` (N, 3),
    ``random_um`` (N, 3) or None; nodes in C order over (x, y, z): z varies fastest."""

    axes_mm: tuple[FloatArray, FloatArray, FloatArray]
    points_mm: FloatArray
    error_um: FloatArray
    random_um: FloatArray | None
    stylus_mm: FloatArray

    @property
    def steps(self) -> tuple[int, int, int]:
        return (len(self.axes_mm[0]), len(self.axes_mm[1]), len(self.axes_mm[2]))

    def write_csv(self, path: str | Path) -> None:
        """CSV ``x,y,z,ex,ey,ez`` (+ ``rx,ry,rz`` when random data exists), docs/formats.md §3."""
        header = ["x", "y", "z", "ex", "ey", "ez"]
        cols = [self.points_mm, self.error_um]
        if self.random_um is not None:
            header += ["rx", "ry", "rz"]
            cols.append(self.random_um)
        table = np.hstack(cols)
        write_csv_atomic(Path(path), header, table)


def check_steps(steps: ArrayLike) -> tuple[int, int, int]:
    """Validate grid steps: three integers ≥ 2 and a bounded node count."""
    s = tuple(int(v) for v in np.asarray(steps).ravel())
    if len(s) != 3 or any(v < 2 for v in s):
        raise ValueError(f"steps must be three integers ≥ 2, got {list(s)}")
    if s[0] * s[1] * s[2] > MAX_MAP_NODES:
        raise ValueError(f"{s[0]}×{s[1]}×{s[2]} nodes is more than the limit of {MAX_MAP_NODES}")
    return s  # type: ignore[return-value]


def volumetric_map(
    machine: Machine,
    steps: ArrayLike | None = None,
    stylus_mm: ArrayLike | None = None,
    temps_C: Mapping[str, Any] | None = None,
    progress: ProgressFn | None = None,
) -> VolumetricMap:
    """The volumetric error at every node (``steps`` nodes per axis; default the machine's)."""
    s = check_steps(steps if steps is not None else (machine.volume.steps or DEFAULT_STEPS))
    p = _stylus(machine, stylus_mm)
    axes = machine.volume.nodes(s)
    grid = np.stack(np.meshgrid(*axes, indexing="ij"), axis=-1).reshape(-1, 3)
    err = np.empty_like(grid)
    for start in range(0, len(grid), _CHUNK):
        sl = slice(start, start + _CHUNK)
        err[sl] = model_error_um(machine, grid[sl], p, temps_C)
        if progress:
            progress(min(1.0, (start + _CHUNK) / len(grid)))
    rnd = machine.random_error(grid, p) if machine.has_random else None
    return VolumetricMap(axes_mm=axes, points_mm=grid, error_um=err, random_um=rnd, stylus_mm=p)


def diagonal_endpoints(machine: Machine) -> list[tuple[FloatArray, FloatArray]]:
    """The 4 space diagonals in the paper's order (§6.1): from (0,0,0), (Xmax,0,0), (0,Ymax,0),
    (0,0,Zmax) to the opposite corner, in the working volume's coordinates."""
    lo, hi = machine.volume.lower_mm, machine.volume.upper_mm
    starts = [(0, 0, 0), (1, 0, 0), (0, 1, 0), (0, 0, 1)]
    out = []
    for s in starts:
        a = np.where(np.array(s) == 1, hi, lo)
        b = np.where(np.array(s) == 1, lo, hi)
        out.append((a.astype(float), b.astype(float)))
    return out


def length_error_um(
    machine: Machine,
    start_mm: ArrayLike,
    end_mm: ArrayLike,
    stylus_mm: ArrayLike | None = None,
    temps_C: Mapping[str, Any] | None = None,
) -> float:
    """True − indicated length (µm) of the segment between two indicated points (exact)."""
    a, b = np.asarray(start_mm, dtype=float), np.asarray(end_mm, dtype=float)
    p = _stylus(machine, stylus_mm)
    e = model_error_um(machine, np.stack([a, b]), p, temps_C) / 1000.0
    true_len = np.linalg.norm((b + e[1]) - (a + e[0]))
    return float((true_len - np.linalg.norm(b - a)) * 1000.0)


def diagonals_um(
    machine: Machine, stylus_mm: ArrayLike | None = None, temps_C: Mapping[str, Any] | None = None
) -> list[float]:
    """Length errors (µm) along the 4 space diagonals, paper's order."""
    return [
        length_error_um(machine, a, b, stylus_mm, temps_C) for a, b in diagonal_endpoints(machine)
    ]


@dataclass(frozen=True)
class LineReport:
    """Errors along a line parallel to one axis through a point (paper's 1-D display)."""

    axis: str
    through_mm: FloatArray
    position_mm: FloatArray  # along the axis
    error_um: FloatArray  # (n, 3)
    resultant_um: FloatArray  # (n,) length of the error vector

    @property
    def bandwidth_um(self) -> float:
        """Peak-to-valley of the resultant."""
        return float(np.ptp(self.resultant_um))

    @property
    def max_um(self) -> float:
        return float(np.max(self.resultant_um))

    def component_bandwidths_um(self) -> list[float]:
        return [float(v) for v in np.ptp(self.error_um, axis=0)]

    def write_csv(self, path: str | Path) -> None:
        table = np.column_stack([self.position_mm, self.error_um, self.resultant_um])
        write_csv_atomic(Path(path), [self.axis, "ex", "ey", "ez", "resultant"], table)

    def summary(self) -> dict[str, Any]:
        return {
            "axis": self.axis,
            "through_mm": self.through_mm.tolist(),
            "bandwidth_um": self.bandwidth_um,
            "max_um": self.max_um,
            "component_bandwidth_um": dict(
                zip(("ex", "ey", "ez"), self.component_bandwidths_um(), strict=True)
            ),
        }


def line_report(
    machine: Machine,
    axis: str,
    through_mm: ArrayLike,
    samples: int = 101,
    stylus_mm: ArrayLike | None = None,
    temps_C: Mapping[str, Any] | None = None,
) -> LineReport:
    """ΔX, ΔY, ΔZ and resultant along a line parallel to ``axis`` through ``through_mm``."""
    if axis not in ("x", "y", "z"):
        raise ValueError(f"axis must be x, y or z, got {axis!r}")
    if not 2 <= samples <= MAX_LINE_SAMPLES:  # 1e9 ran out of memory (a traceback)
        raise ValueError(f"samples must be 2…{MAX_LINE_SAMPLES}, got {samples}")
    k = "xyz".index(axis)
    point = np.asarray(through_mm, dtype=float)
    if point.shape != (3,) or not np.all(np.isfinite(point)):
        raise ValueError(
            f"the line's point must be (x, y, z) in mm, finite numbers, got {point.tolist()}"
        )
    q = np.linspace(machine.volume.lower_mm[k], machine.volume.upper_mm[k], samples)
    pts = np.repeat(point[None, :], samples, axis=0)
    pts[:, k] = q
    p = _stylus(machine, stylus_mm)
    err = model_error_um(machine, pts, p, temps_C)
    return LineReport(
        axis=axis,
        through_mm=point,
        position_mm=q,
        error_um=err,
        resultant_um=np.linalg.norm(err, axis=1),
    )


def write_csv_atomic(path: Path, header: list[str], table: FloatArray) -> None:
    """Write a numeric CSV via a temporary file and rename: nothing partial is ever left."""
    with atomic_output(path) as fh:
        w = csv.writer(fh)
        w.writerow(header)
        for row in table:
            w.writerow([f"{v:.6f}" if abs(v) >= 1e-3 or v == 0 else f"{v:.6e}" for v in row])
