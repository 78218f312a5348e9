"""The diagnosis in words: what a metrologist writes after reading the figures.

:func:`report_markdown` states, for each effect, its ISO 230-1 name (E_XX, the positioning
error of X; E_YX, the straightness of X in Y; E_AX, E_BX, E_CX its roll, pitch and yaw …), its
size and shape (period, amplitude and phase of a cyclic error; the law of a chirped one; the
extent of a smooth curve; the change of a drift along the axis), which instrument carries it
and the evidence for that, what it explains, and what the session cannot tell apart;
then the periods refused and why, and the gain held out. :func:`verdict_line` is the one line
the terminal prints.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np

from ..effects import Effect, ParametricEffect
from ..parametric_errors import ISO_ALIASES
from .outcome import Diagnosis

__all__ = ["iso_name", "report_markdown", "verdict_line"]

_OURS_TO_ISO = {ours: iso for iso, ours in ISO_ALIASES.items() if len(iso) == 3}
_SQUARENESS = {"alpha": "E_C(0X)Y", "beta1": "E_B(0X)Z", "beta2": "E_A(0Y)Z"}
_MEANING = {"d": "straightness", "e": "angular error"}
_ROT = {"x": "roll", "y": "pitch", "z": "yaw"}
_SOURCE_WORDS = {
    "machine": "the machine",
    "reference": "the reference instrument",
    "either": "the machine or the reference instrument (the session cannot tell which)",
}


def iso_name(component: str) -> str:
    """``dx_x`` → ``E_XX`` (ISO 230-1), a squareness → its ISO name; else the name itself."""
    if component in _SQUARENESS:
        return _SQUARENESS[component]
    iso = _OURS_TO_ISO.get(component)
    return f"E_{iso[1:]}" if iso else component


def _component_words(component: str) -> str:
    if component in _SQUARENESS:
        return f"squareness {component}"
    kind, direction, axis = component[0], component[1], component[-1]
    if kind == "d" and direction == axis:
        return f"positioning error of {axis.upper()}"
    if kind == "d":
        return f"straightness of {axis.upper()} in {direction.upper()}"
    rot = {"x": "A", "y": "B", "z": "C"}[direction]
    return f"angular error {rot} of {axis.upper()} (rotation about {direction.upper()})"


def _head(e: dict[str, Any]) -> str:
    cause, axis = e["cause"], e.get("axis")
    comp = e.get("component")
    if comp:
        return f"{iso_name(comp)} ({_component_words(comp)})"
    if cause in ("periodic", "reversal", "drift") and axis:
        return f"E_{axis.upper()}{axis.upper()} (positioning error of {axis.upper()}), {cause}"
    if cause.startswith("reference_") or cause == "latency":
        return f"reference instrument on {axis or '?'}: {cause.replace('_', ' ')}"
    return f"{cause.replace('_', ' ')}" + (f" of {axis.upper()}" if axis else "")


def _phase_deg(p: dict[str, Any]) -> float:
    return math.degrees(math.atan2(p.get("b_sin_um", 0.0), p.get("a_cos_um", 0.0)))


def _law_words(p: dict[str, Any]) -> str:
    law = p.get("law", "constant")
    ends = p.get("period_at_ends_mm") or [float("nan"), float("nan")]
    period = p.get("period_mm", float("nan"))
    if law == "triangulation":
        return (
            f"a period that follows a triangulation sensor's distance law, p(r) = P·((r − r0)/"
            f"(c − r0))² with P = {period:.4g} mm at the centre of the travel and r0 = "
            f"{p.get('r0_mm', float('nan')):.4g} mm (axis frame): {ends[0]:.4g} mm at one end of "
            f"the travel, {ends[1]:.4g} mm at the other"
        )
    if law == "smooth":
        knots = ", ".join(
            f"{k:.4g} mm: {v:.4g}"
            for k, v in zip(p.get("knots_mm", []), p.get("period_at_knots_mm", []), strict=False)
        )
        return f"a period that changes smoothly along the travel ({knots} mm)"
    return f"period {period:.4g} mm"


def _shape_words(e: dict[str, Any], eff: Effect | None) -> str:
    cause, p = e["cause"], e.get("parameters", {})
    if cause in ("periodic", "reference_ripple"):
        text = f"{_law_words(p)}; amplitude {p.get('amplitude_um', float('nan')):.3g} µm"
        if p.get("law", "constant") == "constant":
            text += f", phase {_phase_deg(p):.0f}° (cosine at position 0)"
        else:
            text += " at most (it changes along the travel)"
        harm = [k for k in p if k.startswith("harmonic_") and k.endswith("amplitude_um")]
        if harm:
            text += "; harmonics " + ", ".join(f"{p[k]:.2g} µm" for k in sorted(harm))
        return text
    if cause == "reversal":
        return (
            f"reversal value B = {p.get('reversal_mean_um', float('nan')):.3g} µm at the centre "
            f"of the travel, changing by {4 * abs(p.get('half_step_slope_um', 0.0)):.2g} µm from "
            "end to end (backlash, hysteresis of the drive)"
        )
    if cause == "drift":
        return _drift_words(p)
    if cause == "latency":
        return (
            f"the reference's timestamps are late by {p.get('latency_ms', float('nan')):.3g} ms "
            "on the axis' (an error −v·τ: it flips sign with the direction of travel and "
            "vanishes at rest)"
        )
    if cause == "reference_scale":
        text = f"scale {p.get('scale_um_per_m', float('nan')):.3g} µm/m"
        if "cosine_angle_mrad" in p:
            text += f" (a cosine misalignment of {p['cosine_angle_mrad']:.3g} mrad)"
        return text
    if cause == "reference_drift":
        return (
            f"{p.get('offset_range_um', float('nan')):.3g} µm over the session, the same everywhere"
        )
    if cause == "reference_nonlinearity":
        return f"a smooth curve of the reading, {p.get('peak_to_peak_um', float('nan')):.3g} µm p-p"
    if isinstance(eff, ParametricEffect) and eff.component not in _SQUARENESS:
        q = np.linspace(*eff.span_mm, 201)
        curve = eff.value(q, float(eff.span_mm[0]))
        return (
            f"a smooth curve along the travel, {float(np.ptp(curve)):.3g} µm peak to peak over "
            f"{eff.span_mm[0]:.4g}…{eff.span_mm[1]:.4g} mm (Legendre orders up to "
            f"{max(eff.orders)})"
        )
    keys = {k: v for k, v in p.items() if isinstance(v, int | float)}
    return ", ".join(f"{k} {v:.3g}" for k, v in list(keys.items())[:6])


def _drift_words(p: dict[str, Any]) -> str:
    shape = p.get("shape", "uniform")
    if shape == "smooth":
        ch = p.get("change_along_axis_um", {})
        pairs = ", ".join(
            f"{q:.3g} mm: {c:+.3g}"
            for q, c in zip(ch.get("position_mm", []), ch.get("change_um", []), strict=False)
        )
        return (
            "changed during the session by an amount that depends on the position along the "
            f"axis (start → end, µm: {pairs}): a thermal change of the structure's shape — the "
            "temperature that drives it was not logged"
        )
    if shape == "expansion":
        fixed = p.get("fixed_point_u_mm")
        return (
            f"changed during the session in proportion to the distance from a fixed point "
            f"({fixed:+.4g} mm from the reference point): thermal expansion about where the "
            "structure is held — log its temperature and a thermal cause replaces this drift"
        )
    return f"{p.get('offset_range_um', float('nan')):.3g} µm over the session, the same everywhere"


def _evidence_words(e: dict[str, Any]) -> str:
    ev = e.get("evidence", {})
    out = [ev.get("summary", "")]
    lock = ev.get("locking", {})
    if "reversal_um" in lock:
        shifts = [
            f"{lock[k]:+.3g} µm in {k.split('_in_')[1].split('_coord')[0]} coordinates"
            for k in lock
            if k.startswith("shift_in_")
        ]
        out.append(
            f"between the two directions of travel (reversal {lock['reversal_um']:+.3g} µm) it "
            f"moved {' and '.join(shifts)}"
        )
    if "pass_phase_coherence" in lock:
        out.append(
            f"its phase holds from pass to pass (coherence {lock['pass_phase_coherence']:.2f} "
            f"over {lock['passes']} passes; ~{1 / math.sqrt(lock['passes']):.2f} if it did not)"
        )
    state = ev.get("reversal_by_state", {})
    if state:
        out.append(
            "reversal "
            + " and ".join(
                f"{v:.3g} µm {k.replace('_um', '').replace('_', ' ')}" for k, v in state.items()
            )
        )
    if "peak_ratio" in ev:
        out.append(
            f"a spectral peak {ev['peak_ratio']:.3g}× above its shoulders, the same in every "
            f"subset ({len(ev.get('subsets', []))} fits: halves of the session, directions, "
            "halves of the travel)"
        )
    return "; ".join(s for s in out if s)


def _unidentifiable(e: dict[str, Any]) -> str:
    alts = e.get("alternatives") or []
    if not alts:
        return ""
    names = ", ".join(
        f"{a.get('cause')} ({a.get('component') or a.get('axis') or ''}, {a.get('source', '?')})"
        for a in alts
    )
    advice = e.get("separate_by", "")
    return f"Cannot be told from: {names}." + (f" To separate them: {advice}." if advice else "")


def report_markdown(diagnosis: Diagnosis, title: str = "Diagnosis") -> str:
    """The report in words (Markdown)."""
    s = diagnosis.summary
    lines = [f"# {title}", ""]
    lines.append(
        f"{s['n_points']} points (of {s.get('n_points_given', s['n_points'])} given), measured "
        f"axes {', '.join(s['measured_axes'])}. Verdict: **{diagnosis.verdict}**. Held-out RMS "
        f"{s['heldout_rms_um']['before']:.3g} → {s['heldout_rms_um']['after']:.3g} µm "
        f"({s['heldout_method']}); in-sample {s['residual_rms_um']['before']:.3g} → "
        f"{s['residual_rms_um']['after']:.3g} µm; what remains: σ = {s['noise_sigma_um']:.3g} µm."
    )
    lines.append("")
    effects = list(diagnosis.effects) + [None] * len(diagnosis.entries)
    for i, e in enumerate(diagnosis.entries, start=1):
        eff = effects[i - 1] if i - 1 < len(diagnosis.effects) else None
        if e["cause"] == "unexplained":
            p = e.get("parameters", {})
            lines += [
                f"## {i}. Unexplained structure",
                "",
                f"Varies mostly with {p.get('varies_mostly_with', '?')}, on {p.get('axis', '?')}"
                f" near {p.get('where_mm')} mm; no cause of either instrument explains it "
                f"({100 * e.get('explained_fraction', 0):.1f} % of the residual sum of squares).",
                "",
            ]
            continue
        lines += [f"## {i}. {_head(e)}", ""]
        lines.append(f"**Shape.** {_shape_words(e, eff)}.")
        lines.append(
            f"**Source.** {_SOURCE_WORDS.get(e.get('source', 'machine'))}; locked to "
            f"{e.get('locked_to', '?')}. {_evidence_words(e)}."
        )
        lines.append(
            f"**Gain.** It explains {100 * e.get('explained_fraction', 0):.1f} % of the residual "
            "sum of squares given the other effects."
            + (
                " Not compensable (it is not the machine's, or not predictable at run time)."
                if e.get("compensable") is False
                else ""
            )
        )
        un = _unidentifiable(e)
        if un:
            lines.append(f"**Unidentifiable.** {un}")
        lines.append("")
    refused = s.get("refused_periods") or []
    if refused:
        lines += ["## Periods that are not periods", ""]
        for r in refused:
            lines.append(
                f"* {r['label']} at {r['period_mm']:.4g} mm: "
                + "; ".join(r["disagreements"])
                + " — its shape is left to the smooth tables."
            )
        lines.append("")
    return "\n".join(lines)


def _short(e: dict[str, Any], eff: Effect | None, machine: Any = None) -> str:
    cause, p = e["cause"], e.get("parameters", {})
    src = e.get("source", "machine")
    axis = e.get("axis") or (e.get("component") or "")[-1:]
    if cause in ("periodic", "reference_ripple"):
        ends = p.get("period_at_ends_mm")
        law = p.get("law", "constant")
        per = (
            f"{law} law {ends[0]:.3g}→{ends[1]:.3g} mm"
            if law != "constant" and ends
            else f"period {p.get('period_mm', float('nan')):.4g} mm"
        )
        what = f"{cause.replace('_', ' ')} {axis} {per}, {p.get('amplitude_um', 0):.3g} µm"
    elif cause == "reversal":
        what = f"reversal {axis} {p.get('reversal_mean_um', float('nan')):.3g} µm"
    elif cause == "drift":
        what = f"drift {axis} ({p.get('shape', 'uniform')})"
    elif cause == "latency":
        what = f"latency {axis} {p.get('latency_ms', float('nan')):.3g} ms"
    elif e.get("component"):
        c = e["component"]
        named = machine.error_label(c) if machine is not None else c
        what = f"{named if named != c else iso_name(c)} {cause}"  # as the machine file names it
    else:
        what = e.get("label", cause)
    return f"{what} [{src}]"


def verdict_line(diagnosis: Diagnosis) -> str:
    """One line: the verdict, each effect with its period or size and source, the periods
    refused, the held-out RMS before and after."""
    effects = list(diagnosis.effects)
    parts = [
        _short(e, effects[i] if i < len(effects) else None, diagnosis.residuals.machine)
        for i, e in enumerate(diagnosis.entries)
    ]
    refused = diagnosis.summary.get("refused_periods") or []
    if refused:
        parts.append("not periods: " + ", ".join(f"{r['period_mm']:.4g} mm" for r in refused))
    h = diagnosis.summary["heldout_rms_um"]
    return (
        f"verdict: {diagnosis.verdict}; "
        + "; ".join(parts)
        + f"; held-out RMS {h['before']:.3f} → {h['after']:.3f} µm"
    )
