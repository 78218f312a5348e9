"""The calibration report (docs/formats.md §10.6): ``calibration.json``, ``volumetric_u.csv``,
``errors.png``, ``residuals.png``, ``volumetric_u.png`` and one ``index.html``.

Everything is rendered in memory first; the files are written (each atomically) only when all
of them exist, so a failure leaves nothing half-written. Units: µm, µrad, mm.
"""

from __future__ import annotations

import html
import json
import math
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from ..errors import CalibrationError
from ..json_values import finite_json
from .plots import errors_png, residuals_png, volumetric_png

if TYPE_CHECKING:
    from .calibrate import CalibrationResult

__all__ = ["REPORT_FORMAT", "report_json", "volumetric_csv", "write_outputs"]

REPORT_FORMAT = "cmm-calibration-report/1"


def _finite(obj: Any, where: str) -> Any:
    """``obj`` as JSON values; :class:`CalibrationError` naming the first non-finite number."""
    return finite_json(
        obj,
        where,
        lambda at, v: CalibrationError(f"calibration.json: {at} is {v}; nothing written"),
    )


def _gauge_list(gauge: dict[str, Any]) -> list[dict[str, Any]]:
    out = [{"scope": "rigid_body", **g} for g in gauge["rigid_body"]]
    out += [{"scope": "all_data", **f} for f in gauge["all_data"]["freedoms"]]
    for kind, entry in gauge["per_data_kind"].items():
        out += [{"scope": f"{kind}_alone", **f} for f in entry["freedoms"]]
    return out


def report_json(r: CalibrationResult, machine_path: str | None) -> dict[str, Any]:
    """The content of ``calibration.json``."""
    errors, reversal = {}, {}
    for b in r.bands:
        entry = {
            "position_mm": b.position_mm,
            "value": b.value,
            "u": b.u,
            "U": 2.0 * b.u,
            "unit": "urad" if b.name.startswith("e") else "um",
        }
        if b.name.startswith("reversal:"):
            reversal[b.name.removeprefix("reversal:")] = entry
        else:
            errors[b.name] = entry
    sol = r.solution
    gauge = r.gauge
    payload = {
        "format": REPORT_FORMAT,
        "model": r.plan.model,
        "name": r.plan.name,
        "plan": str(r.plan.source),
        "machine_file": machine_path,
        "errors": errors,
        "reversal_half_um": reversal,
        "squareness": r.squareness,
        "volumetric_U_um": {**r.volumetric.summary(), "csv": "volumetric_u.csv"},
        "datasets": r.datasets_summary,
        "reach": r.reach,
        "gauge": _gauge_list(gauge),
        "gauge_summary": {
            "null_dimension_all_data": gauge["all_data"]["null_dimension"],
            "null_dimension_per_kind": {
                k: v["null_dimension"] for k, v in gauge["per_data_kind"].items()
            },
        },
        "condition": gauge["condition"],
        "smoothness_tau": {c: 1.0 / math.sqrt(v) for c, v in sol.lam.items()},
        "fit": {
            "basis": r.plan.fit.basis,
            "nodes": list(r.plan.fit.nodes),
            "parameters": r.problem.p,
            "nuisance_parameters": r.problem.n - r.problem.p,
            "readings": sum(b.n_rows for b in r.problem.blocks),
            "iterations": sol.iterations,
            "converged": sol.converged,
            "elapsed_s": r.elapsed_s,
            "prior_sd": r.plan.fit.prior,
        },
        "checks": r.checks,
        "warnings": r.warnings,
        "units": {
            "positions": "mm",
            "linear errors": "um",
            "angles": "urad",
            "u": "standard uncertainty (k = 1)",
            "U": "expanded uncertainty (k = 2)",
        },
    }
    return _finite(payload, "calibration")


def volumetric_csv(r: CalibrationResult) -> str:
    """``x,y,z,ex_um,ey_um,ez_um,Ux_um,Uy_um,Uz_um`` on the plan's grid (C order, z fastest)."""
    v = r.volumetric
    lines = ["x,y,z,ex_um,ey_um,ez_um,Ux_um,Uy_um,Uz_um"]
    for q, e, u in zip(v.points_mm, v.error_um, v.U_um, strict=True):
        lines.append(",".join(f"{x:.6f}" for x in (*q, *e, *u)))
    return "\n".join(lines) + "\n"


