"""Files written by ``cmm-comp import camonitor``: the stage's linear model and its dense measurements.

From an :class:`~.camonitor_stream.AlignedStream`:

* ``machine.toml`` (docs/formats.md §1): a one-axis machine, the *calibrated linear model* of the
  stage (no error tables: the linear map of the reference removed the axis' linear error); the
  map, the latency and the alignment error are written in its comments and ``[meta]``;
* ``measurements.csv`` (docs/formats.md §2): one row per kept reference sample, indicated = axis
  position at the sample's time, reference = mapped reference (mm), ``t`` (s), ``dir_<axis>``,
  ``group`` = ``cycle-<n>``, plus the extra columns ``v_<axis>`` (mm/s) and ``state``
  (rest/steady/accelerating), which the diagnosis ignores;
* ``summary.json``: counts, map, latency, timestamp jitter, alignment error, reversal at rest and
  while moving (µm, ms);
* ``import.png``: the error along the axis by direction and state, and against time by cycle.

Every file is written atomically; the machine text is validated before anything is written.
"""

from __future__ import annotations

import csv
import io
import json
import math
import tomllib
from pathlib import Path
from typing import Any

import numpy as np

from ..errors import RealDataError
from .atomic import atomic_output, write_text_atomic
from .camonitor_stream import AlignedStream, reversal_um

__all__ = ["import_summary", "machine_toml_text", "measurements_csv_text", "write_import"]

_OTHER = {"x": ("y", "z"), "y": ("x", "z"), "z": ("x", "y")}


def _volume(a: AlignedStream) -> tuple[float, float, float]:
    """Axis span (lower, upper, reference), mm: the travel rounded out to whole mm."""
    lo = math.floor(float(a.indicated_mm.min()) - 0.5)
    hi = math.ceil(float(a.indicated_mm.max()) + 0.5)
    ref = 0.0 if lo < 0.0 < hi else float(lo)
    return float(lo), float(hi), ref


def machine_toml_text(a: AlignedStream, name: str, source: str) -> str:
    """The one-axis calibrated linear model as ``machine.toml`` text, documented in comments."""
    o = a.options
    ax = o.axis
    lo, hi, ref = _volume(a)
    resid = math.sqrt(float(np.mean(a.error_um**2)))
    vol = {ax: (lo, hi)} | {k: (-1.0, 1.0) for k in _OTHER[ax]}
    reference = [ref if k == ax else 0.0 for k in "xyz"]
    lines = [
        f"# Calibrated linear model of axis {ax} ({o.position_pv}), written by",
        f"# `cmm-comp import camonitor` from {source}.",
        f"# The raw reference {o.reference_pv} is mapped onto the axis frame by the",
        "# least-squares line over the kept samples (rest and constant velocity, both directions):",
        f"#   ref_{ax} [mm] = gain * raw + offset,  gain = {a.gain:.9g} mm per raw unit,",
        f"#   offset = {a.offset_mm:.9g} mm  ({a.counts['kept']} samples, RMS of what is left",
        f"#   {resid:.2f} um).",
        f"# The line takes up the axis' linear (scale and offset) error, so this model has d{ax}_{ax} = 0:",
        "# measurements.csv holds what the linear model gets wrong.",
        f"# Time alignment: the reference's timestamps are late by {a.latency_s * 1e3:.1f} ms",
        f"# (+-{a.latency_sigma_s * 1e3:.1f} ms) on the position's; each reference sample is compared",
        "# with the position interpolated at its time minus that latency. Alignment error (1 sigma,",
        f"# speed x timing uncertainty + interpolation): RMS {_rms(a.align_error_um):.2f} um,",
        f"# largest {float(a.align_error_um.max()):.2f} um.",
        'format = "cmm-machine/1"',
        f"name = {json.dumps(name)}",
        'model = "MB1"',
        "",
        "[meta]",
        f"note = {json.dumps(f'calibrated linear model of {o.position_pv} against {o.reference_pv}')}",
        f"source = {json.dumps(source)}",
        f"reference_gain_mm_per_unit = {a.gain!r}",
        f"reference_offset_mm = {a.offset_mm!r}",
        f"latency_s = {a.latency_s!r}",
        "",
        "[volume]",
        *(f"{k} = [{vol[k][0]!r}, {vol[k][1]!r}]" for k in "xyz"),
        f"reference = [{', '.join(repr(v) for v in reference)}]",
        "",
        "[probe]",
        "offset = [0.0, 0.0, 0.0]",
        "",
        "[thermal]                      # no temperature was logged: no thermal terms",
        "reference_C = 20.0",
        "expansion = { x = 0.0, y = 0.0, z = 0.0 }",
        "",
    ]
    text = "\n".join(lines)
    from ..machine import Machine

    Machine.from_dict(tomllib.loads(text))  # the file must load as it is
    return text


