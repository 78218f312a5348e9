"""Verification measurements (docs/formats.md §2): one row per measured point, read and written as CSV.

Columns: ``x,y,z`` indicated (mm), ``ref_x,ref_y,ref_z`` reference = true position of the stylus
tip (mm) are required; optional ``t`` (s), temperatures ``T_x … T_air`` (°C), ``dir_x …`` (±1),
``nx,ny,nz`` (unit probing direction), ``px,py,pz`` stylus offset (mm), ``v_x,v_y,v_z``
(velocity of each axis at the sample, mm/s, signed: a dense stream's), ``state`` (``rest``,
``steady``, … : what the axis was doing), ``group`` (label).
Unknown columns are kept aside and ignored. The observed error is ``(ref − indicated)·1000`` µm
(error = true − indicated).
"""

from __future__ import annotations

import csv
import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from ..errors import MeasurementFileError
from ..thermal.roles import TEMPERATURE_ROLES

__all__ = [
    "TEMPERATURE_COLUMNS",
    "MeasurementFileError",
    "Measurements",
    "read_measurements",
    "write_measurements",
]

FloatArray = NDArray[np.float64]

REQUIRED = ("x", "y", "z", "ref_x", "ref_y", "ref_z")
TEMPERATURE_COLUMNS = TEMPERATURE_ROLES
DIR_COLUMNS = ("dir_x", "dir_y", "dir_z")
NORMAL_COLUMNS = ("nx", "ny", "nz")
STYLUS_COLUMNS = ("px", "py", "pz")
VELOCITY_COLUMNS = ("v_x", "v_y", "v_z")
_TEXT_COLUMNS = ("group", "state")
NUMERIC = (
    *REQUIRED,
    "t",
    *TEMPERATURE_COLUMNS,
    *DIR_COLUMNS,
    *NORMAL_COLUMNS,
    *STYLUS_COLUMNS,
    *VELOCITY_COLUMNS,
)


@dataclass
class Measurements:
    """N measured points. Optional arrays are None when the file has no such column(s)."""

    indicated_mm: FloatArray  # (N, 3)
    reference_mm: FloatArray  # (N, 3)
    t_s: FloatArray | None = None
    temps_C: dict[str, FloatArray] = field(default_factory=dict)
    directions: dict[str, FloatArray] = field(default_factory=dict)  # dir_x … (±1)
    normals: FloatArray | None = None  # (N, 3)
    stylus_mm: FloatArray | None = None  # (N, 3)
    group: NDArray[np.str_] | None = None
    source: str = "<memory>"
    #: v_x … (mm/s, signed): each axis' velocity at the sample (a dense stream's; diagnosis only)
    velocities: dict[str, FloatArray] = field(default_factory=dict)
    #: what the axis was doing at the sample (``rest``, ``steady``, …; diagnosis only)
    state: NDArray[np.str_] | None = None

    @property
    def n(self) -> int:
        return int(self.indicated_mm.shape[0])

    def observed_error_um(self) -> FloatArray:
        """(N, 3) µm: reference − indicated (true − indicated)."""
        return (self.reference_mm - self.indicated_mm) * 1000.0

    def stylus(self, default_mm: Sequence[float]) -> FloatArray:
        """(N, 3) stylus offsets: the file's, or ``default_mm`` (the machine's) for every point."""
        if self.stylus_mm is not None:
            return self.stylus_mm
        return np.broadcast_to(np.asarray(default_mm, dtype=float), (self.n, 3)).copy()

    def inputs(self) -> dict[str, FloatArray]:
        """Runtime signals other than temperatures (``t``, ``dir_*``, ``nx``…) for the model."""
        out: dict[str, FloatArray] = dict(self.directions)
        if self.t_s is not None:
            out["t"] = self.t_s
        if self.normals is not None:
            for k, name in enumerate(NORMAL_COLUMNS):
                out[name] = self.normals[:, k]
        return out

    def subset(self, index: Any) -> Measurements:
        """The rows selected by ``index`` (boolean mask or integer indices)."""

        def pick(a: Any) -> Any:
            return None if a is None else a[index]

        return Measurements(
            indicated_mm=self.indicated_mm[index],
            reference_mm=self.reference_mm[index],
            t_s=pick(self.t_s),
            temps_C={k: v[index] for k, v in self.temps_C.items()},
            directions={k: v[index] for k, v in self.directions.items()},
            normals=pick(self.normals),
            stylus_mm=pick(self.stylus_mm),
            group=pick(self.group),
            source=self.source,
            velocities={k: v[index] for k, v in self.velocities.items()},
            state=pick(self.state),
        )

    def columns(self) -> dict[str, Any]:
        """Column name → (N,) array, in docs/formats.md §2 order (what :func:`write_measurements` writes)."""
        out: dict[str, Any] = {}
        for k, a in enumerate("xyz"):
            out[a] = self.indicated_mm[:, k]
        for k, a in enumerate("xyz"):
            out[f"ref_{a}"] = self.reference_mm[:, k]
        if self.t_s is not None:
            out["t"] = self.t_s
        out.update({k: self.temps_C[k] for k in TEMPERATURE_COLUMNS if k in self.temps_C})
        out.update({k: self.directions[k] for k in DIR_COLUMNS if k in self.directions})
        if self.normals is not None:
            out.update({c: self.normals[:, k] for k, c in enumerate(NORMAL_COLUMNS)})
        if self.stylus_mm is not None:
            out.update({c: self.stylus_mm[:, k] for k, c in enumerate(STYLUS_COLUMNS)})
        out.update({k: self.velocities[k] for k in VELOCITY_COLUMNS if k in self.velocities})
        if self.state is not None:
            out["state"] = self.state
        if self.group is not None:
            out["group"] = self.group
        return out


