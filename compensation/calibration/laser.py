"""Laser interferometer runs (docs/formats.md §10.2): the CSV of runs, or an ISO 230-2 ``.dat``
file of one axis' positional error, read into :class:`LaserRun` objects and checked.

CSV columns: ``axis,quantity,position_mm,value,direction,run,line_x_mm,line_y_mm,line_z_mm,
optic_offset_x_mm,optic_offset_y_mm,optic_offset_z_mm`` (optional ``T_x,T_y,T_z,T_wp``). Row
order is the order measured; a *pass* is a maximal block of consecutive rows of one run with
the same ``direction``; its positions must run strictly the way it says (increasing for +1).
Values are errors, true − indicated: µm (``linear_um``, ``straightness_<dir>_um``), µrad
(``pitch_urad``, ``yaw_urad``, ``roll_urad``, ``squareness_urad``).
"""

from __future__ import annotations

import itertools
from dataclasses import dataclass, field

import numpy as np
from numpy.typing import NDArray

from ..errors import CalibrationError, RealDataError
from ..parametric_errors import AXES, AXIS_INDEX
from .csvtable import TEMPERATURES, CsvTable, outside, read_csv_table
from .plan import LaserSpec

__all__ = [
    "ANGLE_AXIS",
    "LaserData",
    "LaserRun",
    "read_laser",
]

FloatArray = NDArray[np.float64]
IntArray = NDArray[np.intp]

COLUMNS = (
    "axis",
    "quantity",
    "position_mm",
    "value",
    "direction",
    "run",
    "line_x_mm",
    "line_y_mm",
    "line_z_mm",
    "optic_offset_x_mm",
    "optic_offset_y_mm",
    "optic_offset_z_mm",
)
#: rotation axis read by pitch/yaw/roll on each moving axis (the issue's mapping)
ANGLE_AXIS = {
    "x": {"roll": "x", "pitch": "y", "yaw": "z"},
    "y": {"roll": "y", "pitch": "x", "yaw": "z"},
    "z": {"roll": "z", "pitch": "y", "yaw": "x"},
}
SQUARENESS_PAIRS = {"xy": (0, 1), "xz": (0, 2), "yz": (1, 2)}
KINDS = ("linear", "straightness", "angle", "squareness")


@dataclass(frozen=True)
class LaserRun:
    """One run: one quantity along one line (or the squareness rows sharing a run id).

    ``kind`` linear | straightness | angle | squareness; ``axis`` the moving axis (0, 1, 2; for
    squareness the first of the pair); ``component``: the error component read (the moving axis
    for linear, the displacement direction for straightness, the rotation axis for an angle, the
    second axis of a squareness pair). ``points_mm`` (n, 3) indicated positions of the optic's
    reference point (for squareness the crossing point), ``optic_mm`` (3,), ``passes`` the row
    indices of each pass (straightness lines are removed per pass)."""

    source: str
    run: str
    quantity: str
    kind: str
    axis: int
    component: int
    position_mm: FloatArray
    value: FloatArray
    direction: FloatArray
    points_mm: FloatArray
    optic_mm: FloatArray
    lines: tuple[int, ...]
    passes: tuple[IntArray, ...]
    temps_C: dict[str, FloatArray] = field(default_factory=dict)

    @property
    def n(self) -> int:
        return int(self.value.shape[0])

    @property
    def label(self) -> str:
        return f"{self.source} run {self.run} ({self.quantity}, {AXES[self.axis]})"


@dataclass(frozen=True)
class LaserData:
    """The runs of one ``[[laser]]`` entry."""

    spec: LaserSpec
    runs: tuple[LaserRun, ...]

    @property
    def source(self) -> str:
        return str(self.spec.file)


def _quantity(table: CsvTable, i: int, axis: str, quantity: str) -> tuple[str, int, int]:
    """(kind, moving axis, component) of one row, refused with its line when inconsistent."""
    if quantity == "squareness_urad":
        pair = SQUARENESS_PAIRS.get(axis) or SQUARENESS_PAIRS.get(axis[::-1])
        if pair is None:
            raise table.fail(i, "axis", f"squareness needs xy, xz or yz, got {axis!r}")
        return "squareness", pair[0], pair[1]
    if axis not in AXES:
        raise table.fail(i, "axis", f"expected x, y or z (xy, xz, yz for squareness), got {axis!r}")
    k = AXIS_INDEX[axis]
    if quantity == "linear_um":
        return "linear", k, k
    if quantity.startswith("straightness_") and quantity.endswith("_um"):
        d = quantity[len("straightness_") : -len("_um")]
        if d not in AXES or d == axis:
            raise table.fail(
                i,
                "quantity",
                f"{quantity}: the direction must be one of the two axes "
                f"perpendicular to {axis} ({', '.join(a for a in AXES if a != axis)})",
            )
        return "straightness", k, AXIS_INDEX[d]
    for name, rot in ANGLE_AXIS[axis].items():
        if quantity == f"{name}_urad":
            return "angle", k, AXIS_INDEX[rot]
    raise table.fail(
        i,
        "quantity",
        f"unknown quantity {quantity!r}; allowed: linear_um, straightness_<dir>_um, pitch_urad, "
        "yaw_urad, roll_urad, squareness_urad",
    )


