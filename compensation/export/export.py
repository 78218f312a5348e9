"""``export_tables``: a machine's volumetric model as a controller's own compensation tables.

The model is evaluated at a fixed tool/stylus offset and the reference temperatures; what the
format can carry is fitted by least squares over the working volume (:mod:`.decompose`,
:mod:`.plan`), written in the format's units, signs, resolution and limits, and then the
residual is measured by evaluating what was written exactly as the control does (linear
interpolation, direction selection, table products) on an evaluation grid, for every
combination of travel directions of the axes whose error depends on it. Units: mm, µm.
"""

from __future__ import annotations

import math
import re
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from itertools import product
from typing import Any

import numpy as np

from ..machine import Machine
from ..parametric_errors import AXES
from .check import unverified
from .decompose import Decomposition, decompose, direction_axes, model_error_um
from .limits import POINT_LIMITS, ExportError
from .linuxcnc import build_linuxcnc, linuxcnc_error_um, render_linuxcnc
from .plan import Plan, left_out, own_axis_plan
from .sinumerik import build_cec, cec_correction_mm, render_cec, total_extremes_mm
from .splines import FloatArray, Knots, make_knots
from .twincat import build_twincat, render_startup, render_twincat, twincat_error_um

__all__ = [
    "FORMATS",
    "ExportError",
    "ExportOptions",
    "ExportResult",
    "export_tables",
    "validate_axes",
]

FORMATS = ("sinumerik-cec", "twincat-cnc", "linuxcnc")

_QUANTUM_MM = 1e-4  # positions: 0.1 µm (TwinCAT's length unit; 4 decimals in the other files)
_MAX_EVAL_STEPS = 201
_MAX_EVAL_POINTS = 2_000_000  # grid nodes × direction combinations
_CHUNK = 100_000  # points per model evaluation (bounds the memory)
#: points per table this exporter fits (the fit's memory grows ~0.35 MB per point: 4001 → 1.5 GB)
_MAX_TABLE_POINTS = 5000


@dataclass
class ExportOptions:
    """How to export; ``None`` means the format's default. Every limit names its source."""

    points: int | None = None  # per table; default: about one point per 10 mm, at least 11
    max_points: int | None = None  # the control's limit per table (default: the format's)
    max_tables: int = 8  # sinumerik-cec: number of CEC tables (828D: 8)
    products: bool = False  # sinumerik-cec: $AN_CEC_MULT_BY_TABLE (Siemens' example semantics)
    invert_sign: bool = False  # the unverified sign (CEC values, TwinCAT cross) written negated
    cec_max_sum_mm: float = 1.0  # sinumerik-cec: MD32720 $MA_CEC_MAX_SUM
    cec_axis_names: tuple[str, str, str] = ("AX1", "AX2", "AX3")
    twincat_axis_numbers: tuple[int, int, int] = (1, 2, 3)
    twincat_axis_names: tuple[str, str, str] = ("X", "Y", "Z")
    twincat_cross: bool = True
    linuxcnc_joints: tuple[int, int, int] = (0, 1, 2)
    linuxcnc_file_type: int = 0
    eval_steps: tuple[int, int, int] = (41, 41, 21)
    min_rms_um: float = 0.01  # a part smaller than this is not worth a table


@dataclass
class ExportResult:
    """What was written (``files``: name → text) and the report (``report``, JSON-ready)."""

    format: str
    files: dict[str, str]
    report: dict[str, Any]
    tables: list[dict[str, Any]]
    represented_um: Callable[[FloatArray, FloatArray], FloatArray] = field(repr=False)
    decomposition: Decomposition = field(repr=False)
    plan: Plan = field(repr=False)
    residual_stats: dict[str, Any] = field(default_factory=dict)


def _check_tool(
    machine: Machine, tool_mm: Sequence[float] | FloatArray, what: str = "--tool"
) -> FloatArray:
    tool = np.asarray(tool_mm, dtype=float)
    if tool.shape != (3,):
        raise ExportError(f"{what} needs 3 numbers (X Y Z mm), got {np.shape(tool_mm)}")
    if not np.all(np.isfinite(tool)):
        raise ExportError(f"{what} must be finite numbers (mm), got {tool.tolist()}")
    reach = float(np.max(machine.volume.upper_mm - machine.volume.lower_mm))
    if np.any(np.abs(tool) > reach):
        raise ExportError(
            f"{what} {tool.tolist()} mm is outside reason: each component must be within "
            f"±{reach:g} mm (the machine's largest travel)"
        )
    return tool