def _table(head: list[str], rows: list[list[Any]]) -> str:
    esc = html.escape
    h = "".join(f"<th>{esc(str(c))}</th>" for c in head)
    body = "".join(
        "<tr>" + "".join(f"<td>{esc(_fmt(c))}</td>" for c in row) + "</tr>" for row in rows
    )
    return f"<table><tr>{h}</tr>{body}</table>"


def _fmt(c: Any) -> str:
    if isinstance(c, float):
        return f"{c:.4g}"
    if c is None:
        return "—"
    return str(c)


def reach_rows(datasets: list[dict[str, Any]]) -> list[list[Any]]:
    """Rows (data set, file, axis, from mm, to mm, % of travel) of the data sets' reach."""
    rows: list[list[Any]] = []
    for d in datasets:
        for axis, span in d["reach"].items():
            if span is None:
                rows.append([d["where"], Path(d["file"]).name, axis, None, None, "no run along"])
            else:
                rows.append(
                    [
                        d["where"],
                        Path(d["file"]).name,
                        axis,
                        round(span["from_mm"], 1),
                        round(span["to_mm"], 1),
                        round(span["percent_of_travel"], 1),
                    ]
                )
    return rows


def _reach_html(payload: dict[str, Any]) -> str:
    """The report's reach section: per data set and axis, then the union and what no set
    reaches."""
    reach = payload["reach"]
    union = [
        [
            axis,
            f"{a['travel_mm'][0]:.1f} … {a['travel_mm'][1]:.1f}",
            "; ".join(f"{lo:.1f} … {hi:.1f}" for lo, hi in a["covered_mm"]) or None,
            round(a["percent_of_travel"], 1),
        ]
        for axis, a in reach["per_axis"].items()
    ]
    missing = "".join(
        f"<li>{html.escape(u['axis'])} = {u['from_mm']:.1f} … {u['to_mm']:.1f} mm "
        f"({u['percent_of_travel']:.1f} % of its travel): extrapolated by the smoothness "
        "prior</li>"
        for u in reach["unreached"]
    )
    limit = reach["warn_above_percent_of_travel"]
    return (
        _table(
            ["data set", "file", "axis", "from mm", "to mm", "% of travel"],
            reach_rows(payload["datasets"]),
        )
        + _table(["axis", "travel mm", "reached by some data set, mm", "% of travel"], union)
        + f"<p>Stretches longer than {limit:g} % of an axis' travel that no data set reaches: "
        + (f"</p><ul>{missing}</ul>" if missing else "none.</p>")
    )


