"""What an export rests on that no public document settles (:func:`unverified`), and the small
tables that settle it on the machine before anyone trusts the rest (:func:`check_tables`:
``cmm-comp export MACHINE --format F --check-table -o DIR``).

The sign check is one table with a known step: ``+CHECK_STEP_MM`` on the output axis while the
input axis is near the centre of its travel, 0 elsewhere, over the whole travel (so no
behaviour beyond a table's ends is involved). The documentation's reading (SINUMERIK K3: "A
positive compensation value causes the corresponding machine axis to move in the negative
direction"; TwinCAT: a value is actual − set and taken off) says the output axis then moves by
``−CHECK_STEP_MM``; a dial indicator shows which. The SINUMERIK product check (only with
``--products``) is two constant tables, one multiplying the other, whose readings tell the
competing readings of ``$AN_CEC_MULT_BY_TABLE`` apart. Positions mm; values mm (TwinCAT 0.1 µm).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from ..machine import Machine
from ..parametric_errors import AXES
from .limits import ExportError
from .sinumerik import CecTable, cec_correction_mm, render_cec
from .splines import Knots, make_knots
from .twincat import TwinCatList, render_startup, render_twincat

__all__ = ["CHECK_STEP_MM", "CheckResult", "check_tables", "unverified"]

#: The known step of the sign check, mm (10 µm: plain on a 1 µm dial indicator, harmless).
CHECK_STEP_MM = 0.010
#: Points of a check table over the input axis' travel (the step rises and falls over 2 of them).
_CHECK_POINTS = 101
#: Product check: the referencing table's constant value and the referenced table's, mm.
PRODUCT_RATE_MM = 0.05
PRODUCT_ARM_MM = 0.2
_MIN_TRAVEL_MM = 10.0


@dataclass
class CheckResult:
    """The check files (name → text; ``check-table.txt`` holds the instructions) and the
    figures the instructions state (``report``, JSON-ready)."""

    format: str
    files: dict[str, str]
    text: str
    report: dict[str, Any] = field(default_factory=dict)


def unverified(fmt: str, *, products: bool = False, cross: bool = False) -> list[dict[str, str]]:
    """The points of ``fmt``'s tables no public passage settles: what is assumed, where from,
    and the measurement on a real control that settles it (docs/export.md, "Not verified")."""
    check = f"cmm-comp export MACHINE --format {fmt} --check-table -o DIR"
    check_products = f"cmm-comp export MACHINE --format {fmt} --check-table --products -o DIR"
    if fmt == "sinumerik-cec":
        items = [
            {
                "point": "sign of $AN_CEC on the output axis",
                "assumed": "the table holds the error (true - indicated, mm) and the control moves "
                "the output axis by minus the total",
                "source": "K3 4.4.2.1 (MSEC): 'A positive compensation value causes the "
                "corresponding machine axis to move in the negative direction'; Figure 4-4: the "
                "compensation curve drawn on the error curve",
                "settle": f"{check}: the one-table step; a dial indicator shows the output axis "
                f"move by -{CHECK_STEP_MM:.3f} mm (else re-export with --invert-sign)",
            },
            {
                "point": "MD32720 $MA_CEC_MAX_SUM",
                "assumed": "a limit of |total compensation| per axis, products included, a "
                "referenced (factor) table not counted on its own; default 1 mm here",
                "source": "its name only: no passage on its default or on what the control does "
                "beyond it was read",
                "settle": "read MD32720 on the control and pass it as --cec-max-sum-mm; the "
                "export refuses tables whose total exceeds it",
            },
        ]
        if products:
            items.insert(
                1,
                {
                    "point": "$AN_CEC_MULT_BY_TABLE (table products)",
                    "assumed": "Siemens' example: the referenced table acts only as the factor; "
                    "the referencing table's own value is added (written below 1/1000 of the "
                    "product, so either way it does not matter)",
                    "source": "K3 p. 249 ('The product is added as an additional compensation "
                    "value'), p. 252 (foundation sag: DX1 = Z1*sin(beta(X1)), table 2 holds Z1)",
                    "settle": f"{check_products}: the product check (two constant tables) gives "
                    "a different indicator reading for each reading of the manual",
                },
            )
        return items
    if fmt == "twincat-cnc" and cross:
        return [
            {
                "point": "sign of kw.crosscomp.table[i].correction",
                "assumed": "the leadscrew tables' meaning: actual - set in 0.1 um, taken off the "
                "slave axis' set point",
                "source": "no page states it ('relative compensation value for the slave axis')",
                "settle": f"{check}: the one-table step; the slave axis moves by "
                f"-{CHECK_STEP_MM:.3f} mm (else re-export with --invert-sign)",
            }
        ]
    return []


def _check_knots(machine: Machine, axis: int) -> Knots:
    lo, hi = float(machine.volume.lower_mm[axis]), float(machine.volume.upper_mm[axis])
    if hi - lo < _MIN_TRAVEL_MM:
        raise ExportError(
            f"--check-table: the {AXES[axis].upper()} travel is {hi - lo:g} mm; the check needs "
            f"at least {_MIN_TRAVEL_MM:g} mm of the input axis (--check-axes picks another)"
        )
    return make_knots(axis, lo, hi, _CHECK_POINTS, 1e-4)


def _step_values(kn: Knots) -> tuple[np.ndarray, float, float]:
    """Values (in units of the step) 1 at the three points around the centre, 0 elsewhere; the
    position inside (centre point) and outside (4 steps below it: value 0) the step, mm."""
    i_c = (kn.count - 1) // 2
    v = np.zeros(kn.count)
    v[i_c - 1 : i_c + 2] = 1.0
    pos = kn.positions()
    return v, float(pos[i_c]), float(pos[i_c - 4])


def check_tables(
    machine: Machine,
    fmt: str,
    *,
    input_axis: int = 1,
    output_axis: int = 0,
    axis_names: Sequence[str] = ("AX1", "AX2", "AX3"),
    axis_numbers: Sequence[int] = (1, 2, 3),
    products: bool = False,
) -> CheckResult:
    """The check files of ``fmt`` for ``machine``: a step of the output axis as a function of the
    input axis (0…2), and, for ``sinumerik-cec`` with ``products``, the product check."""
    if fmt == "linuxcnc":
        raise ExportError(
            "--check-table: linuxcnc's sign was checked against LinuxCNC's source "
            "(docs/export.md): there is no unverified sign to check"
        )
    if fmt not in ("sinumerik-cec", "twincat-cnc"):
        raise ExportError(
            f"--format must be sinumerik-cec or twincat-cnc for --check-table, got {fmt!r}"
        )
    if input_axis == output_axis:
        raise ExportError(
            "--check-axes: input and output must differ (the check moves one axis and watches "
            "the other)"
        )
    kn = _check_knots(machine, input_axis)
    unit, inside, outside = _step_values(kn)
    a, k = AXES[input_axis].upper(), AXES[output_axis].upper()
    report: dict[str, Any] = {
        "format": fmt,
        "machine": machine.name,
        "input_axis": AXES[input_axis],
        "output_axis": AXES[output_axis],
        "table_positions_mm": kn.positions().tolist(),
        "step_mm": CHECK_STEP_MM,
        "inside_mm": inside,
        "outside_mm": outside,
        "expected_output_move_mm": {"documented": -CHECK_STEP_MM, "opposite": CHECK_STEP_MM},
    }
    files: dict[str, str] = {}
    if fmt == "sinumerik-cec":
        table = CecTable(input_axis, output_axis, kn, np.round(unit * CHECK_STEP_MM, 4))
        table.role = f"SIGN CHECK: +{CHECK_STEP_MM:.4f} mm on {k} around {a} = {inside:g} mm"
        header = [
            f"cmm-comp export --check-table: SIGN CHECK for {machine.name} - not a compensation;",
            "load it alone, check with a dial indicator (check-table.txt), then remove it",
        ]
        files["NC_CEC.INI"] = render_cec([table], axis_names, header)
        text = _cec_sign_text(machine, report, axis_names, input_axis, output_axis)
        if products:
            prod_files, prod_report, prod_text = _cec_product_check(
                machine, input_axis, output_axis, axis_names
            )
            files.update(prod_files)
            report["product_check"] = prod_report
            text += "\n" + prod_text
        report["unverified"] = unverified(fmt, products=products)
    else:
        lo_k, hi_k = machine.volume.lower_mm[output_axis], machine.volume.upper_mm[output_axis]
        lead = make_knots(output_axis, float(lo_k), float(hi_k), 2, 1e-4)
        entry = TwinCatList(
            output_axis,
            lead,
            np.zeros(2, np.int64),
            np.zeros(2, np.int64),
            False,
            input_axis,
            kn,
            np.round(unit * CHECK_STEP_MM * 1e4).astype(np.int64),
        )
        header = [
            f"cmm-comp export --check-table: SIGN CHECK of the cross compensation, {machine.name};",
            "not a compensation: load it alone, check with a dial indicator, then remove it",
        ]
        nr = axis_numbers[output_axis]
        files[f"achskw{nr}.lis"] = render_twincat(entry, axis_numbers, axis_names, header)
        files["startup-snippet.txt"] = render_startup([entry], axis_numbers)
        text = _twincat_sign_text(machine, report, axis_numbers, input_axis, output_axis)
        report["unverified"] = unverified(fmt, cross=True)
    files["check-table.txt"] = text
    return CheckResult(fmt, files, text, report)


def _indicator_steps(k: str) -> list[str]:
    return [
        f"Put a dial test indicator (1 µm divisions, >= 0.5 mm travel) against the tool holder "
        f"in the {k} direction, {k} standing anywhere inside its travel. Learn which way the "
        f"pointer turns for +{k}: jog {k} by +0.005 mm with the handwheel (1 µm increments) and "
        "back. Set the indicator to zero.",
    ]


def _step_facts(rep: dict[str, Any], a_idx: int, k_idx: int) -> tuple[Any, ...]:
    """(input name, output name, step mm, inside mm, outside mm, positions, centre index)."""
    pos = rep["table_positions_mm"]
    return (
        AXES[a_idx].upper(),
        AXES[k_idx].upper(),
        rep["step_mm"],
        rep["inside_mm"],
        rep["outside_mm"],
        pos,
        (len(pos) - 1) // 2,
    )


def _cec_sign_text(
    machine: Machine, rep: dict[str, Any], names: Sequence[str], a_idx: int, k_idx: int
) -> str:
    a, k, s, inside, outside, pos, i_c = _step_facts(rep, a_idx, k_idx)
    lines = [
        f"SINUMERIK CEC sign check for {machine.name} ({machine.model})",
        "",
        f"NC_CEC.INI holds one table (index 0): basic (input) axis {a} = {names[a_idx]}, "
        f"compensation (output) axis {k} = {names[k_idx]}, {len(pos)} points {pos[1] - pos[0]:g} mm "
        f"apart over the {a} travel; $AN_CEC = +{s:.4f} mm at {a} = {pos[i_c - 1]:g}, {pos[i_c]:g}, "
        f"{pos[i_c + 1]:g} mm, 0 at every other point (linear in between): +{s:.4f} mm while "
        f"{a} is between {pos[i_c - 1]:g} and {pos[i_c + 1]:g} mm, nothing below {pos[i_c - 2]:g} "
        f"or above {pos[i_c + 2]:g} mm.",
        "",
        "1. Save the control's CEC data. With MD32710 $MA_CEC_ENABLE = 0 for the output axis, load "
        "this NC_CEC.INI only (no other CEC table active); set SD41300 $SN_CEC_TABLE_ENABLE[0] = 1 "
        "and MD32710 $MA_CEC_ENABLE = 1 for the output axis; NCK reset; reference the axes.",
        f"2. Move {a} to {outside:g} mm (the table gives 0 there). " + _indicator_steps(k)[0],
        f"3. Move {a} to {inside:g} mm ({k} stays commanded where it is) and read the indicator. "
        f"The service display 'Sag/temperature' of {k} should show {s:.4f} (the table is active; "
        "the display does not tell the direction).",
        f"   - the tool moved {s:.3f} mm in -{k}: the documentation's reading holds (a positive "
        "value moves the axis negative): load the exported NC_CEC.INI as written.",
        f"   - the tool moved {s:.3f} mm in +{k}: the opposite holds: do not load the exported "
        "tables; export again with --invert-sign (and repeat this check to be sure).",
        "   - nothing moved: the table is not active (option, enable data, referencing); "
        "any other amount: the control does something this export does not model: stop.",
        f"4. Move {a} back to {outside:g} mm: the indicator returns to zero (within 1 µm).",
        f"   Without moving {a} (no sliding of the indicator tip): at {a} = {inside:g} mm toggle "
        "SD41300 $SN_CEC_TABLE_ENABLE[0] between 0 and 1 (MDA or the setting-data screen; K3 "
        "says tables can be switched from the part program): the same readings apply.",
        f"   If the indicator tip slides along {a} on a face of the tool holder, that face must be "
        f"parallel to {a} within 1 µm over {abs(inside - outside):g} mm.",
        "5. Remove the check table (SD41300[0] = 0, or load the exported NC_CEC.INI over it).",
    ]
    return "\n".join(lines) + "\n"


def _cec_product_check(
    machine: Machine, a_idx: int, k_idx: int, names: Sequence[str]
) -> tuple[dict[str, str], dict[str, Any], str]:
    b_idx = next(i for i in range(3) if i not in (a_idx, k_idx))
    lo, hi = machine.volume.lower_mm, machine.volume.upper_mm
    rate_kn = make_knots(a_idx, float(lo[a_idx]), float(hi[a_idx]), 2, 1e-4)
    arm_kn = make_knots(b_idx, float(lo[b_idx]), float(hi[b_idx]), 2, 1e-4)
    rate = CecTable(a_idx, k_idx, rate_kn, np.full(2, PRODUCT_RATE_MM), 0, 1, "PRODUCT CHECK: rate")
    arm = CecTable(b_idx, k_idx, arm_kn, np.full(2, PRODUCT_ARM_MM), 0, None, "PRODUCT CHECK: arm")
    header = [
        f"cmm-comp export --check-table --products: PRODUCT CHECK for {machine.name} - not a "
        "compensation; load it alone after the sign check (check-table.txt), then remove it",
    ]
    r, m = PRODUCT_RATE_MM, PRODUCT_ARM_MM
    q = np.array([[(lo[i] + hi[i]) / 2 for i in range(3)]])
    ours = float(cec_correction_mm([rate, arm], q, np.ones((1, 3)))[0, k_idx])
    readings = {
        "this export (Siemens' example: the referenced table only as the factor)": -ours,
        "product only (neither table's own value)": -(r * m),
        "both tables' own values and the product": -(r + m + r * m),
        "the referenced table's own value and the product": -(m + r * m),
        "no product (both tables' own values only)": -(r + m),
    }
    k = AXES[k_idx].upper()
    lines = [
        f"SINUMERIK CEC product check (only if you want --products), {machine.name}",
        "",
        f"NC_CEC_PRODUCT.INI: table 0 ({AXES[a_idx].upper()} -> {k}) = {r:.4f} mm everywhere with "
        f"$AN_CEC_MULT_BY_TABLE[0] = 2; table 1 ({AXES[b_idx].upper()} -> {k}) = {m:.4f} mm "
        "everywhere. Do the sign check first; the readings below assume it showed the "
        "documentation's sign (else every sign flips).",
        "",
        "1. Load NC_CEC_PRODUCT.INI as NC_CEC.INI (as in step 1 of the sign check), both "
        "SD41300 $SN_CEC_TABLE_ENABLE[0] and [1] = 0; set the indicator as in step 2; all axes "
        "stand still.",
        f"2. Set SD41300[1] = 1 (the referenced table alone): {k} should not move (this "
        f"export's reading); {-m:+.3f} mm means a referenced table acts on its own too: never "
        "use --products on this control.",
        f"3. Set SD41300[0] = 1 as well and read the move of {k} (mm):",
    ]
    lines += [f"   {v:+.3f}  {name}" for name, v in readings.items()]
    lines.append(
        "   Use --products only if the first line's reading appears; then remove the tables."
    )
    report = {
        "rate_mm": r,
        "arm_mm": m,
        "arm_axis": AXES[b_idx],
        "expected_output_move_mm": readings,
    }
    files = {"NC_CEC_PRODUCT.INI": render_cec([rate, arm], names, header)}
    return files, report, "\n".join(lines) + "\n"


def _twincat_sign_text(
    machine: Machine, rep: dict[str, Any], numbers: Sequence[int], a_idx: int, k_idx: int
) -> str:
    a, k, s, inside, outside, pos, i_c = _step_facts(rep, a_idx, k_idx)
    nr = numbers[k_idx]
    lines = [
        f"TwinCAT CNC cross-compensation sign check for {machine.name} ({machine.model})",
        "",
        f"achskw{nr}.lis is the list of the slave axis {k} (logical axis {nr}): a leadscrew table "
        f"of zeros and a cross table with master axis {a} (logical axis {numbers[a_idx]}), "
        f"{len(pos)} setpoints over the {a} travel, correction +{round(s * 1e4)} (0.1 µm) at "
        f"{a} = {pos[i_c - 1]:g}, {pos[i_c]:g}, {pos[i_c + 1]:g} mm and 0 elsewhere.",
        "",
        f"1. Save the CNC's lists. Put this list (and startup-snippet.txt's entries) in place of "
        f"axis {nr}'s list, lr_param.crosscomp 1 for axis {nr}, restart the CNC, home the axes.",
        f"2. Move {a} to {outside:g} mm (correction 0 there). " + _indicator_steps(k)[0],
        f"3. Move {a} to {inside:g} mm and read the indicator. (The normal position display does "
        "not show compensations; the position output to the drive does.)",
        f"   - {k} moved {s:.3f} mm in -{k}: a correction is taken off like a leadscrew value "
        "(actual - set), as this export writes it: load the exported lists as written.",
        f"   - {k} moved {s:.3f} mm in +{k}: the opposite: export again with --invert-sign.",
        "   - nothing: the cross compensation is not active (activation, homing of the master); "
        "any other amount: stop.",
        f"4. Move {a} back to {outside:g} mm: the indicator returns to zero. If the tip slides "
        f"along {a} on a face, that face must be parallel to {a} within 1 µm over "
        f"{abs(inside - outside):g} mm.",
        "5. Restore the saved list.",
    ]
    return "\n".join(lines) + "\n"