def _points(machine: Machine, fmt: str, opts: ExportOptions) -> tuple[list[int], int, str]:
    default_limit, hard_limit, source = POINT_LIMITS[fmt]
    limit = opts.max_points if opts.max_points is not None else default_limit
    if hard_limit is not None and limit > hard_limit:
        raise ExportError(f"{fmt}: --max-points {limit} is more than the format holds ({source})")
    if limit < 2:
        raise ExportError(f"{fmt}: --max-points must be at least 2, got {limit}")
    span = machine.volume.upper_mm - machine.volume.lower_mm
    if opts.points is not None:
        if opts.points < 2:
            raise ExportError(f"--points must be at least 2 per table, got {opts.points}")
        if opts.points > limit:
            raise ExportError(
                f"{fmt}: --points {opts.points} is more than a table holds: at most {limit} "
                f"({source}; --max-points raises it to your control's setting)"
            )
        counts = [opts.points] * 3
    else:
        counts = [int(min(limit, max(11, math.ceil(float(s) / 10.0) + 1))) for s in span]
    if max(counts) > _MAX_TABLE_POINTS:
        raise ExportError(
            f"{fmt}: {max(counts)} points per table is more than this exporter fits: at most "
            f"{_MAX_TABLE_POINTS} (memory and time grow with the points; set --points)"
        )
    return counts, limit, source


def _knots_fit(kn: Knots, lo: float, hi: float) -> bool:
    """Whether every point of the table has travel to fit: one position step per point (never
    a step shorter than the resolution on a shorter travel) and the last but one point inside
    the volume (else the last point's weight has nothing to fit: a singular fit)."""
    return (kn.count - 1) * _QUANTUM_MM <= (hi - lo) * (1 + 1e-9) and (
        kn.start_mm + (kn.count - 2) * kn.step_mm < hi
    )


def _count_fits(machine: Machine, axes: Sequence[int], count: int) -> bool:
    lo, hi = machine.volume.lower_mm, machine.volume.upper_mm
    return all(
        _knots_fit(make_knots(a, float(lo[a]), float(hi[a]), count, _QUANTUM_MM), lo[a], hi[a])
        for a in axes
    )


_AXIS_NAME = re.compile(r"[A-Za-z][A-Za-z0-9_]{0,15}")  # whole name (fullmatch: "X\n" is not one)


def validate_axes(fmt: str, opts: ExportOptions) -> None:
    """Axis names are identifiers (letter first, ≤ 16 letters, digits, _); TwinCAT logical axis
    numbers are distinct and ≥ 1 (0 is not allowed), LinuxCNC joints distinct and ≥ 0."""
    names = opts.cec_axis_names if fmt == "sinumerik-cec" else opts.twincat_axis_names
    named = len(names) == 3 and all(isinstance(n, str) and _AXIS_NAME.fullmatch(n) for n in names)
    if fmt != "linuxcnc" and not named:
        raise ExportError(
            f"--axis-names needs 3 identifiers (a letter, then letters, digits or _; at most "
            f"16), got {list(names)}"
        )
    numbers, low, what = (
        (opts.twincat_axis_numbers, 1, "TwinCAT logical axis numbers")
        if fmt == "twincat-cnc"
        else (opts.linuxcnc_joints, 0, "LinuxCNC joint numbers")
    )
    if fmt != "sinumerik-cec" and (
        len(set(numbers)) != 3 or any(int(n) != n or n < low or n > 65535 for n in numbers)
    ):
        raise ExportError(
            f"--axis-numbers: {what} must be 3 distinct integers in {low}…65535, got {list(numbers)}"
        )


def _check_eval_steps(steps: Sequence[int]) -> tuple[int, int, int]:
    if len(steps) != 3 or any(int(s) != s or s < 2 or s > _MAX_EVAL_STEPS for s in steps):
        raise ExportError(
            f"--eval-steps needs 3 integers in 2…{_MAX_EVAL_STEPS}, got {list(steps)}"
        )
    return int(steps[0]), int(steps[1]), int(steps[2])


