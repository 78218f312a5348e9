"""SINUMERIK sag / cross-error compensation (CEC) tables: ``%_N_NC_CEC_INI`` (Function Manual
Extended Functions, K3 "Compensations", interpolatory compensation).

Each table ``t`` adds to its *compensation* (output) axis a value interpolated linearly between
equidistant points of its *basic* (input) axis, ``$AN_CEC[t,N]`` in mm at
``$AN_CEC_MIN[t] + N·$AN_CEC_STEP[t]``, the first and last values held beyond
``$AN_CEC_MIN``/``$AN_CEC_MAX``; ``$AN_CEC_DIRECTION[t]`` = 0/1/−1 applies it in both / only the
positive / only the negative travel direction of the input axis; ``$AN_CEC_MULT_BY_TABLE[t] = m``
(m = table number = index + 1) multiplies the table's values by those of table m-1 and adds the
product to the total compensation value (read here as: the table's own value still applies, the
product comes on top; docs/export.md). A compensation value moves the axis, so the table holds
the negative of the error (error = true − indicated): ``Σ tables = −e/1000`` mm.

The limits are a control's machine data: MD18342 ``$MN_MM_CEC_MAX_POINTS`` points per table
(828D: 8 tables of 200 points, fixed), MD32720 ``$MA_CEC_MAX_SUM`` the largest total compensation
of an axis; the defaults here are the 828D's and 1 mm, overridable.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from ..parametric_errors import AXES
from .decompose import Decomposition
from .plan import Plan, choose_greedy
from .splines import FloatArray, Knots, evaluate

__all__ = ["CecTable", "build_cec", "cec_correction_mm", "render_cec"]


@dataclass
class CecTable:
    """One CEC table as written: values (mm, rounded) at ``knots`` of ``input_axis``."""

    input_axis: int
    output_axis: int
    knots: Knots
    values_mm: FloatArray
    direction: int = 0
    mult_by: int | None = None  # 0-based index of the table whose values multiply this one's
    role: str = "plain"


def _round(values_mm: FloatArray, resolution_mm: float) -> FloatArray:
    return np.round(np.asarray(values_mm, dtype=float) / resolution_mm) * resolution_mm


def build_cec(
    d: Decomposition,
    *,
    max_tables: int,
    products: bool,
    resolution_mm: float,
    min_rms_um: float = 0.01,
) -> tuple[list[CecTable], Plan]:
    """The CEC tables (at most ``max_tables``) that carry most of the model, and the plan."""
    plan = choose_greedy(d, max_tables, products, min_rms_um)
    knots = d.knots
    # products first: their own values are then taken back by the plain tables, rounded as written
    prod_tables: list[tuple[CecTable, CecTable]] = []
    own: dict[tuple[int, int], FloatArray] = {}
    for t in plan.products:
        umax, vmax = float(np.max(np.abs(t.u))), float(np.max(np.abs(t.v)))
        g = float(np.sqrt(1000.0 * vmax / umax)) if umax > 0 and vmax > 0 else 1.0
        ta = _round(-t.u * g / 1000.0, resolution_mm)
        tb = _round(t.v / g, resolution_mm)
        a_tab = CecTable(t.a, t.k, knots[t.a], ta, 0, None, f"product {AXES[t.a]}×{AXES[t.b]} (a)")
        b_tab = CecTable(t.b, t.k, knots[t.b], tb, 0, None, f"product {AXES[t.a]}×{AXES[t.b]} (b)")
        prod_tables.append((a_tab, b_tab))
        own[(t.a, t.k)] = own.get((t.a, t.k), 0.0) + ta
        own[(t.b, t.k)] = own.get((t.b, t.k), 0.0) + tb
    tables: list[CecTable] = []
    for k in range(3):
        for a in range(3):
            if (a, k) not in plan.plain:
                continue
            base = -plan.plain[(a, k)] / 1000.0 - own.get((a, k), 0.0)
            if (a, k) in plan.directional:
                h = -plan.directional[(a, k)] / 1000.0
                tables.append(
                    CecTable(
                        a, k, knots[a], _round(base + h, resolution_mm), 1, None, "direction +"
                    )
                )
                tables.append(
                    CecTable(
                        a, k, knots[a], _round(base - h, resolution_mm), -1, None, "direction −"
                    )
                )
            else:
                tables.append(
                    CecTable(a, k, knots[a], _round(base, resolution_mm), 0, None, "plain")
                )
    for a_tab, b_tab in prod_tables:
        tables.append(a_tab)
        tables.append(b_tab)
        a_tab.mult_by = len(tables) - 1
    if len(tables) > max_tables:  # cannot happen: the plan respects the budget
        raise AssertionError(f"{len(tables)} CEC tables > {max_tables}")
    return tables, plan


def cec_correction_mm(tables: Sequence[CecTable], q_mm: FloatArray, dirs: FloatArray) -> FloatArray:
    """Total compensation (N, 3) mm the control adds to X, Y, Z at commanded positions ``q_mm``
    with travel directions ``dirs`` (N, 3) ±1 — the writer's own emulation of K3's rules."""
    q = np.asarray(q_mm, dtype=float)
    out = np.zeros((q.shape[0], 3))
    value = [evaluate(t.knots, t.values_mm, q[:, t.input_axis]) for t in tables]
    active = [
        np.ones(q.shape[0], bool)
        if t.direction == 0
        else np.sign(dirs[:, t.input_axis]) == t.direction
        for t in tables
    ]
    for i, t in enumerate(tables):
        out[:, t.output_axis] += np.where(active[i], value[i], 0.0)
        if t.mult_by is not None:
            m = t.mult_by
            both = active[i] & active[m]
            out[:, t.output_axis] += np.where(both, value[i] * value[m], 0.0)
    return out


#: Above this many combinations of points the peak total is bounded instead of enumerated.
_MAX_ENUMERATED = 4_000_000


def total_extremes_mm(
    tables: Sequence[CecTable], direction_axes: Sequence[int]
) -> tuple[FloatArray, bool]:
    """Largest |total compensation| per axis (3,) mm over every combination of the tables'
    points (sums and products of piecewise-linear tables peak there) and travel directions, and
    whether it is exact (True) or, for very large tables, an upper bound (the sum of each
    table's largest |value| and each product's largest |factors|)."""
    if not tables:
        return np.zeros(3), True
    knots_by_axis: dict[int, FloatArray] = {t.input_axis: t.knots.positions() for t in tables}
    axes_pos = [knots_by_axis.get(a, np.zeros(1)) for a in range(3)]
    shape = tuple(len(p) for p in axes_pos)
    if int(np.prod(shape)) > _MAX_ENUMERATED:
        bound = np.zeros(3)
        for t in tables:
            bound[t.output_axis] += float(np.max(np.abs(t.values_mm)))
            if t.mult_by is not None:
                other = tables[t.mult_by].values_mm
                bound[t.output_axis] += float(np.max(np.abs(t.values_mm)) * np.max(np.abs(other)))
        return bound, False
    peak = np.zeros(3)
    combos = (
        np.array(np.meshgrid(*[[1.0, -1.0]] * len(direction_axes), indexing="ij"))
        .reshape(len(direction_axes), -1)
        .T
        if direction_axes
        else np.zeros((1, 0))
    )
    for combo in combos:
        total = np.zeros((3, *shape))
        dsign = np.ones(3)
        for j, a in enumerate(direction_axes):
            dsign[a] = combo[j]

        def along(t: CecTable) -> FloatArray:
            view = [1, 1, 1]
            view[t.input_axis] = shape[t.input_axis]
            return t.values_mm.reshape(view)

        for t in tables:
            if t.direction != 0 and t.direction != dsign[t.input_axis]:
                continue
            total[t.output_axis] = total[t.output_axis] + along(t)
            if t.mult_by is not None:
                total[t.output_axis] = total[t.output_axis] + along(t) * along(tables[t.mult_by])
        peak = np.maximum(peak, np.abs(total).reshape(3, -1).max(axis=1))
    return peak, True


def _num(v: float) -> str:
    text = f"{v:.4f}"
    return "0.0000" if text in ("-0.0000", "0.0000") else text


def render_cec(tables: Sequence[CecTable], axis_names: Sequence[str], header: Sequence[str]) -> str:
    """The ``%_N_NC_CEC_INI`` file: ``header`` lines become ``;`` comments after CHANDATA(1)."""
    lines = ["%_N_NC_CEC_INI", "CHANDATA(1)"]
    lines += [f"; {h}" if h else ";" for h in header]
    for t, tab in enumerate(tables):
        lines.append(
            f"; table {t}: {AXES[tab.input_axis].upper()} -> {AXES[tab.output_axis].upper()}, "
            f"{tab.role}, {tab.knots.count} points"
        )
        for n, v in enumerate(tab.values_mm):
            lines.append(f"$AN_CEC[{t},{n}]={_num(float(v))}")
        lines += [
            f"$AN_CEC_INPUT_AXIS[{t}]=({axis_names[tab.input_axis]})",
            f"$AN_CEC_OUTPUT_AXIS[{t}]=({axis_names[tab.output_axis]})",
            f"$AN_CEC_STEP[{t}]={_num(tab.knots.step_mm)}",
            f"$AN_CEC_MIN[{t}]={_num(tab.knots.start_mm)}",
            f"$AN_CEC_MAX[{t}]={_num(tab.knots.end_mm)}",
            f"$AN_CEC_DIRECTION[{t}]={tab.direction}",
            f"$AN_CEC_MULT_BY_TABLE[{t}]={0 if tab.mult_by is None else tab.mult_by + 1}",
            f"$AN_CEC_IS_MODULO[{t}]=0",
        ]
    lines.append("M17")
    return "\n".join(lines) + "\n"