def _rms(v: np.ndarray) -> float:
    """RMS, scaled so that values whose squares overflow (a position glitch of 1e200 mm) give
    their true, finite RMS rather than inf."""
    if not v.size:
        return math.nan
    peak = float(np.max(np.abs(v)))
    if not 0.0 < peak < math.inf:
        return peak  # 0, or the inf/NaN itself (a caller's bug: refused by write_import)
    return peak * math.sqrt(float(np.mean(np.square(v / peak))))


def measurements_csv_text(a: AlignedStream) -> str:
    """The rows as docs/formats.md §2 CSV text (full-precision floats)."""
    ax = a.options.axis
    buf = io.StringIO()
    w = csv.writer(buf, lineterminator="\n")
    w.writerow(
        ["x", "y", "z", "ref_x", "ref_y", "ref_z", "t", f"dir_{ax}", "group", f"v_{ax}", "state"]
    )
    col = "xyz".index(ax)
    for i in range(a.t_s.size):
        ind = ["0.0", "0.0", "0.0"]
        ref = ["0.0", "0.0", "0.0"]
        ind[col] = repr(float(a.indicated_mm[i]))
        ref[col] = repr(float(a.reference_mm[i]))
        w.writerow(
            [
                *ind,
                *ref,
                repr(float(a.t_s[i])),
                int(a.direction[i]),
                f"cycle-{int(a.cycle[i])}",
                f"{float(a.velocity_mm_s[i]):.6f}",
                str(a.state[i]),
            ]
        )
    return buf.getvalue()


def import_summary(a: AlignedStream, source: str) -> dict[str, Any]:
    """Counts, map, latency, jitter, alignment error and reversal by state (µm, ms, mm/s)."""
    o = a.options
    err = a.error_um
    rest, moving = a.state == "rest", a.state != "rest"
    err_nolag = (a.reference_mm - a.indicated_nolag_mm) * 1000.0
    speed = np.abs(a.velocity_mm_s[moving])
    v_med = float(np.median(speed)) if speed.size else 0.0
    return {
        "source": source,
        "axis": o.axis,
        "position_pv": o.position_pv,
        "reference_pv": o.reference_pv,
        "encoder_pv": o.encoder_pv,
        "rows": int(a.t_s.size),
        "counts": a.counts,
        "cycles": int(np.unique(a.cycle).size),
        "cycles_from": a.cycles_from,
        "reference_map": {
            "gain_mm_per_unit": a.gain,
            "offset_mm": a.offset_mm,
            "fitted_over": "kept samples (rest and constant velocity), least squares",
            "residual_rms_um": _rms(err),
        },
        "latency_ms": {
            "value": a.latency_s * 1e3,
            "sigma": a.latency_sigma_s * 1e3,
            "statistical_sigma": _ms(a.latency_split_s.get("statistical")),
            "all_moves": _ms(a.latency_split_s.get("all_moves")),
            "starts_only": _ms(a.latency_split_s.get("starts")),
            "method": a.latency_method,
            "convention": "> 0: the reference's timestamps are late; position taken at t - latency",
        },
        "timestamp_jitter_ms": {k: v * 1e3 for k, v in a.jitter_s.items()},
        "alignment_error_um": {
            "rms": _rms(a.align_error_um),
            "max": float(a.align_error_um.max()),
            "definition": "|v|*sqrt(jitter_ref^2 + jitter_pos^2 + sigma_latency^2) + |a|*h^2/8",
        },
        "speed_mm_s": {"median_moving": v_med, "max": float(speed.max()) if speed.size else 0.0},
        "reversal_um": {
            "at_rest": reversal_um(a.indicated_mm[rest], err[rest], a.direction[rest]),
            "moving": reversal_um(a.indicated_mm[moving], err[moving], a.direction[moving]),
            "moving_without_latency_correction": reversal_um(
                a.indicated_nolag_mm[moving], err_nolag[moving], a.direction[moving]
            ),
            "latency_part_um": 2.0 * v_med * a.latency_s * 1000.0,
            "definition": "mean over 1 mm bins of (error after + approach) - (error after -)",
        },
        "notes": a.notes,
    }