def _stats(r: FloatArray, what: str) -> dict[str, Any]:
    """RMS and max µm of the 3-D vector and per axis; :class:`ExportError` naming ``what`` when
    one is not a finite number (an error so large that its square overflows, or a table value
    beyond what the control's arithmetic holds): never a NaN/inf figure reported as a result."""
    with np.errstate(over="ignore", invalid="ignore"):
        norm = np.linalg.norm(r, axis=1)
        rms, peak = float(np.sqrt(np.mean(norm**2))), float(np.max(norm))
        per_axis = {
            AXES[k]: {
                "rms": float(np.sqrt(np.mean(r[:, k] ** 2))),
                "max": float(np.max(np.abs(r[:, k]))),
            }
            for k in range(3)
        }
    figures = [rms, peak] + [v for a in per_axis.values() for v in a.values()]
    if not all(math.isfinite(v) for v in figures):
        raise ExportError(
            f"{what} over the working volume is not a finite number (RMS {rms:g} µm, "
            f"max {peak:g} µm): the machine description's errors are too large to "
            "export; check its error tables (µm, µrad)"
        )
    return {"rms": rms, "max": peak, "per_axis": per_axis}


def evaluation_points(machine: Machine, steps: Sequence[int]) -> FloatArray:
    """The evaluation grid (N, 3) mm: ``steps`` nodes per axis over the volume, C order."""
    nodes = machine.volume.nodes(tuple(int(s) for s in steps))  # type: ignore[arg-type]
    mesh = np.meshgrid(*nodes, indexing="ij")
    return np.stack([m.ravel() for m in mesh], axis=1)


def direction_combinations(dir_axes: Sequence[int]) -> list[dict[int, float]]:
    """Every combination of ±1 for the axes whose error depends on the direction ({} if none)."""
    return [dict(zip(dir_axes, c, strict=True)) for c in product((1.0, -1.0), repeat=len(dir_axes))]


def measure_residual(
    machine: Machine,
    tool_mm: FloatArray,
    represented_um: Callable[[FloatArray, FloatArray], FloatArray],
    steps: Sequence[int],
) -> tuple[dict[str, Any], dict[str, Any]]:
    """(residual, uncompensated) statistics µm over the evaluation grid and direction
    combinations: residual = model error − the error the tables take off."""
    q_all = evaluation_points(machine, steps)
    res, raw = [], []
    for combo in direction_combinations(direction_axes(machine)):
        for start in range(0, len(q_all), _CHUNK):
            q = q_all[start : start + _CHUNK]
            e = model_error_um(machine, q, tool_mm, combo)
            dirs = np.ones_like(q)
            for a, s in combo.items():
                dirs[:, a] = s
            with np.errstate(over="ignore", invalid="ignore"):
                res.append(e - represented_um(q, dirs))
            raw.append(e)
    raw_stats = _stats(np.concatenate(raw), "the model's error")
    return _stats(np.concatenate(res), "the residual after the written tables"), raw_stats


def _header(machine: Machine, fmt: str, tool: FloatArray) -> list[str]:
    return [
        f"cmm-comp export --format {fmt}: {machine.name} ({machine.model})",
        f"machine description sha256 {machine.identity_sha256()}",
        f"tool/stylus offset {tool.tolist()} mm; reference temperatures "
        f"({machine.thermal.reference_C:g} C): valid for this tool only",
        "error = true - indicated; see docs/export.md of cmm-comp for the conventions",
    ]


def export_tables(
    machine: Machine,
    fmt: str,
    tool_mm: Sequence[float] | FloatArray | None = None,
    options: ExportOptions | None = None,
    progress: Callable[[str], None] | None = None,
) -> ExportResult:
    """Fit, write (in memory) and measure the tables of ``fmt`` for ``machine`` at ``tool_mm``
    (default: the machine's probe offset). :class:`ExportError` names any limit it cannot meet.

    Floating-point overflow on the way (errors of absurd size) is not warned about here: the
    measured residual is checked to be finite at the end (:func:`_stats`)."""
    with np.errstate(over="ignore", invalid="ignore"):
        return _export_tables(machine, fmt, tool_mm, options, progress)


