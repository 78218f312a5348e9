"""SINUMERIK sag / cross-error compensation (CEC) tables: ``%_N_NC_CEC_INI`` (Function Manual
Extended Functions, K3 "Compensations", 4.4 interpolatory compensation; docs/export.md quotes
the passages, with pages).

**Sign (what the documentation implies; not confirmed on a control).** No Siemens passage says in
so many words how ``$AN_CEC`` acts on the compensation (output) axis. The only explicit sign
statement of K3 is for the interpolatory compensation of the same chapter (MSEC, 4.4.2.1, p. 238
of 6FC5397-1BP40-3BA1): "A positive compensation value causes the corresponding machine axis to
move in the negative direction"; the chapter's common figure of the interpolation (Figure 4-4,
p. 237, drawn for the "compensation axis" over the "base axis") shows the compensation curve as
the linear interpolation of the *error curve*, and the MSEC example (p. 242) does the same. So
the table holds the error and the control moves the axis by minus the table: here
``Σ tables = +e/1000`` mm with e = true − indicated (µm), the axis moved by ``−Σ``, what the
tables take off is ``+1000·Σ`` µm. ``cmm-comp export --check-table`` writes a one-table step that
settles this on the machine; ``ExportOptions.invert_sign`` writes the opposite if it fails.

Each table ``t`` adds, at the commanded position of its *basic* (input) axis, a value interpolated
linearly between equidistant points ``$AN_CEC[t,N]`` (mm) at ``$AN_CEC_MIN[t] + N·$AN_CEC_STEP[t]``,
the first and last values held beyond ``$AN_CEC_MIN``/``$AN_CEC_MAX``; ``$AN_CEC_DIRECTION[t]``
= 0/1/−1 applies it in both / only the positive / only the negative travel direction of the
input axis; the values of all tables of an output axis add up.

**Products (off by default).** ``$AN_CEC_MULT_BY_TABLE[t] = m`` multiplies table t by table number
m (= index + 1) and adds the product "as an additional compensation value" (p. 249). Siemens'
only worked example (foundation sag, p. 252: ΔX1 = Z1·sinβ(X1), table 1 holds sinβ(X1), the
referenced table 2 holds Z1 itself, in mm) only makes sense if the referenced table acts as the
factor and not on its own (else X1 would move by Z1). Written only with ``products=True`` and in
those semantics: the referencing table holds a small "rate" (like sinβ; its own value, if the
control adds it, is below 1/1000 of the product), the referenced table an "arm" scaled to
±1000 mm (like Z1) that the writer counts only as the factor.

The limits are a control's machine data: MD18342 ``$MN_MM_CEC_MAX_POINTS`` points per table
(828D: 8 tables of 200 points, fixed), MD32720 ``$MA_CEC_MAX_SUM`` the largest total compensation
of an axis (what the control does beyond it is not documented in the pages we read); the
defaults here are the 828D's and 1 mm, overridable.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from ..parametric_errors import AXES
from .decompose import Decomposition
from .plan import Plan, choose_greedy
from .splines import FloatArray, Knots, evaluate

__all__ = [
    "ARM_SCALE_MM",
    "RATE_DECIMALS",
    "CecTable",
    "build_cec",
    "cec_correction_mm",
    "referenced_tables",
    "render_cec",
]

#: Largest |value| of a product's referenced ("arm") table, mm — Siemens' example holds Z1 there.
ARM_SCALE_MM = 1000.0
#: Decimals written for a product's referencing ("rate") table, whose values are ~ product/1000.
RATE_DECIMALS = 12
#: Decimals of every other table: 0.1 µm.
PLAIN_DECIMALS = 4


@dataclass
class CecTable:
    """One CEC table as written: values (mm, rounded to ``decimals``) at ``knots`` of
    ``input_axis``; ``mult_by`` is the 0-based index of the table whose values multiply this
    one's (``$AN_CEC_MULT_BY_TABLE`` = mult_by + 1)."""

    input_axis: int
    output_axis: int
    knots: Knots
    values_mm: FloatArray
    direction: int = 0
    mult_by: int | None = None
    role: str = "plain"
    decimals: int = PLAIN_DECIMALS


def _round(values_mm: FloatArray, decimals: int) -> FloatArray:
    return np.round(np.asarray(values_mm, dtype=float), decimals)


def referenced_tables(tables: Sequence[CecTable]) -> set[int]:
    """Indices of the tables another table multiplies by: in Siemens' example they act only as
    the factor."""
    return {t.mult_by for t in tables if t.mult_by is not None}


