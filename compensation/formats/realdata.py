"""Importers for real ISO 230-2 runs: ecmc ``key=value`` .dat files and raw EPICS camonitor logs.

Two sources, one result type (:class:`Iso230Run`):

- :func:`read_iso230_dat` reads the ``TGT_DATA[i]`` / ``REF_DATA_FWD[i,c]`` / ``REF_DATA_BWD[i,c]``
  input files written by the ecmc motion test tools (mm).
- :func:`read_camonitor_log` reads a raw ``camonitor`` stream (``PV date time value [alarm…]``)
  into per-PV time series; :func:`iso230_points_from_log` recovers every approach of the test from
  it (time, target, raw reference, encoder) and :func:`iso230_run_from_points` maps the raw
  reference linearly to the target frame and assembles the run.

From a run: :func:`error_table_from_run` gives the machine description's positional error table
(docs/formats.md §1) and :func:`measurement_rows` / :func:`write_measurements_csv` the measurements
table (docs/formats.md §2). Error sign: error = true − indicated = reference − target, the ISO 230-2
deviation x_ij itself (see ``docs/iso230.md``).
"""

from __future__ import annotations

import csv
import math
import re
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
from numpy.typing import NDArray

from ..errors import RealDataError
from ..reports.iso230 import Iso230Result, evaluate_iso230

__all__ = [
    "ApproachPoint",
    "Iso230Run",
    "PvSeries",
    "RealDataError",
    "error_table_from_run",
    "iso230_points_from_log",
    "iso230_run_from_points",
    "measurement_rows",
    "read_camonitor_log",
    "read_iso230_dat",
    "write_measurements_csv",
]

AXES = ("x", "y", "z")
_UNIT_TO_MM = {"mm": 1.0, "um": 1e-3, "µm": 1e-3, "m": 1e3}


@dataclass(frozen=True, eq=False)
class Iso230Run:
    """One bidirectional ISO 230-2 run of one axis, positions in mm.

    ``fwd_mm[i, c]`` / ``bwd_mm[i, c]``: reference (true) position reached at target i, cycle c,
    approaching in the positive / negative direction. ``time_fwd_s`` etc. are seconds since the
    session start and ``encoder_*_mm`` the axis' own (indicated) position, when a raw log gave them.
    """

    target_mm: NDArray[np.float64]
    fwd_mm: NDArray[np.float64]
    bwd_mm: NDArray[np.float64]
    source: str = ""
    meta: Mapping[str, str] = field(default_factory=dict)
    time_fwd_s: NDArray[np.float64] | None = None
    time_bwd_s: NDArray[np.float64] | None = None
    encoder_fwd_mm: NDArray[np.float64] | None = None
    encoder_bwd_mm: NDArray[np.float64] | None = None

    def evaluate(self) -> Iso230Result:
        """ISO 230-2 evaluation of this run (µm)."""
        return evaluate_iso230(self.target_mm, self.fwd_mm, self.bwd_mm)


# ------------------------------------------------------------------------------------ .dat files
_KEY_RE = re.compile(r"^(?P<name>[A-Za-z_][A-Za-z0-9_]*)(?:\[(?P<idx>[^\]]*)\])?$")
_INDEXED = {"TGT_DATA": 1, "REF_DATA_FWD": 2, "REF_DATA_BWD": 2}


def _parse_float(text: str, where: str) -> float:
    try:
        value = float(text)
    except ValueError:
        raise RealDataError(f"{where}: value {text!r} is not a number") from None
    if not math.isfinite(value):
        raise RealDataError(f"{where}: value {text!r} is not finite")
    return value