def _export_tables(
    machine: Machine,
    fmt: str,
    tool_mm: Sequence[float] | FloatArray | None,
    options: ExportOptions | None,
    progress: Callable[[str], None] | None,
) -> ExportResult:
    if fmt not in FORMATS:
        raise ExportError(f"--format must be one of {', '.join(FORMATS)}, got {fmt!r}")
    opts = options or ExportOptions()
    say = progress or (lambda _line: None)
    if tool_mm is None:
        tool = _check_tool(machine, machine.probe.offset_mm, "the machine's probe offset (--tool)")
    else:
        tool = _check_tool(machine, tool_mm)
    validate_axes(fmt, opts)
    steps = _check_eval_steps(opts.eval_steps)
    n_eval = int(np.prod(steps)) * len(direction_combinations(direction_axes(machine)))
    if n_eval > _MAX_EVAL_POINTS:
        raise ExportError(
            f"--eval-steps {list(steps)}: {n_eval} evaluations (nodes × direction combinations), "
            f"at most {_MAX_EVAL_POINTS}"
        )
    counts, limit, source = _points(machine, fmt, opts)
    lo, hi = machine.volume.lower_mm, machine.volume.upper_mm
    knots: tuple[Knots, Knots, Knots] = tuple(  # type: ignore[assignment]
        make_knots(a, float(lo[a]), float(hi[a]), counts[a], _QUANTUM_MM) for a in range(3)
    )
    for a, kn in enumerate(knots):
        if not _knots_fit(kn, float(lo[a]), float(hi[a])):
            # --points sets all three axes: a count to suggest must fit each of them
            axes = range(3) if opts.points is not None else (a,)
            fitting = [n for n in range(2, _MAX_TABLE_POINTS + 1) if _count_fits(machine, axes, n)]
            hint = (
                f"set --points to one that fits, e.g. {min(fitting, key=lambda n: abs(n - kn.count))}"
                if fitting
                else "it is shorter than that resolution"
            )
            raise ExportError(
                f"{fmt}: the {AXES[a].upper()} travel of {float(hi[a] - lo[a]):g} mm cannot hold "
                f"{kn.count} points {_QUANTUM_MM * 1000:g} µm apart or more (the position "
                f"resolution written): {hint}"
            )
    ranks = 2 if (fmt == "sinumerik-cec" and opts.products) else 0
    say(f"fitting {fmt} tables ({counts[0]}/{counts[1]}/{counts[2]} points on X/Y/Z)")
    d = decompose(machine, tool, knots, interaction_ranks=ranks)
    header = _header(machine, fmt, tool)
    files: dict[str, str] = {}
    tables_info: list[dict[str, Any]] = []
    extra: dict[str, Any] = {}
    represented: Callable[[FloatArray, FloatArray], FloatArray]
    if fmt == "sinumerik-cec":
        if opts.max_tables < 1:
            raise ExportError(f"--max-tables must be at least 1, got {opts.max_tables}")
        if not (0 < opts.cec_max_sum_mm < math.inf):
            raise ExportError(
                f"--cec-max-sum-mm must be a positive number, got {opts.cec_max_sum_mm}"
            )
        sign = -1 if opts.invert_sign else 1
        cec, plan = build_cec(
            d,
            max_tables=opts.max_tables,
            products=opts.products,
            sign=sign,
            min_rms_um=opts.min_rms_um,
        )
        peak, exact = total_extremes_mm(cec, d.direction_axes)
        for k in range(3):
            if peak[k] > opts.cec_max_sum_mm:
                raise ExportError(
                    f"sinumerik-cec: the total compensation of {AXES[k].upper()} reaches "
                    f"{'' if exact else 'up to '}{peak[k]:.4f} mm, above MD32720 $MA_CEC_MAX_SUM = {opts.cec_max_sum_mm:g} mm "
                    "(the control would limit it and raise an alarm, leaving a wrong correction): "
                    "set --cec-max-sum-mm to your control's value, or correct the gross errors first"
                )
        files["NC_CEC.INI"] = render_cec(cec, opts.cec_axis_names, header)

        def represented(q: FloatArray, dirs: FloatArray) -> FloatArray:
            # the axis moves by minus the total (K3's sign statement; docs/export.md)
            return sign * 1000.0 * cec_correction_mm(cec, q, dirs)

        for i, t in enumerate(cec):
            tables_info.append(
                {
                    "table": i,
                    "input": AXES[t.input_axis],
                    "output": AXES[t.output_axis],
                    "role": t.role,
                    "direction": t.direction,
                    "mult_by_table": None if t.mult_by is None else t.mult_by + 1,
                    "points": t.knots.count,
                    "min_mm": t.knots.start_mm,
                    "max_mm": t.knots.end_mm,
                    "step_mm": t.knots.step_mm,
                    "max_abs_mm": round(float(np.max(np.abs(t.values_mm))), 7),
                    # what the compensation asks of the output axis per mm of the input axis
                    "max_slope_um_per_mm": round(
                        1000.0 * float(np.max(np.abs(np.diff(t.values_mm)))) / t.knots.step_mm, 6
                    ),
                }
            )
        extra["limits"] = {
            "max_tables": opts.max_tables,
            "tables_written": len(cec),
            "max_points": limit,
            "points_source": source,
            "cec_max_sum_mm": opts.cec_max_sum_mm,
            "total_compensation_peak_mm": peak.tolist(),
            "total_compensation_peak_exact": exact,
            "value_resolution_um": 0.1,
            # what a referencing (rate) table would add on its own: the most the result changes
            # between the two readings of "added as an additional compensation value"
            "product_rate_own_max_um": max(
                (1000.0 * float(np.max(np.abs(t.values_mm))) for t in cec if t.mult_by is not None),
                default=0.0,
            ),
        }
        extra["unverified"] = unverified(fmt, products=bool(plan.products))
        if opts.products and plan.products:
            flat, _ = build_cec(
                d, max_tables=opts.max_tables, products=False, sign=sign, min_rms_um=opts.min_rms_um
            )
            extra["residual_without_products_um"] = measure_residual(
                machine, tool, lambda q, s: sign * 1000.0 * cec_correction_mm(flat, q, s), steps
            )[0]
    elif fmt == "twincat-cnc":
        plan = own_axis_plan(d, cross=opts.twincat_cross, min_rms_um=opts.min_rms_um)
        cross_sign = -1 if opts.invert_sign else 1
        lists = build_twincat(plan, knots, cross_sign)
        for entry in lists:
            nr = opts.twincat_axis_numbers[entry.axis]
            files[f"achskw{nr}.lis"] = render_twincat(
                entry, opts.twincat_axis_numbers, opts.twincat_axis_names, header
            )
            tables_info.append(
                {
                    "list": f"achskw{nr}.lis",
                    "axis": AXES[entry.axis],
                    "leadscrew_points": entry.knots.count,
                    "bilateral": entry.bilateral,
                    "cross_master": None
                    if entry.cross_master is None
                    else AXES[entry.cross_master],
                    "cross_points": None if entry.cross_knots is None else entry.cross_knots.count,
                }
            )
        files["startup-snippet.txt"] = render_startup(lists, opts.twincat_axis_numbers)

        def represented(q: FloatArray, dirs: FloatArray) -> FloatArray:
            return twincat_error_um(lists, q, dirs, cross_sign)

        extra["limits"] = {
            "max_points": limit,
            "points_source": source,
            "value_range": "SGN32 in 0.1 µm",
        }
        extra["unverified"] = unverified(fmt, cross=any(e.cross_master is not None for e in lists))
    else:
        plan = own_axis_plan(d, cross=False, min_rms_um=opts.min_rms_um)
        joints = build_linuxcnc(plan, knots, opts.linuxcnc_file_type)
        for j in joints:
            n = opts.linuxcnc_joints[j.axis]
            files[f"joint{n}.comp"] = render_linuxcnc(j)
            tables_info.append(
                {
                    "file": f"joint{n}.comp",
                    "joint": n,
                    "axis": AXES[j.axis],
                    "points": len(j.nominal_mm),
                    "file_type": j.file_type,
                }
            )
        files["linuxcnc-joints.ini"] = _linuxcnc_ini(joints, opts, header)

        def represented(q: FloatArray, dirs: FloatArray) -> FloatArray:
            return linuxcnc_error_um(joints, q, dirs)

        extra["limits"] = {"max_points": limit, "points_source": source}
    say("measuring the residual as the control interpolates")
    residual, raw = measure_residual(machine, tool, represented, steps)
    report: dict[str, Any] = {
        "format": fmt,
        "machine": machine.name,
        "model": machine.model,
        "machine_sha256": machine.identity_sha256(),
        "source": machine.source,
        "tool_mm": tool.tolist(),
        "temperatures_C": "reference",
        "reference_C": machine.thermal.reference_C,
        "files": sorted(files),
        "tables": tables_info,
        "points_per_axis": counts,
        "evaluation": {
            "grid_steps": list(steps),
            "direction_axes": [AXES[a] for a in d.direction_axes],
            "direction_combinations": len(direction_combinations(d.direction_axes)),
            "points": int(np.prod(steps)) * len(direction_combinations(d.direction_axes)),
        },
        "uncompensated_um": raw,
        "residual_um": residual,
        "left_out": _with_remainder(left_out(d, plan), residual),
        "not_modelled_here": _runtime_parts(machine),
        "convention": "error = true - indicated (µm); residual = model error - what the tables "
        "take off, evaluated as the control interpolates; RMS and max of the 3-D vector",
        **extra,
    }
    return ExportResult(fmt, files, report, tables_info, represented, d, plan, residual)


