"""Beckhoff TwinCAT CNC (ISG kernel, TF5200) axis compensation lists: one ASCII list per axis.

Per the TF5200 axis-compensation pages: a list has a header ``kopf.achs_nr`` (logical axis
number, P-COMP-00001) and ``kopf.log_achs_name``; the leadscrew error compensation
``kw.ssfk.*`` (P-COMP-00017…25: ``unit`` 1 = metric, lengths in 0.1 µm; ``interval`` the point
spacing; ``kw_startpos``; ``kw_nr_max`` the number of points, below ``max_points`` = 1500 by
default; ``bilateral`` 1 = a table per direction; ``table[i].pos`` / ``.neg`` the values) is a
function of the axis' own command position, interpolated linearly; the cross compensation
``kw.crosscomp.*`` of the *slave* axis' list (P-COMP-00003…07: ``unit``, ``master_ax_nr``,
``last_index`` below ``max_points`` = 1001, ``table[i].setpoint`` ascending positions of the
master axis, ``table[i].correction``) adds a function of one other axis, for both directions.

Values: a leadscrew value is the deviation ``Δs = actual − set`` (the manual's worked example),
i.e. the error (true − indicated) in 0.1 µm, which the control takes off the set point. The
public pages do not say which sign the cross ``correction`` has; we write it with the same
meaning as the leadscrew values (the error, 0.1 µm) — docs/export.md says how to check it.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from ..parametric_errors import AXES
from .limits import SGN32, ExportError
from .plan import Plan
from .splines import FloatArray, Knots, evaluate

__all__ = ["TwinCatList", "build_twincat", "render_startup", "render_twincat", "twincat_error_um"]

NDInt = np.ndarray  # integer values in 0.1 µm


@dataclass
class TwinCatList:
    """The list of one axis: leadscrew table (0.1 µm integers) and an optional cross table."""

    axis: int
    knots: Knots  # leadscrew points along the axis itself
    pos_01um: NDInt
    neg_01um: NDInt
    bilateral: bool
    cross_master: int | None = None
    cross_knots: Knots | None = None
    cross_01um: NDInt | None = None


def _to_01um(values_um: FloatArray, what: str) -> NDInt:
    raw = np.round(np.asarray(values_um, dtype=float) * 10.0)
    if not np.all(np.isfinite(raw)) or raw.min() < SGN32[0] or raw.max() > SGN32[1]:
        raise ExportError(
            f"twincat-cnc: {what} reaches {np.nanmax(np.abs(raw)) / 1e4:.4g} mm, outside the "
            f"SGN32 range of the list (±{SGN32[1] / 1e4:.4g} mm in 0.1 µm)"
        )
    return raw.astype(np.int64)


def _pos_01um(mm: float, what: str) -> int:
    return int(_to_01um(np.array([mm * 1000.0]), what)[0])


def build_twincat(
    plan: Plan, knots: tuple[Knots, Knots, Knots], cross_sign: int = 1
) -> list[TwinCatList]:
    """One list per axis from an own-axis plan (with at most one cross table per axis); the cross
    ``correction`` holds ``cross_sign`` × the error (+1: the leadscrew tables' meaning, −1: the
    opposite, for a control whose ``--check-table`` showed it)."""
    lists: list[TwinCatList] = []
    for k in range(3):
        base = plan.plain.get((k, k), np.zeros(knots[k].count))
        h = plan.directional.get((k, k))
        name = AXES[k].upper()
        pos = _to_01um(base + (h if h is not None else 0.0), f"the {name} leadscrew table")
        neg = _to_01um(base - (h if h is not None else 0.0), f"the {name} leadscrew table")
        entry = TwinCatList(k, knots[k], pos, neg, h is not None)
        masters = [a for (a, kk) in plan.plain if kk == k and a != k]
        if masters:
            m = masters[0]
            entry.cross_master = m
            entry.cross_knots = knots[m]
            entry.cross_01um = _to_01um(cross_sign * plan.plain[(m, k)], f"the {name} cross table")
        for kn in (knots[k], entry.cross_knots):
            if kn is not None:
                _pos_01um(kn.start_mm, f"the {name} table positions")
                _pos_01um(kn.end_mm, f"the {name} table positions")
        lists.append(entry)
    return lists


def twincat_error_um(
    lists: Sequence[TwinCatList], q_mm: FloatArray, dirs: FloatArray, cross_sign: int = 1
) -> FloatArray:
    """The error (N, 3) µm the lists take off at command positions ``q_mm`` with travel
    directions ``dirs`` (N, 3) ±1: the writer's own emulation (linear interpolation); a cross
    value is taken off like a leadscrew value (``cross_sign`` +1) or added (−1)."""
    q = np.asarray(q_mm, dtype=float)
    out = np.zeros((q.shape[0], 3))
    for entry in lists:
        k = entry.axis
        up = evaluate(entry.knots, entry.pos_01um, q[:, k])
        down = evaluate(entry.knots, entry.neg_01um, q[:, k])
        table = np.where(dirs[:, k] > 0, up, down)
        out[:, k] += table / 10.0
        if entry.cross_master is not None:
            assert entry.cross_knots is not None and entry.cross_01um is not None
            cross = evaluate(entry.cross_knots, entry.cross_01um, q[:, entry.cross_master])
            out[:, k] += cross_sign * cross / 10.0
    return out


def render_twincat(
    entry: TwinCatList,
    axis_numbers: Sequence[int],
    axis_names: Sequence[str],
    header: Sequence[str],
) -> str:
    """The compensation value list of one axis (``#`` comments, one ``name value`` per line)."""
    k = entry.axis
    kn = entry.knots
    rows: list[tuple[str, str]] = [
        ("kopf.achs_nr", str(axis_numbers[k])),
        ("kopf.log_achs_name", axis_names[k]),
    ]
    rows += [
        ("kw.ssfk.unit", "1"),
        ("kw.ssfk.interval", str(_pos_01um(kn.step_mm, "interval"))),
        ("kw.ssfk.kw_startpos", str(_pos_01um(kn.start_mm, "start"))),
        ("kw.ssfk.kw_nr_max", str(kn.count)),
        ("kw.ssfk.bilateral", "1" if entry.bilateral else "0"),
        ("kw.ssfk.modulo", "0"),
    ]
    if kn.count >= 1500:
        rows.append(("kw.ssfk.max_points", str(kn.count + 1)))
    for i in range(kn.count):
        rows.append((f"kw.ssfk.table[{i}].pos", str(int(entry.pos_01um[i]))))
    for i in range(kn.count):
        rows.append((f"kw.ssfk.table[{i}].neg", str(int(entry.neg_01um[i]))))
    if entry.cross_master is not None:
        assert entry.cross_knots is not None and entry.cross_01um is not None
        ck = entry.cross_knots
        rows += [
            ("kw.crosscomp.unit", "1"),
            ("kw.crosscomp.master_ax_nr", str(axis_numbers[entry.cross_master])),
            ("kw.crosscomp.last_index", str(ck.count - 1)),
        ]
        if ck.count > 1001:
            rows.append(("kw.crosscomp.max_points", str(ck.count)))
        for i, p in enumerate(ck.positions()):
            rows.append((f"kw.crosscomp.table[{i}].setpoint", str(_pos_01um(float(p), "setpoint"))))
            rows.append((f"kw.crosscomp.table[{i}].correction", str(int(entry.cross_01um[i]))))
    width = max(len(r[0]) for r in rows) + 2
    lines = [f"# {h}" if h else "#" for h in header]
    lines += [f"{name.ljust(width)}{value}" for name, value in rows]
    return "\n".join(lines) + "\n"


def render_startup(lists: Sequence[TwinCatList], axis_numbers: Sequence[int]) -> str:
    """The start-up list entries (``zahl_kw``, ``achs_kw_log_ax_nr[i]``, ``achs_kw[i]``) for
    ``lists`` and, as comments, the axis parameters that activate them."""
    lines = [
        "# TwinCAT CNC start-up list entries for these compensation lists (adapt the paths)",
        f"zahl_kw                   {len(lists)}",
    ]
    for i, entry in enumerate(lists):
        nr = axis_numbers[entry.axis]
        lines += [
            f"achs_kw_log_ax_nr[{i}]      {nr}",
            f"achs_kw[{i}]                achskw{nr}.lis",
        ]
    lines += ["#", "# axis parameter lists: activate per axis"]
    for entry in lists:
        nr = axis_numbers[entry.axis]
        lines.append(
            f"#   axis {nr}: lr_param.ssfk 1"
            + (", lr_param.crosscomp 1" if entry.cross_master is not None else "")
        )
    return "\n".join(lines) + "\n"