def read_laser(
    spec: LaserSpec,
    lower_mm: FloatArray,
    upper_mm: FloatArray,
    reference_mm: FloatArray,
    *,
    need_values: bool = True,
) -> LaserData:
    """Read one ``[[laser]]`` entry; every position must lie in the volume ``lower…upper``.
    ``need_values`` False (the planner): empty ``value`` cells are allowed (NaN)."""
    runs = _read_dat(spec, reference_mm) if spec.is_iso230 else _read_csv(spec, need_values)
    for run in runs:
        _check_inside(run, lower_mm, upper_mm)
    return LaserData(spec=spec, runs=tuple(runs))


def _read_csv(spec: LaserSpec, need_values: bool) -> list[LaserRun]:
    table = read_csv_table(spec.file, COLUMNS, TEMPERATURES)
    axis_txt = [a.lower() for a in table.text("axis")]
    quantity = [q.lower() for q in table.text("quantity")]
    run_id = table.text("run")
    value = table.numbers("value", allow_empty=not need_values)
    position = table.numbers("position_mm", allow_empty=True)
    direction = table.numbers("direction", allow_empty=True)
    line = np.column_stack([table.numbers(f"line_{a}_mm", allow_empty=True) for a in AXES])
    optic = np.column_stack([table.numbers(f"optic_offset_{a}_mm") for a in AXES])
    temps = table.temperatures()
    kinds = [_quantity(table, i, axis_txt[i], quantity[i]) for i in range(len(table))]
    for i, (kind, axis, _) in enumerate(kinds):
        # the moving axis' own line cell may be empty (it is the position); the rest is needed
        needed = [k for k in range(3) if kind == "squareness" or k != axis]
        for k in needed:
            if np.isnan(line[i, k]):
                raise table.fail(i, f"line_{AXES[k]}_mm", "empty: where the other axes stand")
        if kind != "squareness":
            line[i, axis] = 0.0 if np.isnan(line[i, axis]) else line[i, axis]
            if np.isnan(position[i]):
                raise table.fail(i, "position_mm", "empty: a run's row needs its position")
            if direction[i] not in (1.0, -1.0):
                raise table.fail(i, "direction", f"must be +1 or -1, got {direction[i]:g}")
    # a run: the rows of one run id, quantity and axis on one line with one optic (the file
    # order kept); a run id reused for another quantity, axis or line starts another run
    order: dict[tuple[object, ...], list[int]] = {}
    for i, r in enumerate(run_id):
        kind, axis, comp = kinds[i]
        if kind == "squareness":
            key: tuple[object, ...] = (r, kind, axis, comp)
        else:
            others = [k for k in range(3) if k != axis]
            key = (r, kind, axis, comp, *np.round(line[i, others], 6), *np.round(optic[i], 6))
        order.setdefault(key, []).append(i)
    runs = []
    for key, rows in order.items():
        rid = str(key[0])
        idx = np.asarray(rows, dtype=np.intp)
        first = rows[0]
        kind, axis, comp = kinds[first]
        points = line[idx].copy()
        if kind != "squareness":
            points[:, axis] = position[idx]
        run = LaserRun(
            source=str(spec.file),
            run=rid,
            quantity=quantity[first],
            kind=kind,
            axis=axis,
            component=comp,
            position_mm=position[idx] if kind != "squareness" else np.zeros(len(idx)),
            value=value[idx],
            direction=np.nan_to_num(direction[idx]),
            points_mm=points,
            optic_mm=optic[first].copy(),
            lines=tuple(table.lines[i] for i in rows),
            passes=_passes(table, rows, kind, position, direction),
            temps_C={t: v[idx] for t, v in temps.items()},
        )
        _check_counts(table, rows, run)
        runs.append(run)
    return runs