def _with_remainder(rows: list[dict[str, Any]], residual: dict[str, Any]) -> list[dict[str, Any]]:
    """``rows`` plus, per output axis, what the measured residual holds beyond them:
    interpolation between points, value rounding and three-axis terms."""
    out = list(rows)
    for a, stats in residual["per_axis"].items():
        listed = sum(r["rms_um"] ** 2 for r in rows if r["output"] == a.upper())
        rest = stats["rms"] ** 2 - listed
        if rest >= 1e-6:
            out.append(
                {
                    "output": a.upper(),
                    "part": "interpolation between points, rounding, three-axis terms (measured)",
                    "rms_um": float(np.sqrt(rest)),
                }
            )
    out.sort(key=lambda r: -r["rms_um"])
    return out


def _runtime_parts(machine: Machine) -> list[str]:
    """Model terms a static table cannot know (runtime signals other than directions)."""
    out = []
    for name in sorted(machine.runtime_signals()):
        if name.startswith("dir_"):
            continue
        out.append(
            f"{name}: the tables are for its reference value; its effect at run time is left to "
            "the daemon"
        )
    return out


def _linuxcnc_ini(joints: Sequence[Any], opts: ExportOptions, header: Sequence[str]) -> str:
    lines = [f"# {h}" for h in header]
    lines.append(
        "# machine units mm ([TRAJ] LINEAR_UNITS = mm); BACKLASH is ignored with COMP_FILE"
    )
    for j in joints:
        n = opts.linuxcnc_joints[j.axis]
        lines += [
            "",
            f"[JOINT_{n}]",
            f"COMP_FILE = joint{n}.comp",
            f"COMP_FILE_TYPE = {j.file_type}",
        ]
    return "\n".join(lines) + "\n"