def read_iso230_dat(path: str | Path) -> Iso230Run:
    """Read an ecmc ISO 230-2 ``key=value`` input file (``TGT_DATA[i]``, ``REF_DATA_FWD[i,c]``, …).

    Indices are 1-based; every position must have a target and every (position, cycle) a forward
    and a backward reading. ``UNIT`` (mm default, also um/µm/m) scales all values to mm;
    ``CYCLES``/``POSITIONS``, when given, must match the data. Comment lines (``#``), blank lines
    and the free-text ``TEST_DATA=`` header are skipped; other scalar keys land in ``meta``.

    Raises:
        RealDataError: naming the file, the line and the problem, for any malformed input.
    """
    path = Path(path)
    try:
        text = path.read_text(encoding="utf-8", errors="strict")
    except (OSError, UnicodeDecodeError) as exc:
        raise RealDataError(f"{path}: cannot read ISO 230-2 data file: {exc}") from None
    meta: dict[str, str] = {}
    values: dict[str, dict[tuple[int, ...], float]] = {k: {} for k in _INDEXED}
    lines_of: dict[str, int] = {}
    for lineno, raw in enumerate(text.splitlines(), start=1):
        line = raw.strip()
        where = f"{path}:{lineno}"
        if not line or line.startswith("#"):
            continue
        key, sep, value = line.partition("=")
        key, value = key.strip(), value.strip()
        if not sep:
            raise RealDataError(f"{where}: expected 'KEY=value', got {raw.strip()!r}")
        m = _KEY_RE.match(key)
        if m is None:
            raise RealDataError(f"{where}: malformed key {key!r}")
        name, idx_text = m.group("name"), m.group("idx")
        if key in lines_of:
            raise RealDataError(f"{where}: duplicate key {key!r} (first on line {lines_of[key]})")
        lines_of[key] = lineno
        if name not in _INDEXED:
            if idx_text is not None:
                raise RealDataError(f"{where}: unexpected index on key {key!r}")
            meta[name] = value
            continue
        want = _INDEXED[name]
        parts = [] if idx_text is None else [p.strip() for p in idx_text.split(",")]
        if len(parts) != want or not all(p.isdigit() and int(p) >= 1 for p in parts):
            form = "[i]" if want == 1 else "[i,c]"
            raise RealDataError(
                f"{where}: key {key!r} needs {want} index(es) >= 1, as {name}{form}"
            )
        values[name][tuple(int(p) for p in parts)] = _parse_float(value, f"{where} ({key})")
    return _assemble_dat(path, meta, values, lines_of)


def _assemble_dat(
    path: Path,
    meta: dict[str, str],
    values: dict[str, dict[tuple[int, ...], float]],
    lines_of: dict[str, int],
) -> Iso230Run:
    unit = meta.get("UNIT", "mm")
    if unit not in _UNIT_TO_MM:
        line = lines_of.get("UNIT", 0)
        raise RealDataError(
            f"{path}:{line}: unknown UNIT {unit!r}: allowed are {', '.join(_UNIT_TO_MM)}"
        )
    tgt = values["TGT_DATA"]
    if not tgt:
        raise RealDataError(f"{path}: no TGT_DATA[i] target positions found")
    m = max(k[0] for k in tgt)
    missing = [i for i in range(1, m + 1) if (i,) not in tgt]
    if missing:
        raise RealDataError(f"{path}: missing TGT_DATA[{missing[0]}] (targets 1..{m} expected)")
    cyc = [k[1] for name in ("REF_DATA_FWD", "REF_DATA_BWD") for k in values[name]]
    if not cyc:
        raise RealDataError(f"{path}: no REF_DATA_FWD[i,c] / REF_DATA_BWD[i,c] readings found")
    n = max(cyc)
    for key, found in (("POSITIONS", m), ("CYCLES", n)):
        if key in meta and meta[key] != str(found):
            raise RealDataError(
                f"{path}:{lines_of[key]}: {key}={meta[key]} but the data has {found}"
            )
    arrays = {}
    for name in ("REF_DATA_FWD", "REF_DATA_BWD"):
        a = np.empty((m, n))
        for i in range(1, m + 1):
            for c in range(1, n + 1):
                if (i, c) not in values[name]:
                    raise RealDataError(f"{path}: missing {name}[{i},{c}]")
                a[i - 1, c - 1] = values[name][(i, c)]
        extra = [k for k in values[name] if k[0] > m]
        if extra:
            i, c = extra[0]
            raise RealDataError(
                f"{path}:{lines_of[f'{name}[{i},{c}]']}: {name}[{i},{c}] has no TGT_DATA[{i}]"
            )
        arrays[name] = a * _UNIT_TO_MM[unit]
    target = np.array([tgt[(i,)] for i in range(1, m + 1)]) * _UNIT_TO_MM[unit]
    return Iso230Run(
        target_mm=target,
        fwd_mm=arrays["REF_DATA_FWD"],
        bwd_mm=arrays["REF_DATA_BWD"],
        source=str(path),
        meta=meta,
    )


