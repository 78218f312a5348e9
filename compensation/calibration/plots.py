"""The calibration report's figures (PNG bytes, matplotlib's Agg canvas, no global backend):
each identified error with its band, the residuals of every data set before and after, and the
expanded uncertainty of the volumetric error over the volume. Units: µm, µrad, mm.
"""

from __future__ import annotations

import io
import math
from typing import TYPE_CHECKING

import numpy as np
from matplotlib.backends.backend_agg import FigureCanvasAgg
from matplotlib.figure import Figure

if TYPE_CHECKING:
    from .calibrate import CalibrationResult

__all__ = ["errors_png", "residuals_png", "volumetric_png"]


def _png(fig: Figure) -> bytes:
    FigureCanvasAgg(fig)
    buf = io.BytesIO()
    fig.savefig(buf, format="png", dpi=90)
    return buf.getvalue()


def errors_png(r: CalibrationResult) -> bytes:
    """Every identified function: value and its 95 % band (±2u) along its axis; squareness."""
    bands = r.bands
    n = len(bands) + (1 if r.squareness else 0)
    cols = 6
    rows = max(1, math.ceil(n / cols))
    fig = Figure(figsize=(3.0 * cols, 2.3 * rows), layout="constrained")
    axs = fig.subplots(rows, cols, squeeze=False).reshape(-1)
    for ax, b in zip(axs, bands, strict=False):
        unit = "µrad" if b.name.startswith("e") else "µm"
        q, v, u = b.curve  # as the machine file evaluates it, between the nodes too
        ax.fill_between(q, v - 2 * u, v + 2 * u, alpha=0.3, lw=0)
        ax.plot(q, v, "-", lw=1.2)
        ax.plot(b.position_mm, b.value, ".", ms=4)
        ax.set_title(b.name, fontsize=9)
        ax.set_ylabel(unit, fontsize=8)
        ax.tick_params(labelsize=7)
        ax.grid(alpha=0.3)
    if r.squareness:
        ax = axs[len(bands)]
        names = list(r.squareness)
        values = [r.squareness[k]["value_urad"] for k in names]
        bars = [2 * r.squareness[k]["u_urad"] for k in names]
        ax.bar(names, values, yerr=bars, capsize=4, alpha=0.7)
        ax.set_title("squareness (±2u)", fontsize=9)
        ax.set_ylabel("µrad", fontsize=8)
        ax.tick_params(labelsize=7)
        ax.grid(alpha=0.3)
    for ax in axs[n:]:
        ax.set_visible(False)
    fig.suptitle(f"{r.plan.name} ({r.plan.model}): identified errors, band = ±2u (k = 2)")
    return _png(fig)


def residuals_png(r: CalibrationResult) -> bytes:
    """Per data set and quantity: RMS of the residuals before (no errors, nuisance fitted) and
    after the fit, with the estimated σ; and the distribution of normalised residuals after."""
    labels, before, after, sigma = [], [], [], []
    for entry in r.datasets_summary:
        for name, q in entry["quantities"].items():
            labels.append(f"{entry['where']}\n{name}")
            before.append(q["rms_before"] or 0.0)
            after.append(q["rms_after"] or 0.0)
            sigma.append(q["sigma_estimated"] or q["sigma_prior"])
    fig = Figure(figsize=(13, 4.2), layout="constrained")
    ax1, ax2 = fig.subplots(1, 2, width_ratios=(2, 1))
    x = np.arange(len(labels))
    ax1.bar(x - 0.2, before, 0.4, label="before (no errors)")
    ax1.bar(x + 0.2, after, 0.4, label="after")
    ax1.plot(x + 0.2, sigma, "k_", ms=18, label="σ estimated")
    ax1.set_xticks(x, labels, fontsize=7)
    ax1.set_yscale("log")
    ax1.set_ylabel("RMS (µm or µrad)")
    ax1.legend(fontsize=8)
    ax1.grid(alpha=0.3, axis="y")
    norm = []
    for gi, g in enumerate(r.problem.groups):
        rows = r.problem.group_index[g.block] == gi
        norm.append(r.solution.residuals[g.block][rows] / g.sigma)
    z = np.concatenate(norm) if norm else np.zeros(0)
    if z.size:
        ax2.hist(z, bins=60, density=True, alpha=0.7)
        s = np.linspace(-4, 4, 200)
        ax2.plot(s, np.exp(-0.5 * s**2) / math.sqrt(2 * math.pi), "k-", lw=1)
    ax2.set_xlabel("residual / σ (after)")
    ax2.set_title("normalised residuals, N(0, 1) for reference", fontsize=9)
    return _png(fig)


def volumetric_png(r: CalibrationResult) -> bytes:
    """Identified volumetric error and its U (k = 2, rigid-body free) at the calibration stylus
    over x–y at the lowest, middle and highest z of the grid."""
    v = r.volumetric
    q, e, u = v.points_mm, v.error_um, v.U_um
    zs = np.unique(q[:, 2])
    layers = [zs[0], zs[len(zs) // 2], zs[-1]]
    fig = Figure(figsize=(13, 7.5), layout="constrained")
    axs = fig.subplots(2, 3, squeeze=False)
    emax = max(float(np.max(np.linalg.norm(e, axis=1))), 1e-12)
    umax = max(float(np.max(u)), 1e-12)
    for col, z in enumerate(layers):
        sel = np.isclose(q[:, 2], z)
        ax = axs[0, col]
        scale = 0.15 * max(np.ptp(q[:, 0]), np.ptp(q[:, 1]), 1.0) / emax
        ax.quiver(
            q[sel, 0],
            q[sel, 1],
            e[sel, 0] * scale,
            e[sel, 1] * scale,
            e[sel, 2],
            angles="xy",
            scale_units="xy",
            scale=1.0,
            cmap="coolwarm",
        )
        ax.set_title(f"error at z = {z:g} mm (arrows x–y, colour z)", fontsize=9)
        ax.set_aspect("equal")
        ax = axs[1, col]
        sc = ax.scatter(q[sel, 0], q[sel, 1], c=np.max(u[sel], axis=1), vmin=0, vmax=umax, s=90)
        ax.set_title(f"largest U component at z = {z:g} mm", fontsize=9)
        ax.set_aspect("equal")
        fig.colorbar(sc, ax=ax, label="U (k = 2), µm")
    fig.suptitle(
        f"volumetric error at stylus {v.stylus_mm.tolist()} mm; U of the rigid-body-free "
        f"part: max {umax:.3g} µm, largest error {emax:.3g} µm"
    )
    return _png(fig)