def describe(result: ExportResult) -> list[str]:
    """Lines for people: residual before/after and the largest parts left for the daemon."""
    r, u = result.report["residual_um"], result.report["uncompensated_um"]
    lines = [
        f"{result.format}: {len(result.tables)} table(s) → {', '.join(result.report['files'])}",
        f"  model error over the volume: RMS {u['rms']:.3f} µm, max {u['max']:.3f} µm",
        f"  left after the control's own interpolation: RMS {r['rms']:.3f} µm, max {r['max']:.3f} µm"
        " (what the daemon would still correct)",
        "  per axis (RMS/max µm): "
        + ", ".join(f"{a.upper()} {v['rms']:.3f}/{v['max']:.3f}" for a, v in r["per_axis"].items()),
    ]
    if "residual_without_products_um" in result.report:
        w = result.report["residual_without_products_um"]
        lines.append(
            f"  without table products it would be RMS {w['rms']:.3f} µm, max {w['max']:.3f} µm"
        )
    big = [p for p in result.report["left_out"] if p["rms_um"] >= 0.05][:6]
    if big:
        lines.append("  largest parts the format cannot carry (≈ RMS over the volume):")
        lines += [f"    {p['output']}: {p['part']}: {p['rms_um']:.3f} µm" for p in big]
    for note in result.report["not_modelled_here"]:
        lines.append(f"  note: {note}")
    for item in result.report.get("unverified", []):
        lines.append(f"  NOT VERIFIED: {item['point']}: assumed {item['assumed']}")
        lines.append(f"    settle it: {item['settle']}")
    return lines