def build_cec(
    d: Decomposition,
    *,
    max_tables: int,
    products: bool,
    sign: int = 1,
    min_rms_um: float = 0.01,
) -> tuple[list[CecTable], Plan]:
    """The CEC tables (at most ``max_tables``) that carry most of the model, and the plan.

    ``sign`` +1 writes the documentation's reading (table = error, mm); −1 its opposite (for a
    control whose ``--check-table`` showed the other sign)."""
    plan = choose_greedy(d, max_tables, products, min_rms_um)
    knots = d.knots
    tables: list[CecTable] = []
    for k in range(3):
        for a in range(3):
            if (a, k) not in plan.plain:
                continue
            base = sign * plan.plain[(a, k)] / 1000.0
            if (a, k) in plan.directional:
                h = sign * plan.directional[(a, k)] / 1000.0
                for direction, values, role in (
                    (1, base + h, "direction +"),
                    (-1, base - h, "direction -"),
                ):
                    tables.append(
                        CecTable(
                            a, k, knots[a], _round(values, PLAIN_DECIMALS), direction, None, role
                        )
                    )
            else:
                tables.append(CecTable(a, k, knots[a], _round(base, PLAIN_DECIMALS)))
    for t in plan.products:
        vmax = float(np.max(np.abs(t.v)))
        if vmax == 0.0:
            continue
        g = ARM_SCALE_MM / vmax  # the arm table spans ±ARM_SCALE_MM
        arm = _round(t.v * g, PLAIN_DECIMALS)
        rate = _round(sign * t.u / (1000.0 * g), RATE_DECIMALS)
        name = f"{AXES[t.a]}*{AXES[t.b]}"
        tables.append(
            CecTable(
                t.a,
                t.k,
                knots[t.a],
                rate,
                0,
                len(tables) + 1,
                f"product {name}: rate",
                RATE_DECIMALS,
            )
        )
        tables.append(
            CecTable(
                t.b,
                t.k,
                knots[t.b],
                arm,
                0,
                None,
                f"product {name}: arm (referenced, only the factor)",
            )
        )
    if len(tables) > max_tables:  # cannot happen: the plan respects the budget
        raise AssertionError(f"{len(tables)} CEC tables > {max_tables}")
    return tables, plan


def cec_correction_mm(tables: Sequence[CecTable], q_mm: FloatArray, dirs: FloatArray) -> FloatArray:
    """Total compensation value (N, 3) mm of X, Y, Z at commanded positions ``q_mm`` with travel
    directions ``dirs`` (N, 3) ±1 — the writer's own emulation: the sum of the tables, a
    referenced table only as the factor of its product (the axis then moves by minus this)."""
    q = np.asarray(q_mm, dtype=float)
    out = np.zeros((q.shape[0], 3))
    value = [evaluate(t.knots, t.values_mm, q[:, t.input_axis]) for t in tables]
    active = [
        np.ones(q.shape[0], bool)
        if t.direction == 0
        else np.sign(dirs[:, t.input_axis]) == t.direction
        for t in tables
    ]
    factors = referenced_tables(tables)
    for i, t in enumerate(tables):
        if i not in factors:
            out[:, t.output_axis] += np.where(active[i], value[i], 0.0)
        if t.mult_by is not None:
            m = t.mult_by
            out[:, t.output_axis] += np.where(active[i] & active[m], value[i] * value[m], 0.0)
    return out


#: Above this many combinations of points the peak total is bounded instead of enumerated.
_MAX_ENUMERATED = 4_000_000


def total_extremes_mm(
    tables: Sequence[CecTable], direction_axes: Sequence[int]
) -> tuple[FloatArray, bool]:
    """Largest |total compensation| per axis (3,) mm over every combination of the tables'
    points (sums and products of piecewise-linear tables peak there) and travel directions, and
    whether it is exact (True) or, for very large tables, an upper bound (the sum of each
    counted table's largest |value| and each product's largest |factors|)."""
    if not tables:
        return np.zeros(3), True
    factors = referenced_tables(tables)
    knots_by_axis: dict[int, FloatArray] = {t.input_axis: t.knots.positions() for t in tables}
    axes_pos = [knots_by_axis.get(a, np.zeros(1)) for a in range(3)]
    shape = tuple(len(p) for p in axes_pos)
    if int(np.prod(shape)) > _MAX_ENUMERATED:
        bound = np.zeros(3)
        for i, t in enumerate(tables):
            if i not in factors:
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

    def along(t: CecTable) -> FloatArray:
        view = [1, 1, 1]
        view[t.input_axis] = shape[t.input_axis]
        return t.values_mm.reshape(view)

    for combo in combos:
        total = np.zeros((3, *shape))
        dsign = np.ones(3)
        for j, a in enumerate(direction_axes):
            dsign[a] = combo[j]
        for i, t in enumerate(tables):
            if t.direction != 0 and t.direction != dsign[t.input_axis]:
                continue
            if i not in factors:
                total[t.output_axis] = total[t.output_axis] + along(t)
            if t.mult_by is not None:
                total[t.output_axis] = total[t.output_axis] + along(t) * along(tables[t.mult_by])
        peak = np.maximum(peak, np.abs(total).reshape(3, -1).max(axis=1))
    return peak, True


def _num(v: float, decimals: int = PLAIN_DECIMALS) -> str:
    text = f"{v:.{decimals}f}"
    return f"{0:.{decimals}f}" if float(text) == 0.0 else text


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
            lines.append(f"$AN_CEC[{t},{n}]={_num(float(v), tab.decimals)}")
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
