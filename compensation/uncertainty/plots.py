"""PNG plots of the virtual CMM's results: U over the working volume, U at probed points, and
histograms of the Monte Carlo outputs with their coverage interval, the first-order (GUM)
Gaussian and an MPE. Drawn on matplotlib's Agg canvas (no global backend). Units: mm, µm.
"""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path

import numpy as np
from matplotlib.figure import Figure
from numpy.typing import NDArray

from ..reports.plots import save_png

__all__ = ["plot_histogram", "plot_points_u", "plot_volume_u"]

FloatArray = NDArray[np.float64]
_COMPONENTS = ("x", "y", "z")


def plot_volume_u(
    axes_mm: Sequence[FloatArray], U_um: FloatArray, path: str | Path, title: str = ""
) -> Path:
    """U (k = 2) of each component over x–y at the lowest, middle and highest z layer of a
    node grid: ``axes_mm`` three node arrays, ``U_um`` (nx, ny, nz, 3). One colour scale per
    component (row)."""
    ax_x, ax_y, ax_z = (np.asarray(a, dtype=float) for a in axes_mm)
    nz = len(ax_z)
    layers = sorted({0, nz // 2, nz - 1})
    fig = Figure(figsize=(4.2 * len(layers) + 1.0, 10), layout="constrained")
    axs = fig.subplots(3, len(layers), squeeze=False)
    for row, comp in enumerate(_COMPONENTS):
        vals = U_um[..., row]
        finite = vals[np.isfinite(vals)]
        vmin, vmax = (float(finite.min()), float(finite.max())) if finite.size else (0.0, 1.0)
        if vmax <= vmin:
            vmax = vmin + 1e-9
        mesh = None
        for col, k in enumerate(layers):
            ax = axs[row][col]
            mesh = ax.pcolormesh(
                ax_x, ax_y, vals[:, :, k].T, shading="gouraud", vmin=vmin, vmax=vmax, cmap="viridis"
            )
            ax.set_title(f"U{comp} at z = {ax_z[k]:g} mm")
            ax.set_xlabel("x / mm")
            ax.set_ylabel("y / mm")
            ax.set_aspect("equal")
        if mesh is not None:
            fig.colorbar(mesh, ax=list(axs[row]), label=f"U{comp} (k = 2) / µm")
    fig.suptitle(title or "expanded uncertainty of the corrected position over the volume")
    return save_png(fig, path)


def plot_points_u(
    points_mm: FloatArray, U_um: FloatArray, path: str | Path, title: str = ""
) -> Path:
    """U (k = 2) per component at arbitrary points: x–y scatter coloured by U, one panel per
    component (NaN points, not ok, drawn as grey crosses)."""
    fig = Figure(figsize=(14, 4.6), layout="constrained")
    axs = fig.subplots(1, 3, squeeze=False)[0]
    ok = np.all(np.isfinite(U_um), axis=1)
    for col, comp in enumerate(_COMPONENTS):
        ax = axs[col]
        if ok.any():
            sc = ax.scatter(
                points_mm[ok, 0], points_mm[ok, 1], c=U_um[ok, col], s=18, cmap="viridis"
            )
            fig.colorbar(sc, ax=ax, label=f"U{comp} (k = 2) / µm")
        if (~ok).any():
            ax.scatter(points_mm[~ok, 0], points_mm[~ok, 1], marker="x", color="0.6", s=18)
        ax.set_title(f"U{comp}")
        ax.set_xlabel("x / mm")
        ax.set_ylabel("y / mm")
        ax.set_aspect("equal", adjustable="datalim")
    fig.suptitle(title or "expanded uncertainty of the corrected positions")
    return save_png(fig, path)


def plot_histogram(
    panels: Sequence[tuple[str, FloatArray, tuple[float, float], float | None, float | None]],
    path: str | Path,
    *,
    title: str = "",
    limit_label: str = "MPE",
    probability: float = 0.95,
) -> Path:
    """Histograms of Monte Carlo outputs, one panel each: ``(label, values, (low, high)
    coverage interval (coverage ``probability``), GUM u or None, limit or None)``; the GUM Gaussian (mean 0) is drawn over
    it and a limit (e.g. an E0 MPE) as a vertical dashed line."""
    n = len(panels)
    cols = min(n, 3)
    rows = (n + cols - 1) // cols
    fig = Figure(figsize=(5.2 * cols, 3.8 * rows), layout="constrained")
    axs = fig.subplots(rows, cols, squeeze=False)
    for i, (label, values, (low, high), u_gum, limit) in enumerate(panels):
        ax = axs[i // cols][i % cols]
        v = np.asarray(values, dtype=float)
        ax.hist(v, bins=80, density=True, color="tab:blue", alpha=0.55, label=f"{len(v)} trials")
        ax.axvline(
            low,
            color="tab:red",
            lw=1.2,
            label=f"{100 * probability:g} % interval [{low:.3g}, {high:.3g}]",
        )
        ax.axvline(high, color="tab:red", lw=1.2)
        if u_gum is not None and u_gum > 0:
            x = np.linspace(v.min(), v.max(), 300)
            pdf = np.exp(-0.5 * (x / u_gum) ** 2) / (u_gum * np.sqrt(2 * np.pi))
            ax.plot(x, pdf, color="k", lw=1.0, label=f"first order (GUM), u = {u_gum:.3g}")
        if limit is not None:
            ax.axvline(
                limit, color="tab:green", lw=1.5, ls="--", label=f"{limit_label} {limit:.3g}"
            )
        ax.set_xlabel(label)
        ax.set_ylabel("probability density")
        ax.grid(True, alpha=0.3)
        ax.legend(fontsize=7)
    for j in range(n, rows * cols):
        axs[j // cols][j % cols].set_visible(False)
    fig.suptitle(title or "Monte Carlo outputs")
    return save_png(fig, path)
