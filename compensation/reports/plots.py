"""PNG plots of what people look at: parametric errors, the 3-D vector map, a 1-D line, diagonals.

Figures are drawn on matplotlib's Agg canvas directly (no global backend is set).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
from matplotlib.backends.backend_agg import FigureCanvasAgg
from matplotlib.figure import Figure

from ..formats.atomic import atomic_output
from ..machine import Machine
from ..parametric_errors import AXES
from .maps import LineReport, VolumetricMap, diagonal_endpoints


def save_png(fig: Figure, path: str | Path) -> Path:
    """Draw ``fig`` on an Agg canvas and write it to ``path`` as PNG (110 dpi) atomically (a
    temporary sibling renamed over it, mode as the umask gives), creating the folder; returns
    the path."""
    out = Path(path)
    FigureCanvasAgg(fig)
    with atomic_output(out, "wb") as fh:
        fig.savefig(fh, format="png", dpi=110)
    return out


def plot_parametric_errors(machine: Machine, path: str | Path, samples: int = 200) -> Path:
    """One panel per axis and kind (linear µm / angular µrad) that has a table, each table
    with its 2σ band, named as the machine file names it (ISO 230-1 names when it used them);
    no panel for an axis and kind without tables (a one-axis stage shows one panel). A machine
    without any table gets a figure saying so."""
    panels = [
        (axis, kind)
        for kind in ("d", "e")
        for axis in AXES
        if any(
            t.component.axis == axis and t.component.kind == kind for t in machine.tables.values()
        )
    ]
    title = f"{machine.name} ({machine.model}): parametric errors, shaded = random 2σ"
    if not panels:
        fig = Figure(figsize=(8, 2.2), layout="constrained")
        fig.text(
            0.5,
            0.5,
            "no parametric error tables: every one of the 21 errors is zero in this model",
            ha="center",
            va="center",
        )
        fig.suptitle(f"{machine.name} ({machine.model}): parametric errors")
        return save_png(fig, path)
    cols = min(3, len(panels))
    rows = (len(panels) + cols - 1) // cols
    fig = Figure(figsize=(4.4 * cols, 4 * rows), layout="constrained")
    axs = fig.subplots(rows, cols, squeeze=False)
    for i, (axis, kind) in enumerate(panels):
        ax = axs[i // cols][i % cols]
        k = AXES.index(axis)
        q = np.linspace(machine.volume.lower_mm[k], machine.volume.upper_mm[k], samples)
        for name, table in sorted(machine.tables.items()):
            c = table.component
            if c.axis != axis or c.kind != kind:
                continue
            v = table.evaluate(q)
            label = f"{machine.error_label(name)} (pv {np.ptp(v):.2f})"
            (line,) = ax.plot(q, v, label=label)
            if table.has_random:
                r = table.evaluate_random(q)
                ax.fill_between(q, v - r, v + r, color=line.get_color(), alpha=0.15)
        ax.set_title(f"{'linear' if kind == 'd' else 'angular'} errors of {axis.upper()}")
        ax.set_xlabel(f"{axis} position / mm")
        ax.set_ylabel("µm" if kind == "d" else "µrad")
        ax.grid(True, alpha=0.3)
        ax.legend(fontsize=7)
    for j in range(len(panels), rows * cols):
        axs[j // cols][j % cols].set_visible(False)
    fig.suptitle(title)
    return save_png(fig, path)


def plot_vector_map(
    vmap: VolumetricMap, path: str | Path, magnification: float | None = None, title: str = ""
) -> Path:
    """Nominal grid (grey) and the grid displaced by the magnified error (red), like the paper's
    Fig. 2c/3d. ``magnification`` defaults to making the largest error 6 % of the volume size."""
    pts, err = vmap.points_mm, vmap.error_um / 1000.0
    size = float(np.max(np.ptp(pts, axis=0)))
    peak = float(np.max(np.linalg.norm(err, axis=1)))  # mm
    auto = 0.06 * size / peak if peak > 0 else 1.0  # no error: nothing to magnify (was shown
    mag = magnification if magnification is not None else auto  # as a 1000 µm peak)
    nx, ny, nz = vmap.steps
    nominal = pts.reshape(nx, ny, nz, 3)
    moved = (pts + mag * err).reshape(nx, ny, nz, 3)
    fig = Figure(figsize=(9, 8), layout="constrained")
    ax = fig.add_subplot(projection="3d")

    def on_surface(i: int, n: int) -> bool:
        return i in (0, n - 1)

    styles = ((nominal, {"color": "0.75", "lw": 0.5}), (moved, {"color": "tab:red", "lw": 0.9}))
    ax.plot([], [], color="0.75", lw=1.5, label="nominal grid (indicated positions)")
    ax.plot(
        [],
        [],
        color="tab:red",
        lw=1.5,
        label=f"distorted: indicated + error × {mag:.3g} (true positions, magnified)",
    )
    for grid, style in styles:  # grid lines on the six faces of the volume
        for i in range(nx):
            for j in range(ny):
                if on_surface(i, nx) or on_surface(j, ny):
                    ax.plot(*grid[i, j, :, :].T, **style)
        for i in range(nx):
            for k in range(nz):
                if on_surface(i, nx) or on_surface(k, nz):
                    ax.plot(*grid[i, :, k, :].T, **style)
        for j in range(ny):
            for k in range(nz):
                if on_surface(j, ny) or on_surface(k, nz):
                    ax.plot(*grid[:, j, k, :].T, **style)
    ax.set_xlabel("x / mm")
    ax.set_ylabel("y / mm")
    ax.set_zlabel("z / mm")
    ax.set_title(
        f"{title} volumetric error map, magnification ×{mag:.3g} (peak {peak * 1000:.1f} µm)"
    )
    ax.legend(loc="upper left", fontsize=8)
    return save_png(fig, path)


def plot_line(report: LineReport, path: str | Path, title: str = "") -> Path:
    """ΔX, ΔY, ΔZ and the resultant along a line (paper's Fig. 2d / 3e)."""
    fig = Figure(figsize=(9, 5), layout="constrained")
    ax = fig.subplots()
    for i, name in enumerate(("ΔX", "ΔY", "ΔZ")):
        ax.plot(report.position_mm, report.error_um[:, i], label=name)
    ax.plot(report.position_mm, report.resultant_um, "k", lw=2, label="resultant")
    through = ", ".join(f"{v:g}" for v in report.through_mm)
    ax.set_title(
        f"{title} line ∥ {report.axis.upper()} through ({through}) mm: "
        f"bandwidth {report.bandwidth_um:.2f} µm, max {report.max_um:.2f} µm"
    )
    ax.set_xlabel(f"{report.axis} / mm")
    ax.set_ylabel("error / µm")
    ax.grid(True, alpha=0.3)
    ax.legend()
    return save_png(fig, path)


def plot_diagonals(machine: Machine, diagonals_um: list[float], path: str | Path) -> Path:
    """Bar chart of the four space-diagonal length errors."""
    fig = Figure(figsize=(7, 4), layout="constrained")
    ax = fig.subplots()
    labels = []
    for n, (a, b) in enumerate(diagonal_endpoints(machine), start=1):
        labels.append(f"d{n}\n({a[0]:g},{a[1]:g},{a[2]:g})→\n({b[0]:g},{b[1]:g},{b[2]:g})")
    ax.bar(labels, diagonals_um, color="tab:blue")
    for i, v in enumerate(diagonals_um):
        ax.annotate(f"{v:.2f}", (i, v), ha="center", va="bottom" if v >= 0 else "top")
    ax.axhline(0, color="k", lw=0.8)
    ax.set_ylabel("length error (true − indicated) / µm")
    ax.set_title(f"{machine.name}: space diagonals")
    ax.tick_params(axis="x", labelsize=7)
    return save_png(fig, path)