def report_html(r: CalibrationResult, payload: dict[str, Any], figures: bool = True) -> str:
    """The one HTML page of the report (self-contained: the PNGs inline). ``figures=False``
    (``--no-figures``): no ``<img>``, a line saying the figures were not drawn instead.

    Long on purpose: it is the page's template, section after section in reading order; no
    logic to split out."""
    esc = html.escape

    def img(alt: str, name: str) -> str:
        if figures:
            return f'<img alt="{alt}" src="{name}">'
        return f"<p>({alt}: {name} not drawn, --no-figures)</p>"

    ds_rows = []
    for d in payload["datasets"]:
        for name, q in d["quantities"].items():
            ds_rows.append(
                [
                    d["where"],
                    Path(d["file"]).name,
                    name,
                    q["n"],
                    q["rms_before"],
                    q["rms_after"],
                    q["unit"],
                    q["sigma_prior"],
                    q["sigma_estimated"],
                ]
            )
    gauge_rows = [
        [
            g["scope"],
            ", ".join(g.get("errors", [g.get("freedom", "")])),
            g.get("what", g.get("fixed_by", "")),
            g.get("consequence", ", ".join(g.get("seen_by", [])) or "no data kind"),
            g.get("dimension", 1),
        ]
        for g in payload["gauge"]
    ]
    err_rows = [
        [
            name,
            e["unit"],
            float(np.max(np.abs(e["value"]))) if e["value"] else 0.0,
            float(np.max(e["U"])) if e["U"] else 0.0,
        ]
        for name, e in payload["errors"].items()
    ]
    sq_rows = [[k, v["value_urad"], 2 * v["u_urad"]] for k, v in payload["squareness"].items()]
    vol = payload["volumetric_U_um"]
    cond = payload["condition"]
    checks = payload["checks"]
    warn = "".join(f"<li>{esc(w)}</li>" for w in payload["warnings"]) or "<li>none</li>"
    return f"""<!doctype html>
<html lang="en"><head><meta charset="utf-8">
<title>{esc(r.plan.name)}: calibration</title>
<style>
body {{ font-family: sans-serif; margin: 1.5em; color: #222; max-width: 1500px; }}
table {{ border-collapse: collapse; margin: 0.5em 0 1em; font-size: 13px; }}
td, th {{ border: 1px solid #bbb; padding: 2px 8px; text-align: left; }}
th {{ background: #eee; }} img {{ max-width: 100%; border: 1px solid #ccc; }}
</style></head><body>
<h1>{esc(r.plan.name)} ({esc(r.plan.model)}): calibration from {esc(r.plan.source.name)}</h1>
<p>{payload["fit"]["readings"]} readings, {payload["fit"]["parameters"]} error parameters
({esc(payload["fit"]["basis"])}), {payload["fit"]["nuisance_parameters"]} nuisance parameters
(plate poses, ball corrections, stations, dead paths); {payload["fit"]["iterations"]} iterations,
converged: {payload["fit"]["converged"]}; {payload["fit"]["elapsed_s"]:.1f} s.
Machine file: {esc(str(payload["machine_file"]))}.</p>
<h2>Warnings</h2><ul>{warn}</ul>
<h2>Volumetric error at the calibration stylus {esc(str(vol["stylus_mm"]))} mm</h2>
<p>U (k = 2) of the rigid-body-free part over {vol["nodes"]} nodes: max
{", ".join(f"{v:.3g}" for v in vol["max_um"])} µm, RMS {", ".join(f"{v:.3g}" for v in vol["rms_um"])} µm
(x, y, z); per node in <a href="volumetric_u.csv">volumetric_u.csv</a>.</p>
{img("volumetric error and U", "volumetric_u.png")}
<h2>Identified errors (band ±2u)</h2>
{img("identified errors", "errors.png")}
{_table(["error", "unit", "max |value|", "max U (k=2)"], err_rows)}
{_table(["squareness", "value µrad", "U µrad (k=2)"], sq_rows)}
<h2>Data sets: residuals before (no errors) and after</h2>
{_table(["data set", "file", "quantity", "n", "RMS before", "RMS after", "unit", "σ a priori", "σ estimated"], ds_rows)}
{img("residuals", "residuals.png")}
<h2>Where the data reach (measurement positions along each axis)</h2>
{_reach_html(payload)}
<h2>What the data could not identify</h2>
{_table(["scope", "errors / freedom", "what", "consequence / seen by", "dimension"], gauge_rows)}
<p>Condition of the data's information (whitened by the prior, directions seen):
{_fmt(cond["data_information"])} over {cond["identified_directions"]} of {cond["parameters"]} directions.</p>
<h2>Checks</h2>
<p>The written machine reproduces every reading of the fit to
{checks["resimulation"]["max_abs"]:.3g} µm/µrad (re-simulated through the public machine API).
Exact chain vs the paper's first-order form: {checks["exact_vs_first_order"]["grid_max_abs_um"]:.3g} µm
on the grid (largest error {checks["exact_vs_first_order"]["grid_max_error_um"]:.3g} µm).</p>
</body></html>
"""


def write_outputs(
    r: CalibrationResult, machine_path: Path | None, report_dir: Path | None, figures: bool = True
) -> list[Path]:
    """Write the machine and/or the report; everything is rendered before the first write.
    ``figures=False`` (``--no-figures``): the report without its three PNGs (matplotlib's
    drawing is about a third of a small calibration's CPU time)."""
    from ..formats.atomic import atomic_output, write_text_atomic
    from ..formats.machine_toml import write_machine_toml

    files: dict[str, bytes | str] = {}
    if report_dir is not None:
        payload = report_json(r, str(machine_path) if machine_path else None)
        files["calibration.json"] = json.dumps(payload, indent=2, allow_nan=False) + "\n"
        files["volumetric_u.csv"] = volumetric_csv(r)
        if figures:
            files["errors.png"] = errors_png(r)
            files["residuals.png"] = residuals_png(r)
            files["volumetric_u.png"] = volumetric_png(r)
        files["index.html"] = report_html(r, payload, figures)
    written: list[Path] = []
    if machine_path is not None:
        write_machine_toml(r.description, machine_path)
        written.append(machine_path)
    if report_dir is not None:
        report_dir.mkdir(parents=True, exist_ok=True)
        for name, content in files.items():
            path = report_dir / name
            if isinstance(content, bytes):
                with atomic_output(path, "wb") as fh:
                    fh.write(content)
            else:
                write_text_atomic(path, content)
            written.append(path)
    return written