# ------------------------------------------------------------------------------ camonitor logs
@dataclass(frozen=True, eq=False)
class PvSeries:
    """Updates of one PV: ``time_s`` since the session start (s), ``value``, ``alarm`` text."""

    name: str
    time_s: NDArray[np.float64]
    value: NDArray[np.float64]
    alarm: tuple[str, ...]

    def at(self, time_s: NDArray[np.float64] | float) -> NDArray[np.float64]:
        """Value in force at ``time_s`` (last update at or before it; NaN before the first)."""
        t = np.atleast_1d(np.asarray(time_s, dtype=float))
        i = np.searchsorted(self.time_s, t, side="right") - 1
        out = np.where(i >= 0, self.value[np.clip(i, 0, None)], np.nan)
        return out


def _log_times_s(dates: list[str], times: list[str], where: str) -> tuple[NDArray, np.datetime64]:
    """The one conversion of camonitor ``date time`` text to seconds since the first line."""
    try:
        stamps = np.array([f"{d}T{t}" for d, t in zip(dates, times, strict=True)], "datetime64[ns]")
    except ValueError as exc:
        raise RealDataError(f"{where}: bad date/time field ({exc})") from None
    t0 = stamps[0]
    return (stamps - t0).astype(np.int64) * 1e-9, t0


def read_camonitor_log(path: str | Path) -> dict[str, PvSeries]:
    """Read a raw EPICS ``camonitor`` log (``PV YYYY-MM-DD hh:mm:ss.ffffff value [alarm…]``).

    Times are seconds since the timestamp of the log's first line (the session start; the
    initial values camonitor prints on connection may carry older record timestamps and so
    negative times). Each PV's updates are sorted by time. Connection notices
    (``PV *** disconnected``) are skipped; non-numeric values (``<undefined>``) become NaN.

    Raises:
        RealDataError: naming the file and line, for a line without PV, date, time and value.
    """
    path = Path(path)
    try:
        text = path.read_text(encoding="utf-8", errors="replace")
    except OSError as exc:
        raise RealDataError(f"{path}: cannot read camonitor log: {exc}") from None
    names: list[str] = []
    dates: list[str] = []
    times: list[str] = []
    vals: list[str] = []
    alarms: list[str] = []
    for lineno, line in enumerate(text.splitlines(), start=1):
        parts = line.split()
        if not parts or (len(parts) > 1 and parts[1] == "***"):
            continue  # blank line or a connection notice such as "PV *** disconnected"
        if len(parts) < 4:
            raise RealDataError(
                f"{path}:{lineno}: expected 'PV date time value [alarm]', got {line.strip()!r}"
            )
        names.append(parts[0])
        dates.append(parts[1])
        times.append(parts[2])
        vals.append(parts[3])
        alarms.append(" ".join(parts[4:]))
    if not names:
        raise RealDataError(f"{path}: empty camonitor log")
    t_s, _ = _log_times_s(dates, times, str(path))
    value = np.array([_float_or_nan(v) for v in vals])
    name_arr = np.array(names)
    out: dict[str, PvSeries] = {}
    for name in dict.fromkeys(names):
        idx = np.flatnonzero(name_arr == name)
        idx = idx[np.argsort(t_s[idx], kind="stable")]
        out[name] = PvSeries(name, t_s[idx], value[idx], tuple(alarms[i] for i in idx))
    return out


def _float_or_nan(text: str) -> float:
    try:
        return float(text)
    except ValueError:
        return math.nan


@dataclass(frozen=True)
class ApproachPoint:
    """One approach of an ISO 230-2 test recovered from a raw log.

    ``direction`` +1 (positive approach, ↑) or −1; ``position``/``cycle`` 1-based; ``time_s``
    when the point was taken (test number update); ``ref_raw`` the reference PV's value then,
    in its own units; ``encoder_mm`` the axis' actual position then.
    """

    test_number: int
    direction: int
    cycle: int
    position: int
    time_s: float
    target_mm: float
    ref_raw: float
    encoder_mm: float


