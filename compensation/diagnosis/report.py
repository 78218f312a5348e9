"""The diagnosis report: the diagnosis in words (``report.md``, :mod:`.words`), residual plots
(PNG, Agg backend) and one HTML page with both.

Plots, for the measured axes only: residual against each moved position, time, temperature, the
temperature difference, travel directions and probing azimuth, before (model as described) and
after (extended model, out-of-fold predictions); residual statistics per axis; the effects found
and the candidates' test table of the first round.
"""

from __future__ import annotations

import html
import json
import re
from pathlib import Path
from typing import Any

import numpy as np

from .outcome import Diagnosis
from .residuals import axis_statistics, binned_statistics, explanatory_variables
from .words import report_markdown


def _plot_against(
    path: Path, name: str, x: np.ndarray, before: np.ndarray, after: np.ndarray, axes: list[int]
) -> None:
    """Residual against ``name`` for each measured axis in ``axes`` (one panel each: an axis
    that was not measured has no residual to show)."""
    from matplotlib.figure import Figure

    from ..reports.plots import save_png

    fig = Figure(figsize=(4 * len(axes), 3.4), layout="constrained")
    panels = fig.subplots(1, len(axes), squeeze=False, sharex=True)[0]
    stats = binned_statistics(x, before)
    for ax, k in zip(panels, axes, strict=True):
        ax.plot(x, before[:, k], ".", ms=3, alpha=0.5, label="before")
        ax.plot(x, after[:, k], ".", ms=3, alpha=0.5, label="after (held out)")
        ax.plot(stats["centre"], stats[f"mean_{'xyz'[k]}_um"], "k-", lw=1.5, label="binned mean")
        ax.set_title(f"residual {'xyz'[k]}")
        ax.set_xlabel(name)
        ax.set_ylabel("µm")
        ax.grid(alpha=0.3)
    panels[0].legend(fontsize=7)
    save_png(fig, path)


def display_label(label: str, machine: Any) -> str:
    """An entry's label with its error component named as the machine file names it
    (``parametric(component=dx_x)`` → ``parametric(component=EXX)`` for a file in ISO names)."""
    return re.sub(r"(component=)(\w+)", lambda m: m[1] + machine.error_label(m[2]), label)


def _shown_keys(entry: dict[str, Any], machine: Any) -> dict[str, Any]:
    """An entry's identifying keys for the report, its component named as the file names it."""
    hidden = ("cause", "parameters", "explained_fraction", "label", "evidence", "alternatives")
    keys = {k: v for k, v in entry.items() if k not in hidden}
    if isinstance(keys.get("component"), str):
        keys["component"] = machine.error_label(keys["component"])
    return keys


def _slug(name: str) -> str:
    return "".join(c if c.isalnum() else "_" for c in name.split(" (")[0]).strip("_")


def write_report(diagnosis: Diagnosis, out_dir: str | Path, title: str = "Diagnosis") -> Path:
    """Write ``report.md``, PNGs, ``diagnosis.json`` and ``index.html`` into ``out_dir``;
    returns the HTML path."""
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    res = diagnosis.residuals
    before = res.residual_um
    after = before - diagnosis.heldout_pred_um
    words = report_markdown(diagnosis, title)
    (out / "report.md").write_text(words + "\n", encoding="utf-8")
    images: list[tuple[str, str]] = []
    binned: dict[str, Any] = {}
    measured = ["xyz".index(a) for a in diagnosis.summary.get("measured_axes", "xyz")]
    for name, x in explanatory_variables(res).items():
        if np.ptp(x) == 0:
            continue
        fname = f"residual_vs_{_slug(name)}.png"
        _plot_against(out / fname, name, x, before, after, measured or [0, 1, 2])
        images.append((name, fname))
        binned[name] = binned_statistics(x, before)
    stats = {"before": axis_statistics(before), "after_heldout": axis_statistics(after)}
    payload = {**diagnosis.to_json(), "statistics": stats, "binned_before": binned}
    (out / "diagnosis.json").write_text(
        json.dumps(payload, indent=2, default=float, allow_nan=False)
    )
    machine = res.machine
    rows = "".join(
        f"<tr><td>{html.escape(str(e.get('cause')))}</td><td>"
        f"{html.escape(json.dumps(_shown_keys(e, machine)))}"
        f"</td><td>{html.escape(json.dumps(e.get('parameters', {}), default=float))}</td>"
        f"<td>{e.get('explained_fraction', 0):.3f}</td></tr>"
        for e in diagnosis.entries
    )
    stat_rows = "".join(
        f"<tr><td>{a}</td>"
        + "".join(
            f"<td>{stats[w][a].get(m, float('nan')):.3f}</td>"
            for w in ("before", "after_heldout")
            for m in ("mean_um", "std_um", "rms_um")
        )
        + "</tr>"
        for a in diagnosis.summary["measured_axes"]
    )
    cand_rows = ""
    if diagnosis.rounds:
        for r in diagnosis.rounds[0][:12]:
            cand_rows += (
                f"<tr><td>{html.escape(display_label(r['label'], machine))}</td><td>{r['p_adj']:.3g}</td>"
                f"<td>{r.get('cv_gain', float('nan')):.3f}</td></tr>"
            )
    s = diagnosis.summary
    figs = "".join(
        f'<h3>{html.escape(n)}</h3><a href="{f}"><img src="{f}" width="900"></a>' for n, f in images
    )
    page = f"""<!doctype html><html><head><meta charset="utf-8"><title>{html.escape(title)}</title>
<style>body{{font-family:sans-serif;max-width:960px;margin:auto}}td,th{{padding:2px 8px;border-bottom:1px solid #ddd}}</style>
</head><body><h1>{html.escape(title)}</h1>
<p>Verdict: <b>{diagnosis.verdict}</b>. Points: {s["n_points"]}, measured axes: {", ".join(s["measured_axes"])},
CV folds: {s["folds"]}.</p>
<table><tr><th></th><th>before</th><th>after</th></tr>
<tr><td>residual RMS 3-D (µm)</td><td>{s["residual_rms_um"]["before"]:.3f}</td><td>{s["residual_rms_um"]["after"]:.3f}</td></tr>
<tr><td>held-out RMS 3-D (µm)</td><td>{s["heldout_rms_um"]["before"]:.3f}</td><td>{s["heldout_rms_um"]["after"]:.3f}</td></tr>
<tr><td>E0 estimate (µm)</td><td>{s["e0_um"]["before"]:.3f}</td><td>{s["e0_um"]["after"]:.3f}</td></tr></table>
<h2>In words</h2><pre style="white-space:pre-wrap">{html.escape(words)}</pre>
<h2>Effects found</h2><table><tr><th>cause</th><th>keys</th><th>parameters</th><th>explained</th></tr>{rows}</table>
<h2>Residual statistics per axis (µm)</h2><table><tr><th>axis</th><th>mean</th><th>std</th><th>rms</th>
<th>mean (after)</th><th>std (after)</th><th>rms (after)</th></tr>{stat_rows}</table>
<h2>First round: best candidates</h2><table><tr><th>candidate</th><th>p (adjusted)</th><th>CV gain</th></tr>{cand_rows}</table>
<h2>Residuals against position, time, temperature, direction</h2>{figs}
<p><a href="diagnosis.json">diagnosis.json</a></p></body></html>"""
    path = out / "index.html"
    path.write_text(page, encoding="utf-8")
    return path