def _ms(value: float | None) -> float | None:
    return None if value is None else value * 1e3


def _plot(a: AlignedStream, path: Path) -> None:
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    ax_name = a.options.axis
    err = a.error_um
    fig = Figure(figsize=(9, 6.5), layout="constrained")
    top, bottom = fig.subplots(2, 1)
    for d, colour, word in ((1, "tab:red", "+"), (-1, "tab:blue", "−")):
        m = (a.state != "rest") & (a.direction == d)
        top.plot(a.indicated_mm[m], err[m], ",", color=colour, alpha=0.5)
        top.plot([], [], ".", color=colour, label=f"moving, direction {word}")
        m = (a.state == "rest") & (a.direction == d)
        top.plot(
            a.indicated_mm[m],
            err[m],
            "o",
            ms=3,
            mfc="none",
            color=colour,
            label=f"at rest after {word}",
        )
    top.set_xlabel(f"{ax_name} indicated (mm)")
    top.set_ylabel("error = reference − indicated (µm)")
    top.set_title(
        f"{a.counts['kept']} samples; latency {a.latency_s * 1e3:.1f} ± "
        f"{a.latency_sigma_s * 1e3:.1f} ms corrected; alignment error RMS "
        f"{_rms(a.align_error_um):.2f} µm"
    )
    top.legend(fontsize=7, markerscale=2)
    for c in np.unique(a.cycle):
        m = a.cycle == c
        bottom.plot(a.t_s[m], err[m], ",", label=f"cycle {c}")
    bottom.set_xlabel("t (s)")
    bottom.set_ylabel("error (µm)")
    bottom.legend(fontsize=7, markerscale=20, ncol=6)
    FigureCanvasAgg(fig)
    with atomic_output(path, "wb") as fh:
        fig.savefig(fh, format="png", dpi=80)


def write_import(
    a: AlignedStream, out_dir: str | Path, source: str, name: str | None = None, plot: bool = True
) -> dict[str, Path]:
    """Write ``machine.toml``, ``measurements.csv``, ``summary.json`` (and ``import.png``) to
    ``out_dir`` (created), each atomically; returns their paths by kind."""
    out = Path(out_dir)
    stem = Path(source).stem
    toml = machine_toml_text(a, name or f"{stem}-{a.options.axis}-linear", source)
    csv_text = measurements_csv_text(a)
    summary = import_summary(a, source)
    try:  # before anything is written: summary.json must be standard JSON (no NaN/Infinity)
        summary_text = json.dumps(summary, indent=2, default=_json_default, allow_nan=False)
    except ValueError:
        where, value = _non_finite(summary)
        raise RealDataError(
            f"summary {where} is {value} (not a finite number): the log holds a value out of "
            "range; nothing written"
        ) from None
    out.mkdir(parents=True, exist_ok=True)
    paths = {
        "machine": out / "machine.toml",
        "measurements": out / "measurements.csv",
        "summary": out / "summary.json",
    }
    write_text_atomic(paths["machine"], toml)
    write_text_atomic(paths["measurements"], csv_text)
    write_text_atomic(paths["summary"], summary_text + "\n")
    if plot:
        paths["plot"] = out / "import.png"
        _plot(a, paths["plot"])
    return paths


def _non_finite(obj: Any, where: str = "") -> tuple[str, float]:
    """The first non-finite float in a JSON-ready tree: (dotted path, value); ("", nan) if none."""
    if isinstance(obj, float | np.floating) and not math.isfinite(obj):
        return where, float(obj)
    items = (
        obj.items() if isinstance(obj, dict) else enumerate(obj) if isinstance(obj, list) else ()
    )
    for k, v in items:
        found = _non_finite(v, f"{where}.{k}" if where else str(k))
        if found[0]:
            return found
    return "", math.nan


def _json_default(value: Any) -> Any:
    if isinstance(value, np.generic):
        return value.item()
    raise TypeError(f"not JSON serialisable: {type(value).__name__}")