def iso230_points_from_log(
    log: Mapping[str, PvSeries],
    test_pv: str = "IOC_TEST:TestNumber",
    target_pv: str = "TARGET_DU:X-PosCmd",
    ref_pv: str = "IOC_TEST:ILD_DownSample",
    encoder_pv: str = "TARGET_DU:X-PosAct",
) -> list[ApproachPoint]:
    """Recover each approach of an ecmc ISO 230-2 test from a camonitor log.

    The test script writes the test number ``D C PP`` (D = 1 positive / 2 negative approach,
    C = cycle, PP = position index) once the axis has settled at the target, then commands the
    next target. A point is taken at each test-number update of that form (other numbers, such
    as the resolver test's 3xxx in the same session, are skipped); the target, the reference and
    the encoder are the values in force then. The direction is checked against the commanded
    positions: the command before the target must lie on the approach side.

    Raises:
        RealDataError: a PV is missing, a test number is malformed, or its direction disagrees
            with the commanded motion.
    """
    for pv in (test_pv, target_pv, ref_pv, encoder_pv):
        if pv not in log:
            raise RealDataError(f"PV {pv!r} not in the log (it has: {', '.join(sorted(log))})")
    tests, cmd = log[test_pv], log[target_pv]
    points = []
    for t, number in zip(tests.time_s, tests.value, strict=True):
        if not number > 0:
            continue
        n = int(np.rint(number))
        d, c, pos = n // 1000, (n // 100) % 10, n % 100
        if d not in (1, 2) or c < 1 or pos < 1 or n >= 10000:
            continue  # another test of the same session (resolver, limit switches: 3xxx, 5xxx)
        direction = 1 if d == 1 else -1
        k = int(np.searchsorted(cmd.time_s, t, side="right")) - 1
        if k < 1:
            raise RealDataError(f"test number {n} at t={t:.3f} s: no commanded move before it")
        target, previous = float(cmd.value[k]), float(cmd.value[k - 1])
        if np.sign(target - previous) != direction:
            raise RealDataError(
                f"test number {n} at t={t:.3f} s says direction {direction:+d} but the axis was "
                f"commanded {previous} → {target} mm"
            )
        ref = float(log[ref_pv].at(t)[0])
        enc = float(log[encoder_pv].at(t)[0])
        points.append(ApproachPoint(n, direction, c, pos, float(t), target, ref, enc))
    if not points:
        raise RealDataError(f"no ISO 230-2 test numbers (1CPP / 2CPP) in {test_pv!r}")
    return points


def iso230_run_from_points(
    points: Sequence[ApproachPoint], source: str = ""
) -> tuple[Iso230Run, tuple[float, float]]:
    """Assemble an :class:`Iso230Run`, mapping the raw reference linearly to the target frame.

    The map ``ref_mm = gain · ref_raw + offset`` is the least-squares fit of the targets on the
    raw readings over all points (the ecmc tool's "gear ratio"); it removes the axis' linear
    (scale and offset) error from the result, as that tool does.

    Returns:
        ``(run, (gain, offset))``; gain in mm per raw unit, offset in mm.
    """
    raw = np.array([p.ref_raw for p in points])
    tgt = np.array([p.target_mm for p in points])
    gain, offset = np.polyfit(raw, tgt, 1)
    targets = np.unique(tgt)
    m, n = targets.size, max(p.cycle for p in points)
    arrays = {k: np.full((m, n), np.nan) for k in ("ref+", "ref-", "t+", "t-", "enc+", "enc-")}
    for p in points:
        i = int(np.searchsorted(targets, p.target_mm))
        s = "+" if p.direction > 0 else "-"
        if not np.isnan(arrays["ref" + s][i, p.cycle - 1]):
            raise RealDataError(f"{source}: test {p.test_number} repeats an earlier approach")
        arrays["ref" + s][i, p.cycle - 1] = gain * p.ref_raw + offset
        arrays["t" + s][i, p.cycle - 1] = p.time_s
        arrays["enc" + s][i, p.cycle - 1] = p.encoder_mm
    if np.isnan(arrays["ref+"]).any() or np.isnan(arrays["ref-"]).any():
        raise RealDataError(f"{source}: incomplete test, some (position, cycle) were not reached")
    run = Iso230Run(
        target_mm=targets,
        fwd_mm=arrays["ref+"],
        bwd_mm=arrays["ref-"],
        source=source,
        time_fwd_s=arrays["t+"],
        time_bwd_s=arrays["t-"],
        encoder_fwd_mm=arrays["enc+"],
        encoder_bwd_mm=arrays["enc-"],
    )
    return run, (float(gain), float(offset))


