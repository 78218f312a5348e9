"""Reading the calibration data files' CSV (docs/formats.md §10): a header row, ``#`` comment
lines and blank lines allowed, every problem one :class:`CalibrationError` naming the file, the
line and the column.

:class:`CsvTable` keeps each row's line number, so a check made later (a station with too few
points, a pass whose positions go backwards) can still name the line it is about.
"""

from __future__ import annotations

import csv
import math
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from ..errors import CalibrationError

__all__ = ["TEMPERATURES", "CsvTable", "PointsFile", "read_csv_table"]

FloatArray = NDArray[np.float64]
MAX_ROWS = 2_000_000
TEMPERATURES = ("T_x", "T_y", "T_z", "T_wp")  # optional columns: the plan's thermal terms, °C
#: how far (fraction of each axis' travel) a reading may lie outside the plan's volume: a ball on
#: the volume's edge probed with noise is a reading, not a mistake (the tables' end values hold)
OUTSIDE_TOLERANCE = 0.02


def outside(points_mm: FloatArray, lower_mm: FloatArray, upper_mm: FloatArray) -> NDArray[np.bool_]:
    """(N,) True where a point lies further outside ``lower…upper`` than the tolerance."""
    tol = OUTSIDE_TOLERANCE * (upper_mm - lower_mm)
    return np.any((points_mm < lower_mm - tol) | (points_mm > upper_mm + tol), axis=1)


class PointsFile:
    """What the data of a points file (plate centres, multilateration points) have in common:
    its plan entry ``spec`` (with its ``file``) and the indicated points ``q_mm`` (N, 3)."""

    spec: Any
    q_mm: FloatArray

    @property
    def source(self) -> str:
        return str(self.spec.file)

    @property
    def n(self) -> int:
        return int(self.q_mm.shape[0])


@dataclass(frozen=True)
class CsvTable:
    """The rows of one CSV file: ``header`` (stripped names), ``rows`` (stripped cells) and the
    1-based ``lines`` each row came from."""

    path: Path
    header: tuple[str, ...]
    rows: tuple[tuple[str, ...], ...]
    lines: tuple[int, ...]

    def __len__(self) -> int:
        return len(self.rows)

    def has(self, column: str) -> bool:
        return column in self.header

    def fail(self, row: int | None, column: str | None, problem: str) -> CalibrationError:
        """The error about ``row`` (index into ``rows``; None: the file) and ``column``."""
        where = str(self.path)
        if row is not None:
            where += f": line {self.lines[row]}"
        if column is not None:
            where += f", column '{column}'"
        return CalibrationError(f"{where}: {problem}")

    def text(self, column: str) -> list[str]:
        """The cells of ``column`` as text (it must exist; empty cells refused)."""
        k = self.header.index(column)
        out = [r[k] for r in self.rows]
        for i, cell in enumerate(out):
            if cell == "":
                raise self.fail(i, column, "empty cell; a value is required")
        return out

    def temperatures(self) -> dict[str, FloatArray]:
        """The optional temperature columns present (°C)."""
        return {t: self.numbers(t) for t in TEMPERATURES if self.has(t)}

    def check_inside(
        self, points_mm: FloatArray, lower_mm: FloatArray, upper_mm: FloatArray, what: str
    ) -> None:
        """Refuse the first row whose point (N, 3) mm lies outside ``lower…upper`` (beyond
        :data:`OUTSIDE_TOLERANCE` of the travel)."""
        bad = outside(points_mm, lower_mm, upper_mm)
        if bad.any():
            i = int(np.argmax(bad))
            raise self.fail(
                i, "x", f"{what} {points_mm[i].tolist()} mm is outside the plan's volume"
            )

    def numbers(self, column: str, *, allow_empty: bool = False) -> FloatArray:
        """The cells of ``column`` as finite floats; ``allow_empty``: an empty cell is NaN."""
        k = self.header.index(column)
        out = np.empty(len(self.rows))
        for i, r in enumerate(self.rows):
            cell = r[k]
            if cell == "" and allow_empty:
                out[i] = math.nan
                continue
            try:
                value = float(cell)
            except ValueError:
                raise self.fail(i, column, f"not a number: {cell!r}") from None
            if not math.isfinite(value):
                raise self.fail(i, column, f"not a finite number: {cell!r}")
            out[i] = value
        return out


def read_csv_table(path: Path, required: Sequence[str], optional: Sequence[str] = ()) -> CsvTable:
    """Read ``path``: skip blank and ``#`` lines, take the first other line as the header, which
    must name every ``required`` column (any order); columns neither required nor ``optional``
    are refused (a misspelt column must not be silently ignored). At least one data row."""
    try:
        text = path.read_text(encoding="utf-8-sig")
    except FileNotFoundError:
        raise CalibrationError(f"{path}: no such file") from None
    except (OSError, UnicodeDecodeError) as exc:
        raise CalibrationError(f"{path}: cannot read the file ({exc})") from None
    header: tuple[str, ...] | None = None
    rows: list[tuple[str, ...]] = []
    lines: list[int] = []
    reader = csv.reader(text.splitlines())
    for lineno, cells in enumerate(reader, start=1):
        if not cells or all(c.strip() == "" for c in cells) or cells[0].lstrip().startswith("#"):
            continue
        stripped = tuple(c.strip() for c in cells)
        if header is None:
            header = stripped
            _check_header(path, lineno, header, required, optional)
            continue
        if len(stripped) != len(header):
            raise CalibrationError(
                f"{path}: line {lineno}: {len(stripped)} fields, the header has {len(header)}"
            )
        rows.append(stripped)
        lines.append(lineno)
        if len(rows) > MAX_ROWS:
            raise CalibrationError(f"{path}: more than {MAX_ROWS} rows")
    if header is None:
        raise CalibrationError(
            f"{path}: empty file: expected a header naming {', '.join(required)}"
        )
    if not rows:
        raise CalibrationError(f"{path}: no data rows after the header")
    return CsvTable(path=path, header=header, rows=tuple(rows), lines=tuple(lines))


def _check_header(
    path: Path,
    lineno: int,
    header: tuple[str, ...],
    required: Sequence[str],
    optional: Sequence[str],
) -> None:
    dup = sorted({h for h in header if header.count(h) > 1})
    if dup:
        raise CalibrationError(f"{path}: line {lineno}: column(s) {dup} named twice")
    missing = [c for c in required if c not in header]
    if missing:
        raise CalibrationError(
            f"{path}: line {lineno}: missing column(s) {', '.join(missing)}; the header must name "
            f"{', '.join(required)}"
        )
    unknown = [c for c in header if c not in required and c not in optional]
    if unknown:
        raise CalibrationError(
            f"{path}: line {lineno}: unknown column(s) {', '.join(unknown)}; allowed: "
            f"{', '.join([*required, *optional])}"
        )
