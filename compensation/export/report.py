"""What an export leaves for people to look at: the JSON report, a PNG of the tables against the
model and the residual, and a static HTML page holding both (docs/export.md).

Figures are drawn on matplotlib's Agg canvas directly (no global backend is set).
"""

from __future__ import annotations

import base64
import html
import io
import json
from pathlib import Path
from typing import Any

import numpy as np
from matplotlib.backends.backend_agg import FigureCanvasAgg
from matplotlib.figure import Figure

from ..json_values import finite_json
from ..parametric_errors import AXES
from .decompose import model_error_um
from .export import ExportResult
from .limits import ExportError
from .residual import direction_combinations, evaluation_points

__all__ = ["export_figure_png", "export_html", "report_json"]


def _finite(obj: Any, where: str = "report") -> Any:
    """``obj`` with numpy scalars as Python numbers; :class:`ExportError` naming the first
    number that is not finite (was written as null: a figure silently missing)."""
    return finite_json(
        obj,
        where,
        lambda at, v: ExportError(
            f"export.json: {at} is {v} (not a finite number); nothing written"
        ),
    )


def report_json(result: ExportResult) -> str:
    """The report as standard JSON text (ExportError if a number is not finite)."""
    return json.dumps(_finite(result.report), indent=2, allow_nan=False) + "\n"


def export_figure_png(result: ExportResult, machine: Any, title: str = "") -> bytes:
    """PNG: per output axis, the model's error and what the written tables take off (µm, as the
    control interpolates them) along the lines through the volume's centre parallel to each
    axis, and the distribution of the error before and after over the evaluation grid."""
    d, plan = result.decomposition, result.plan
    fig = Figure(figsize=(13, 9.5), layout="constrained")
    axs = fig.subplots(3, 2, squeeze=False, width_ratios=(2.2, 1))
    q = evaluation_points(machine, result.report["evaluation"]["grid_steps"])
    tool = np.asarray(result.report["tool_mm"])
    combos = direction_combinations(d.direction_axes)
    errs, reps = [], []
    for combo in combos:
        dirs = np.ones_like(q)
        for a, s in combo.items():
            dirs[:, a] = s
        errs.append(model_error_um(machine, q, tool, combo))
        reps.append(result.represented_um(q, dirs))
    e, rep = np.concatenate(errs), np.concatenate(reps)
    res = e - rep
    centre = (d.lower_mm + d.upper_mm) / 2
    for k in range(3):
        ax = axs[k][0]
        for a in range(3):
            span = np.linspace(d.lower_mm[a], d.upper_mm[a], 300)
            frac = (span - d.lower_mm[a]) / (d.upper_mm[a] - d.lower_mm[a])
            line_q = np.repeat(centre[None, :], len(span), axis=0)
            line_q[:, a] = span
            signs = (1.0, -1.0) if a in d.direction_axes else (1.0,)
            for s in signs:
                dirs = np.ones_like(line_q)
                combo = {b: (s if b == a else 1.0) for b in d.direction_axes}
                for b, v in combo.items():
                    dirs[:, b] = v
                model = model_error_um(machine, line_q, tool, combo)[:, k]
                taken = result.represented_um(line_q, dirs)[:, k]
                tag = "" if len(signs) == 1 else (" +" if s > 0 else " −")
                (line,) = ax.plot(frac, model, lw=3, alpha=0.3, label=f"model along {AXES[a]}{tag}")
                ax.plot(
                    frac,
                    taken,
                    color=line.get_color(),
                    lw=1.1,
                    ls="-" if s > 0 else "--",
                    label=f"tables along {AXES[a]}{tag}",
                )
        n_prod = sum(1 for t in plan.products if t.k == k)
        ax.set_title(
            f"error of {AXES[k].upper()} on the three lines through the centre: model (wide) vs "
            f"tables (thin)" + (f"; {n_prod} product term(s)" if n_prod else "")
        )
        ax.set_xlabel("position along the line, fraction of the axis travel")
        ax.set_ylabel("µm")
        ax.grid(True, alpha=0.3)
        ax.legend(fontsize=7, ncol=3)
        hx = axs[k][1]
        lim = float(np.max(np.abs(e[:, k]))) or 1.0
        bins = np.linspace(-lim, lim, 61)
        hx.hist(
            e[:, k],
            bins=bins,
            alpha=0.5,
            label=f"model: RMS {np.sqrt(np.mean(e[:, k] ** 2)):.2f} µm",
        )
        hx.hist(
            res[:, k],
            bins=bins,
            alpha=0.7,
            label=f"left: RMS {np.sqrt(np.mean(res[:, k] ** 2)):.2f} µm",
        )
        hx.set_title(f"{AXES[k].upper()} over the volume ({len(e)} points)")
        hx.set_xlabel("µm")
        hx.legend(fontsize=7)
    fig.suptitle(title or f"{result.report['machine']}: {result.format} tables vs the model")
    FigureCanvasAgg(fig)
    buf = io.BytesIO()
    fig.savefig(buf, format="png", dpi=100)
    return buf.getvalue()