def _passes(
    table: CsvTable, rows: list[int], kind: str, position: FloatArray, direction: FloatArray
) -> tuple[IntArray, ...]:
    """Row indices (local to the run) of each pass; positions strictly monotonic in a pass."""
    if kind == "squareness":
        return (np.arange(len(rows), dtype=np.intp),)
    out: list[IntArray] = []
    start = 0
    for j in range(1, len(rows) + 1):
        if j == len(rows) or direction[rows[j]] != direction[rows[start]]:
            out.append(np.arange(start, j, dtype=np.intp))
            start = j
    for p in out:
        sign = direction[rows[p[0]]]
        for a, b in itertools.pairwise(p):
            step = (position[rows[b]] - position[rows[a]]) * sign
            if not step > 0:
                want = "increase" if sign > 0 else "decrease"
                raise table.fail(
                    rows[b],
                    "position_mm",
                    f"not monotonic: in a pass with direction {sign:+g} positions must {want} "
                    f"strictly (previous row, line {table.lines[rows[a]]}: "
                    f"{position[rows[a]]:g} mm, this row: {position[rows[b]]:g} mm)",
                )
    return tuple(out)


def _check_counts(table: CsvTable, rows: list[int], run: LaserRun) -> None:
    if run.kind == "straightness":
        for p in run.passes:
            if len(p) < 3:
                raise table.fail(
                    rows[p[0]],
                    "run",
                    f"run {run.run!r}: a straightness pass needs ≥ 3 rows "
                    f"(its least-squares line is removed), this one has {len(p)}",
                )
    elif run.kind in ("linear", "angle") and run.n < 2:
        raise table.fail(
            rows[0],
            "run",
            f"run {run.run!r}: a {run.quantity} run needs ≥ 2 rows (its values "
            "are relative to its first row)",
        )


def _check_inside(run: LaserRun, lower: FloatArray, upper: FloatArray) -> None:
    bad = np.flatnonzero(outside(run.points_mm, lower, upper))
    if bad.size:
        i = int(bad[0])
        raise CalibrationError(
            f"{run.source}: line {run.lines[i]}: point {run.points_mm[i].tolist()} mm is outside "
            f"the plan's volume {lower.tolist()} … {upper.tolist()} mm"
        )


def _read_dat(spec: LaserSpec, reference_mm: FloatArray) -> list[LaserRun]:
    """An ISO 230-2 file: one linear run per cycle (forward then backward pass), values
    (reference − target)·1000 µm, the other axes at ``line_mm`` (default the reference point)."""
    from ..formats.realdata import read_iso230_dat

    try:
        data = read_iso230_dat(spec.file)
    except RealDataError as exc:
        raise CalibrationError(str(exc)) from None
    assert spec.axis is not None
    k = AXIS_INDEX[spec.axis]
    n_cycles = data.fwd_mm.shape[1]
    cycles = spec.cycles or tuple(range(1, n_cycles + 1))
    bad = [c for c in cycles if c > n_cycles]
    if bad:
        raise CalibrationError(
            f"{spec.file}: {spec.where}.cycles names cycle {bad[0]} but the file has {n_cycles}"
        )
    target = data.target_mm
    order = np.argsort(target)
    if np.any(np.diff(target[order]) <= 0):
        raise CalibrationError(f"{spec.file}: TGT_DATA: target positions repeat")
    line = np.asarray(reference_mm if spec.line_mm is None else spec.line_mm, dtype=float)
    optic = np.zeros(3) if spec.optic_offset_mm is None else spec.optic_offset_mm
    runs = []
    m = len(target)
    for c in cycles:
        pos = np.concatenate([target[order], target[order[::-1]]])
        ref = np.concatenate([data.fwd_mm[order, c - 1], data.bwd_mm[order[::-1], c - 1]])
        points = np.repeat(line[None, :], 2 * m, axis=0)
        points[:, k] = pos
        runs.append(
            LaserRun(
                source=str(spec.file),
                run=f"cycle-{c}",
                quantity="linear_um",
                kind="linear",
                axis=k,
                component=k,
                position_mm=pos,
                value=(ref - pos) * 1000.0,
                direction=np.concatenate([np.ones(m), -np.ones(m)]),
                points_mm=points,
                optic_mm=np.asarray(optic, dtype=float),
                lines=tuple([0] * (2 * m)),
                passes=(np.arange(m, dtype=np.intp), np.arange(m, 2 * m, dtype=np.intp)),
            )
        )
    return runs
