"""``fleet diagnose --report DIR``: PNG plots of the trends and one HTML page.

``trend-<machine>.png``: per effect named on the machine, its parameters against the date
(sessions that named it as dots, the fitted line with its ±u band, a changed parameter first,
at most :data:`MAX_PARAMETERS` per effect), sessions that did not name it as ticks at the bottom,
and each change marked at its date. ``fleet-trends.png``: the same panels for every effect with a
change, all machines side by side. ``index.html``: the machines' summaries linking the plots.
"""

from __future__ import annotations

import html
from datetime import date
from pathlib import Path
from typing import Any

import numpy as np

__all__ = ["MAX_PARAMETERS", "write_fleet_report"]

MAX_PARAMETERS = 2
"""Parameters plotted per effect (the changed ones first)."""
MAX_PANELS = 12
"""Panels in the overview."""


def _days(dates: list[str]) -> np.ndarray:
    return np.array([date.fromisoformat(d).toordinal() for d in dates], dtype=float)


def _chosen(name: str, eff: dict[str, Any], changes: list[dict[str, Any]]) -> list[str]:
    changed = [c["parameter"] for c in changes if c["effect"] == name and "parameter" in c]
    rest = [p for p in eff["parameters"] if p not in changed]
    return (changed + rest)[:MAX_PARAMETERS]


def _panel(ax: Any, machine: str, name: str, pname: str, section: dict[str, Any]) -> None:
    from matplotlib import dates as mdates

    eff = section["trend"][name]
    par = eff["parameters"][pname]
    all_days = _days(section["dates"])
    t = _days(par["dates"])
    v = np.array(par["values"], dtype=float)
    ax.plot(t, v, "o", ms=4, label="session (named)")
    if "slope_per_day" in par and len(t) >= 3:
        tt = np.linspace(t.min(), t.max(), 50)
        tm = t.mean()
        line = par["mean"] + par["slope_per_day"] * (tt - tm)
        n = par["n"]
        band = np.hypot(par["residual_sd"] / np.sqrt(n), par["u_slope_per_day"] * (tt - tm))
        ax.plot(tt, line, "-", lw=1, color="C1", label="line ± u (k = 1)")
        ax.fill_between(tt, line - band, line + band, color="C1", alpha=0.25, lw=0)
    missing = all_days[~np.array(eff["named"], dtype=bool)]
    if len(missing):
        lo = np.nanmin(v) if len(v) else 0.0
        ax.plot(missing, np.full(len(missing), lo), "|", ms=10, color="grey", label="not named")
    for c in section["changes"]:
        if c["effect"] == name and "between" in c and c.get("parameter") in (None, pname):
            a, b = _days(c["between"])
            ax.axvspan(a, b, color="red", alpha=0.15, label=f"{c['kind']}")
    ax.set_title(f"{machine}: {name}", fontsize=8)
    ax.set_ylabel(pname, fontsize=8)
    ax.xaxis.set_major_formatter(mdates.DateFormatter("%m-%d"))
    ax.tick_params(labelsize=7)
    ax.grid(alpha=0.3)


def _figure(panels: list[tuple[str, str, str, dict[str, Any]]], path: Path, cols: int) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    rows = max(1, -(-len(panels) // cols))
    fig, axes = plt.subplots(rows, cols, figsize=(4.2 * cols, 2.8 * rows), squeeze=False)
    for ax, (machine, name, pname, section) in zip(axes.flat, panels, strict=False):
        _panel(ax, machine, name, pname, section)
    for ax in list(axes.flat)[len(panels) :]:
        ax.set_visible(False)
    if panels:
        handles, labels = axes.flat[0].get_legend_handles_labels()
        axes.flat[0].legend(handles, labels, fontsize=6, loc="best")
    fig.tight_layout()
    fig.savefig(path, dpi=90)
    plt.close(fig)


def write_fleet_report(machines: dict[str, Any], out_dir: Path) -> Path:
    """Write the plots and ``index.html`` into ``out_dir``; returns the HTML path."""
    out_dir.mkdir(parents=True, exist_ok=True)
    overview: list[tuple[str, str, str, dict[str, Any]]] = []
    rows = []
    for machine, section in machines.items():
        panels = [
            (machine, name, pname, section)
            for name, eff in section["trend"].items()
            for pname in _chosen(name, eff, section["changes"])
        ]
        image = ""
        if panels:
            fname = f"trend-{machine}.png"
            _figure(panels, out_dir / fname, cols=MAX_PARAMETERS)
            image = f'<a href="{fname}"><img src="{fname}" width="600"></a>'
        changed = {c["effect"] for c in section["changes"]}
        overview += [p for p in panels if p[1] in changed][: MAX_PARAMETERS * len(changed)]
        rows.append(
            f"<h2>{html.escape(machine)}</h2><p>{html.escape(section['summary'])}</p>{image}"
        )
    if overview:
        _figure(overview[:MAX_PANELS], out_dir / "fleet-trends.png", cols=min(3, len(overview)))
        rows.insert(0, '<h2>Changes</h2><img src="fleet-trends.png" width="900">')
    page = (
        '<!doctype html><html><head><meta charset="utf-8"><title>Fleet trends</title></head>'
        "<body style='font-family:sans-serif;max-width:960px;margin:auto'><h1>Fleet trends</h1>"
        + "".join(rows)
        + "</body></html>"
    )
    path = out_dir / "index.html"
    path.write_text(page, encoding="utf-8")
    return path