def export_html(result: ExportResult, png: bytes) -> str:
    """A static, self-contained page: summary, residual per axis, tables, what is left out."""
    r, u = result.report["residual_um"], result.report["uncompensated_um"]
    esc = html.escape
    rows = "".join(
        f"<tr><td>{a.upper()}</td><td>{u['per_axis'][a]['rms']:.3f}</td><td>{u['per_axis'][a]['max']:.3f}</td>"
        f"<td>{v['rms']:.3f}</td><td>{v['max']:.3f}</td></tr>"
        for a, v in r["per_axis"].items()
    )
    rows += (
        f"<tr class='total'><td>|vector|</td><td>{u['rms']:.3f}</td><td>{u['max']:.3f}</td>"
        f"<td>{r['rms']:.3f}</td><td>{r['max']:.3f}</td></tr>"
    )
    left = "".join(
        f"<tr><td>{esc(p['output'])}</td><td>{esc(p['part'])}</td><td>{p['rms_um']:.3f}</td></tr>"
        for p in result.report["left_out"][:12]
    )
    tables = "".join(
        "<tr>" + "".join(f"<td>{esc(str(v))}</td>" for v in t.values()) + "</tr>"
        for t in result.tables
    )
    heads = "".join(f"<th>{esc(str(k))}</th>" for k in (result.tables[0] if result.tables else {}))
    extra = ""
    if "residual_without_products_um" in result.report:
        w = result.report["residual_without_products_um"]
        extra = f"<p>Without table products: RMS {w['rms']:.3f} µm, max {w['max']:.3f} µm.</p>"
    img = base64.b64encode(png).decode("ascii")
    return f"""<!doctype html>
<html lang="en"><head><meta charset="utf-8">
<title>{esc(result.report["machine"])}: {esc(result.format)} export</title>
<style>
body {{ font-family: sans-serif; margin: 1.5em; color: #222; max-width: 1400px; }}
table {{ border-collapse: collapse; margin: 0.5em 0 1em; font-size: 13px; }}
td, th {{ border: 1px solid #bbb; padding: 2px 8px; text-align: right; }}
table.left td:nth-child(2) {{ text-align: left; }}
th {{ background: #eee; }} tr.total td {{ font-weight: bold; }}
.cols {{ display: flex; gap: 2em; flex-wrap: wrap; }}
img {{ max-width: 100%; border: 1px solid #ccc; }}
</style></head><body>
<h1>{esc(result.report["machine"])} ({esc(result.report["model"])}): {esc(result.format)} compensation tables</h1>
<p>Tool/stylus offset {esc(str(result.report["tool_mm"]))} mm, reference temperatures.
Files: {esc(", ".join(result.report["files"]))}. Residual measured on
{result.report["evaluation"]["points"]} points by evaluating the written tables as the control
interpolates them.</p>
<div class="cols"><div>
<h2>Error over the volume (µm)</h2>
<table><tr><th>axis</th><th>model RMS</th><th>model max</th><th>left RMS</th><th>left max</th></tr>{rows}</table>
{extra}
</div><div>
<h2>Left for the daemon (≈ RMS, µm)</h2>
<table class="left"><tr><th>output</th><th>part</th><th>RMS</th></tr>{left}</table>
</div></div>
<img alt="tables vs model" src="data:image/png;base64,{img}">
<h2>Tables</h2>
<table><tr>{heads}</tr>{tables}</table>
</body></html>
"""


def write_export(result: ExportResult, machine: Any, out_dir: Path) -> list[Path]:
    """Every file of ``result`` plus export.json, export.png and export.html, each atomically."""
    from ..formats.atomic import atomic_output, write_text_atomic

    # everything is made before the first file is written: a failure leaves no partial directory
    png = export_figure_png(result, machine)
    page = export_html(result, png)
    report = report_json(result)
    out_dir.mkdir(parents=True, exist_ok=True)
    written = []
    for name, text in result.files.items():
        write_text_atomic(out_dir / name, text)
        written.append(out_dir / name)
    with atomic_output(out_dir / "export.png", "wb") as fh:
        fh.write(png)
    write_text_atomic(out_dir / "export.html", page)
    write_text_atomic(out_dir / "export.json", report)
    written += [out_dir / "export.png", out_dir / "export.html", out_dir / "export.json"]
    return written