def write_measurements(path: str | Path, data: Measurements) -> Path:
    """Write ``data`` as a docs/formats.md §2 CSV (floats with full precision)."""
    cols = data.columns()
    path = Path(path)
    with path.open("w", newline="", encoding="utf-8") as fh:
        writer = csv.writer(fh)
        writer.writerow(list(cols))
        for i in range(data.n):
            writer.writerow(
                [
                    repr(float(v[i])) if k not in _TEXT_COLUMNS else str(v[i])
                    for k, v in cols.items()
                ]
            )
    return path


def _fail(source: str, line: int | None, column: str | None, problem: str) -> MeasurementFileError:
    where = source
    if line is not None:
        where += f": line {line}"
    if column is not None:
        where += f", column {column!r}"
    return MeasurementFileError(f"{where}: {problem}")


def read_measurements(path: str | Path) -> Measurements:
    """Read a measurements CSV; :class:`MeasurementFileError` naming file, line and column."""
    path = Path(path)
    src = str(path)
    try:
        text = path.read_text(encoding="utf-8-sig")
    except FileNotFoundError:
        raise _fail(src, None, None, "no such file") from None
    except (OSError, UnicodeDecodeError) as exc:
        raise _fail(src, None, None, f"cannot read: {exc}") from None
    rows = list(csv.reader(text.splitlines()))
    if not rows or not any(c.strip() for c in rows[0]):
        raise _fail(
            src, 1, None, "empty file: a header row with x,y,z,ref_x,ref_y,ref_z is required"
        )
    header = [h.strip() for h in rows[0]]
    seen: set[str] = set()
    for h in header:
        if h in seen:
            raise _fail(src, 1, h, "duplicate column")
        seen.add(h)
    missing = [c for c in REQUIRED if c not in header]
    if missing:
        raise _fail(src, 1, None, f"missing required column(s) {', '.join(missing)}")
    body = [(i + 2, r) for i, r in enumerate(rows[1:]) if any(c.strip() for c in r)]
    if not body:
        raise _fail(src, 2, None, "no data rows")
    index = {h: k for k, h in enumerate(header)}
    numeric = [c for c in NUMERIC if c in index]
    values = {c: np.empty(len(body)) for c in numeric}
    groups: list[str] = []
    states: list[str] = []
    for r, (line, row) in enumerate(body):
        if len(row) != len(header):
            raise _fail(src, line, None, f"{len(row)} fields, the header has {len(header)}")
        for c in numeric:
            cell = row[index[c]].strip()
            try:
                v = float(cell)
            except ValueError:
                raise _fail(src, line, c, f"not a number: {cell!r}") from None
            if not math.isfinite(v):
                raise _fail(src, line, c, f"not a finite number: {cell!r}")
            if c in DIR_COLUMNS and v not in (1.0, -1.0):
                raise _fail(src, line, c, f"direction must be +1 or -1, got {cell!r}")
            if c in TEMPERATURE_COLUMNS and not -273.15 <= v <= 1000.0:
                raise _fail(src, line, c, f"not a temperature in -273.15…1000 °C: {cell!r}")
            values[c][r] = v
        if "group" in index:
            groups.append(row[index["group"]].strip())
        if "state" in index:
            states.append(row[index["state"]].strip())
        if all(c in index for c in NORMAL_COLUMNS):
            norm = math.sqrt(sum(values[c][r] ** 2 for c in NORMAL_COLUMNS))
            if abs(norm - 1.0) > 0.01:
                raise _fail(
                    src, line, "nx", f"probing direction must be a unit vector, |n| = {norm:.4g}"
                )
    for group_cols in (NORMAL_COLUMNS, STYLUS_COLUMNS):
        present = [c for c in group_cols if c in index]
        if present and len(present) != 3:
            absent = [c for c in group_cols if c not in index]
            raise _fail(
                src,
                1,
                None,
                f"columns {', '.join(group_cols)} go together; missing {', '.join(absent)}",
            )

    columns: dict[str, Any] = dict(values)
    if "group" in index:
        columns["group"] = groups
    if "state" in index:
        columns["state"] = states
    return measurements_from_columns(columns, src)


def measurements_from_columns(columns: Mapping[str, Any], source: str = "<memory>") -> Measurements:
    """Build from a column mapping like :meth:`Measurements.columns` returns."""
    arr = {k: np.asarray(v, dtype=float) for k, v in columns.items() if k not in _TEXT_COLUMNS}

    def stack(cols: Sequence[str]) -> FloatArray | None:
        return np.column_stack([arr[c] for c in cols]) if all(c in arr for c in cols) else None

    ind, ref = stack(REQUIRED[:3]), stack(REQUIRED[3:])
    if ind is None or ref is None:
        raise ValueError("columns x, y, z, ref_x, ref_y, ref_z are required")
    return Measurements(
        indicated_mm=ind,
        reference_mm=ref,
        t_s=arr.get("t"),
        temps_C={c: arr[c] for c in TEMPERATURE_COLUMNS if c in arr},
        directions={c: arr[c] for c in DIR_COLUMNS if c in arr},
        normals=stack(NORMAL_COLUMNS),
        stylus_mm=stack(STYLUS_COLUMNS),
        group=None if "group" not in columns else np.asarray(columns["group"], dtype=str),
        source=source,
        velocities={c: arr[c] for c in VELOCITY_COLUMNS if c in arr},
        state=None if "state" not in columns else np.asarray(columns["state"], dtype=str),
    )
