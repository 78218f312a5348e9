"""Sequential multilateration (docs/formats.md §10.4): ``station,point,x,y,z,length_mm`` (and
optionally ``T_x,T_y,T_z,T_wp``), read and checked.

The machine moves the reflector to the indicated point (x, y, z) mm; the tracking
interferometer at ``station`` reports a length (mm) with an unknown dead-path offset per
station, so a length may be negative. Stations are numbered in order of first appearance; the
plan gives one rough position per station (``station_guess_mm``).

The rows of a station are in the order measured (the program's order): each axis' last
direction of travel at a row is the sign of its move from the station's previous row (an axis
that did not move keeps its direction; unknown, 0, before its first move). The machine's
reversal (backlash) follows that direction: along a program of points in random order it is
correlated with the position (a point near the top of an axis is mostly reached moving up), so
a fit that ignored it would read half the reversal step as a scale error (docs/calibration.md).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from numpy.typing import NDArray

from ..errors import CalibrationError
from ..parametric_errors import AXES
from .csvtable import TEMPERATURES, PointsFile, read_csv_table
from .plan import MultilaterationSpec

__all__ = [
    "MIN_POINTS_PER_STATION",
    "MIN_STATIONS",
    "MultilaterationData",
    "read_multilateration",
    "travel_directions",
]

FloatArray = NDArray[np.float64]
IntArray = NDArray[np.intp]
MIN_POINTS_PER_STATION = 4
MIN_STATIONS = 4


@dataclass(frozen=True)
class MultilaterationData(PointsFile):
    """One ``[[multilateration]]`` entry: ``stations`` (names, order of first appearance),
    ``station`` index per row, ``q_mm`` (N, 3) indicated points, ``length_mm`` (N,), ``point``
    per row the index of its shared point (the same ``point`` label at the same indicated
    position, measured from ≥ 2 stations; −1 for a point one station alone measured);
    ``direction`` (N, 3) each axis' last direction of travel at the row (±1, 0 unknown:
    :func:`travel_directions`)."""

    spec: MultilaterationSpec
    stations: tuple[str, ...]
    station: IntArray
    q_mm: FloatArray
    length_mm: FloatArray
    lines: tuple[int, ...]
    temps_C: dict[str, FloatArray] = field(default_factory=dict)
    point: IntArray = field(default_factory=lambda: np.zeros(0, dtype=np.intp))
    direction: FloatArray = field(default_factory=lambda: np.zeros((0, 3)))

    @property
    def n_points(self) -> int:
        """Shared points (measured from ≥ 2 stations)."""
        return int(self.point.max(initial=-1)) + 1


def travel_directions(station: IntArray, q_mm: FloatArray) -> FloatArray:
    """(N, 3) each axis' last direction of travel (+1, −1; 0 unknown) at every row: the sign
    of the axis' move from the previous row of the same station (rows in the order measured);
    an axis that did not move keeps its last direction; 0 until its first move."""
    out = np.zeros((station.shape[0], 3))
    for k in np.unique(station):
        rows = np.flatnonzero(station == k)
        step = np.sign(np.diff(q_mm[rows], axis=0))
        last = np.zeros(3)
        for i, s in zip(rows[1:], step, strict=True):
            last = np.where(s != 0.0, s, last)
            out[i] = last
    return out


def shared_points(labels: list[str], q_mm: FloatArray) -> IntArray:
    """Per row the index of its point among those measured more than once (same label, same
    indicated position to 1 µm), −1 for a point measured once."""
    keys = [(lab, *np.round(q, 3).tolist()) for lab, q in zip(labels, q_mm, strict=True)]
    count: dict[tuple[object, ...], int] = {}
    for k in keys:
        count[k] = count.get(k, 0) + 1
    index: dict[tuple[object, ...], int] = {}
    out = np.full(len(keys), -1, dtype=np.intp)
    for i, k in enumerate(keys):
        if count[k] > 1:
            out[i] = index.setdefault(k, len(index))
    return out


def read_multilateration(
    spec: MultilaterationSpec,
    lower_mm: FloatArray,
    upper_mm: FloatArray,
    *,
    need_values: bool = True,
) -> MultilaterationData:
    """Read one ``[[multilateration]]`` entry: ≥ 4 stations, ≥ 4 points each, one guess per
    station, points within the plan's volume. ``need_values`` False (the planner): empty
    ``length_mm`` cells are allowed (NaN)."""
    table = read_csv_table(
        spec.file,
        ("station", "point", "x", "y", "z", "length_mm"),
        TEMPERATURES,
    )
    q = np.column_stack([table.numbers(a) for a in AXES])
    length = table.numbers("length_mm", allow_empty=not need_values)
    names = table.text("station")
    labels = list(table.text("point"))  # any label: the same label = the same point
    stations: list[str] = []
    first: list[int] = []
    idx = np.empty(len(table), dtype=np.intp)
    for i, s in enumerate(names):
        if s not in stations:
            stations.append(s)
            first.append(i)
        idx[i] = stations.index(s)
    for k, name in enumerate(stations):
        count = int(np.sum(idx == k))
        if count < MIN_POINTS_PER_STATION:
            raise table.fail(
                first[k],
                "station",
                f"station {name!r} has {count} point(s); a station's "
                f"position and dead path need ≥ {MIN_POINTS_PER_STATION}",
            )
    if len(stations) < MIN_STATIONS:
        raise table.fail(
            None,
            "station",
            f"{len(stations)} station(s) ({', '.join(stations)}); "
            f"multilateration with unknown station positions needs ≥ {MIN_STATIONS}",
        )
    if spec.station_guess_mm.shape[0] != len(stations):
        raise CalibrationError(
            f"{spec.file}: the file has {len(stations)} stations ({', '.join(stations)}) but "
            f"{spec.where}.station_guess_mm gives {spec.station_guess_mm.shape[0]} positions: "
            "one per station, in order of first appearance"
        )
    table.check_inside(q, lower_mm, upper_mm, "point")
    temps = table.temperatures()
    return MultilaterationData(
        spec=spec,
        stations=tuple(stations),
        station=idx,
        q_mm=q,
        length_mm=length,
        lines=table.lines,
        temps_C=temps,
        point=shared_points(labels, q),
        direction=travel_directions(idx, q),
    )