# ------------------------------------------------------------------------- project formats
def error_table_from_run(run: Iso230Run, axis: str = "x") -> tuple[str, dict[str, list[float]]]:
    """Positional error table (docs/formats.md §1) of the run's axis: ``("dx_x", table)`` for x.

    ``value`` = x̄_i (mean bidirectional deviation, µm; error = true − indicated, so the
    correction to add), ``random`` = the 2σ band max(2s_i↑, 2s_i↓) (µm), and ``reversal`` =
    B_i/2 (µm): the error after an approach in + is ``value + reversal`` (= x̄_i↑), in −
    ``value − reversal`` (= x̄_i↓); the machine model applies it with the ``dir_<axis>`` signal.
    """
    if axis not in AXES:
        raise ValueError(f"unknown axis {axis!r}: allowed are {', '.join(AXES)}")
    r = run.evaluate()
    table = {
        "position": r.target_mm.tolist(),
        "value": r.mean_bidir_um.tolist(),
        "random": (2.0 * np.maximum(r.s_fwd_um, r.s_bwd_um)).tolist(),
        "reversal": (0.5 * r.reversal_um).tolist(),
    }
    return f"d{axis}_{axis}", table


MEASUREMENT_COLUMNS = ("x", "y", "z", "ref_x", "ref_y", "ref_z", "t", "dir_x", "dir_y", "dir_z")


def measurement_rows(run: Iso230Run, axis: str = "x") -> list[dict[str, float | int | str]]:
    """Rows of a measurements table (docs/formats.md §2), one per approach, in time order if known.

    The stage's axis goes to ``axis``; the other axes are 0 (indicated and reference). Indicated
    = the encoder position where the run came from a log, else the target; ``ref_<axis>`` the
    reference position; ``t`` (s since session start) where known; ``dir_<axis>`` +1/−1 (only
    the moved axis gets a ``dir_`` column); ``group`` = ``fwd-c<cycle>`` / ``bwd-c<cycle>``.
    """
    if axis not in AXES:
        raise ValueError(f"unknown axis {axis!r}: allowed are {', '.join(AXES)}")
    rows: list[dict[str, float | int | str]] = []
    for sign, ref, enc, times in (
        (1, run.fwd_mm, run.encoder_fwd_mm, run.time_fwd_s),
        (-1, run.bwd_mm, run.encoder_bwd_mm, run.time_bwd_s),
    ):
        for i, c in np.ndindex(ref.shape):
            row: dict[str, float | int | str] = {k: 0.0 for k in ("x", "y", "z")}
            row.update({f"ref_{k}": 0.0 for k in AXES})
            row[axis] = float(run.target_mm[i] if enc is None else enc[i, c])
            row[f"ref_{axis}"] = float(ref[i, c])
            if times is not None:
                row["t"] = float(times[i, c])
            row[f"dir_{axis}"] = sign
            row["group"] = f"{'fwd' if sign > 0 else 'bwd'}-c{c + 1}"
            rows.append(row)
    if all("t" in r for r in rows):
        rows.sort(key=lambda r: r["t"])
    return rows


def write_measurements_csv(
    path: str | Path, rows: Sequence[Mapping[str, float | int | str]]
) -> Path:
    """Write measurement rows as CSV (docs/formats.md §2): known columns first, then any others.

    Raises:
        ValueError: before writing anything, if there are no rows, a required column
            (x, y, z, ref_x, ref_y, ref_z) is missing or rows have different columns.
    """
    if not rows:
        raise ValueError("no measurement rows to write")
    keys = list(rows[0])
    for n, row in enumerate(rows):
        if set(row) != set(keys):
            raise ValueError(f"row {n} has columns {sorted(row)}, row 0 has {sorted(keys)}")
    missing = [k for k in MEASUREMENT_COLUMNS[:6] if k not in keys]
    if missing:
        raise ValueError(f"measurement rows lack required column(s) {', '.join(missing)}")
    header = [k for k in MEASUREMENT_COLUMNS if k in keys] + [
        k for k in keys if k not in MEASUREMENT_COLUMNS
    ]
    path = Path(path)
    with path.open("w", newline="", encoding="utf-8") as fh:
        writer = csv.DictWriter(fh, fieldnames=header)
        writer.writeheader()
        for row in rows:
            writer.writerow({k: repr(v) if isinstance(v, float) else v for k, v in row.items()})
    return path
