"""ISO 230-2:2014 evaluation of a bidirectional positioning test of one numerically controlled axis.

Inputs are target positions ``P_i`` (mm, i = 1..m) and the measured (reference-system) positions
``P_ij`` reached at them in cycles j = 1..n, approaching in the positive (forward, ↑) and negative
(backward, ↓) direction. The positional deviation is ``x_ij = P_ij − P_i`` (measured − target).
All results are in µm. Formulas and the sign conventions are written out in ``docs/iso230.md``.

The project's error convention is ``error = true − indicated`` (docs/formats.md); in an ISO 230-2 test
the axis indicates the target and the reference measures the true position, so ``x_ij`` *is* the
error in that convention and the correction to add to an indicated position is ``+x̄``.
"""

from __future__ import annotations

from dataclasses import dataclass, fields
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

__all__ = [
    "Iso230Result",
    "evaluate_iso230",
    "format_iso230_report",
    "plot_iso230",
]

_UM_PER_MM = 1000.0
_MAX_DEVIATION_MM = 1e6  # 1 km: beyond it no deviation, a wrong value or unit


@dataclass(frozen=True, eq=False)
class Iso230Result:
    """ISO 230-2:2014 results of one bidirectional test. Arrays are per target position i.

    Symbols: ↑ = ``fwd`` (positive approach), ↓ = ``bwd`` (negative approach).
    """

    target_mm: NDArray[np.float64]  #: P_i, mm, shape (m,)
    deviation_fwd_um: NDArray[np.float64]  #: x_ij↑ = P_ij↑ − P_i, µm, shape (m, n)
    deviation_bwd_um: NDArray[np.float64]  #: x_ij↓, µm, shape (m, n)
    mean_fwd_um: NDArray[np.float64]  #: x̄_i↑, mean unidirectional positional deviation
    mean_bwd_um: NDArray[np.float64]  #: x̄_i↓
    mean_bidir_um: NDArray[np.float64]  #: x̄_i = (x̄_i↑ + x̄_i↓)/2
    reversal_um: NDArray[np.float64]  #: B_i = x̄_i↑ − x̄_i↓
    s_fwd_um: NDArray[np.float64]  #: s_i↑, unidirectional estimator of standard uncertainty
    s_bwd_um: NDArray[np.float64]  #: s_i↓
    repeat_fwd_um: NDArray[np.float64]  #: R_i↑ = 4 s_i↑
    repeat_bwd_um: NDArray[np.float64]  #: R_i↓ = 4 s_i↓
    repeat_bidir_um: NDArray[np.float64]  #: R_i = max(2s_i↑ + 2s_i↓ + |B_i|, R_i↑, R_i↓)
    B_um: float  #: reversal value of the axis, max |B_i|
    B_mean_um: float  #: mean reversal value of the axis, (1/m) Σ B_i (signed)
    R_fwd_um: float  #: R↑ = max R_i↑
    R_bwd_um: float  #: R↓ = max R_i↓
    R_um: float  #: R = max R_i
    E_fwd_um: float  #: E↑ = max x̄_i↑ − min x̄_i↑
    E_bwd_um: float  #: E↓ = max x̄_i↓ − min x̄_i↓
    E_um: float  #: E = max(x̄_i↑, x̄_i↓) − min(x̄_i↑, x̄_i↓)
    M_um: float  #: M = max x̄_i − min x̄_i
    A_fwd_um: float  #: A↑ = max(x̄_i↑ + 2s_i↑) − min(x̄_i↑ − 2s_i↑)
    A_bwd_um: float  #: A↓ = max(x̄_i↓ + 2s_i↓) − min(x̄_i↓ − 2s_i↓)
    A_um: float  #: A = max(x̄_i↑ + 2s_i↑, x̄_i↓ + 2s_i↓) − min(x̄_i↑ − 2s_i↑, x̄_i↓ − 2s_i↓)

    @property
    def positions(self) -> int:
        """Number of target positions m."""
        return int(self.target_mm.size)

    @property
    def cycles(self) -> int:
        """Number of cycles n (per direction)."""
        return int(self.deviation_fwd_um.shape[1])

    def to_dict(self) -> dict[str, Any]:
        """Plain JSON-ready dict: arrays as (nested) lists of float, scalars as float."""
        out: dict[str, Any] = {}
        for f in fields(self):
            v = getattr(self, f.name)
            out[f.name] = v.tolist() if isinstance(v, np.ndarray) else float(v)
        return out


def _check_inputs(
    target_mm: ArrayLike, fwd_mm: ArrayLike, bwd_mm: ArrayLike
) -> tuple[NDArray[np.float64], NDArray[np.float64], NDArray[np.float64]]:
    p = np.asarray(target_mm, dtype=float)
    up = np.asarray(fwd_mm, dtype=float)
    down = np.asarray(bwd_mm, dtype=float)
    if p.ndim != 1 or p.size < 2:
        raise ValueError(f"target positions must be 1-D with at least 2 values, got {p.shape}")
    for name, a in (("forward", up), ("backward", down)):
        if a.ndim != 2 or a.shape[0] != p.size or a.shape[1] < 2:
            raise ValueError(
                f"{name} measurements must have shape (positions={p.size}, cycles>=2), "
                f"got {a.shape}"
            )
    if up.shape != down.shape:
        raise ValueError(
            f"forward and backward runs must have the same cycles, got {up.shape} and {down.shape}"
        )
    if not all(np.all(np.isfinite(a)) for a in (p, up, down)):
        raise ValueError("target and measured positions must be finite (no NaN or inf)")
    for name, a in (("forward", up), ("backward", down)):
        with np.errstate(over="ignore"):
            dev = np.abs(a - p[:, None])
        if not np.all(dev <= _MAX_DEVIATION_MM):  # its square overflowed: s, R, A were inf
            i, j = np.unravel_index(
                int(np.argmax(np.where(np.isfinite(dev), dev, np.inf))), a.shape
            )
            raise ValueError(
                f"{name} measurement {a[i, j]:g} mm at target {p[i]:g} mm (position {i + 1}, "
                f"cycle {j + 1}) deviates by more than {_MAX_DEVIATION_MM:g} mm: not a "
                "positioning deviation (check the value and the file's UNIT)"
            )
    return p, up, down


def evaluate_iso230(
    target_mm: ArrayLike, measured_fwd_mm: ArrayLike, measured_bwd_mm: ArrayLike
) -> Iso230Result:
    """Evaluate a bidirectional ISO 230-2:2014 positioning test.

    Args:
        target_mm: target positions P_i, mm, shape (m,), m >= 2.
        measured_fwd_mm: measured positions P_ij↑ reached approaching in the positive direction,
            mm, shape (m, n), n >= 2 cycles (the standard asks for n = 5).
        measured_bwd_mm: measured positions P_ij↓ approaching in the negative direction, mm,
            shape (m, n).

    Returns:
        The :class:`Iso230Result`, all deviations and parameters in µm.
    """
    p, up, down = _check_inputs(target_mm, measured_fwd_mm, measured_bwd_mm)
    x_up = (up - p[:, None]) * _UM_PER_MM
    x_down = (down - p[:, None]) * _UM_PER_MM
    mean_up, mean_down = x_up.mean(axis=1), x_down.mean(axis=1)
    s_up, s_down = x_up.std(axis=1, ddof=1), x_down.std(axis=1, ddof=1)
    b_i = mean_up - mean_down
    r_up, r_down = 4.0 * s_up, 4.0 * s_down
    r_i = np.maximum.reduce([2.0 * s_up + 2.0 * s_down + np.abs(b_i), r_up, r_down])
    mean_bi = 0.5 * (mean_up + mean_down)
    both_means = np.concatenate([mean_up, mean_down])
    hi_up, lo_up = mean_up + 2.0 * s_up, mean_up - 2.0 * s_up
    hi_down, lo_down = mean_down + 2.0 * s_down, mean_down - 2.0 * s_down
    return Iso230Result(
        target_mm=p,
        deviation_fwd_um=x_up,
        deviation_bwd_um=x_down,
        mean_fwd_um=mean_up,
        mean_bwd_um=mean_down,
        mean_bidir_um=mean_bi,
        reversal_um=b_i,
        s_fwd_um=s_up,
        s_bwd_um=s_down,
        repeat_fwd_um=r_up,
        repeat_bwd_um=r_down,
        repeat_bidir_um=r_i,
        B_um=float(np.max(np.abs(b_i))),
        B_mean_um=float(np.mean(b_i)),
        R_fwd_um=float(r_up.max()),
        R_bwd_um=float(r_down.max()),
        R_um=float(r_i.max()),
        E_fwd_um=float(np.ptp(mean_up)),
        E_bwd_um=float(np.ptp(mean_down)),
        E_um=float(np.ptp(both_means)),
        M_um=float(np.ptp(mean_bi)),
        A_fwd_um=float(hi_up.max() - lo_up.min()),
        A_bwd_um=float(hi_down.max() - lo_down.min()),
        A_um=float(max(hi_up.max(), hi_down.max()) - min(lo_up.min(), lo_down.min())),
    )


_SUMMARY = (
    ("A", "A_um", "bidirectional accuracy"),
    ("A↑", "A_fwd_um", "unidirectional accuracy, positive approach"),
    ("A↓", "A_bwd_um", "unidirectional accuracy, negative approach"),
    ("E", "E_um", "bidirectional systematic positional deviation"),
    ("E↑", "E_fwd_um", "unidirectional systematic positional deviation ↑"),
    ("E↓", "E_bwd_um", "unidirectional systematic positional deviation ↓"),
    ("M", "M_um", "mean bidirectional positional deviation range"),
    ("R", "R_um", "bidirectional positioning repeatability"),
    ("R↑", "R_fwd_um", "unidirectional positioning repeatability ↑"),
    ("R↓", "R_bwd_um", "unidirectional positioning repeatability ↓"),
    ("B", "B_um", "reversal value of the axis (max |B_i|)"),
    ("B̄", "B_mean_um", "mean reversal value of the axis"),
)


def format_iso230_report(result: Iso230Result, title: str = "ISO 230-2 positioning test") -> str:
    """Markdown report: summary parameters, then a per-position table (all values in µm)."""
    lines = [
        f"# {title}",
        "",
        f"ISO 230-2:2014, {result.positions} target positions × {result.cycles} cycles, "
        "bidirectional. Deviation x = measured − target (= true − indicated). Units: µm.",
        "",
        "| parameter | value (µm) | meaning |",
        "|---|---:|---|",
    ]
    lines += [f"| {sym} | {getattr(result, key):.3f} | {text} |" for sym, key, text in _SUMMARY]
    lines += [
        "",
        "| i | P_i (mm) | x̄↑ | x̄↓ | x̄ | B_i | s↑ | s↓ | R↑_i | R↓_i | R_i |",
        "|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|",
    ]
    for i in range(result.positions):
        row = [
            result.mean_fwd_um[i],
            result.mean_bwd_um[i],
            result.mean_bidir_um[i],
            result.reversal_um[i],
            result.s_fwd_um[i],
            result.s_bwd_um[i],
            result.repeat_fwd_um[i],
            result.repeat_bwd_um[i],
            result.repeat_bidir_um[i],
        ]
        cells = " | ".join(f"{v:.3f}" for v in row)
        lines.append(f"| {i + 1} | {result.target_mm[i]:.4f} | {cells} |")
    return "\n".join(lines) + "\n"


def plot_iso230(
    result: Iso230Result, path: str | Path, title: str = "ISO 230-2 positioning test"
) -> Path:
    """Write a PNG: every x_ij, the mean ↑/↓ deviations with their ±2s bands, and x̄_i.

    Uses matplotlib's Agg canvas directly, so no global backend is selected or needed.
    """
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    path = Path(path)
    fig = Figure(figsize=(8.0, 5.0), dpi=100)
    FigureCanvasAgg(fig)
    ax = fig.add_subplot(1, 1, 1)
    p = result.target_mm
    for mean, s, dev, colour, label in (
        (result.mean_fwd_um, result.s_fwd_um, result.deviation_fwd_um, "tab:blue", "↑ forward"),
        (result.mean_bwd_um, result.s_bwd_um, result.deviation_bwd_um, "tab:red", "↓ backward"),
    ):
        ax.plot(p, mean, "-o", color=colour, label=f"x̄ {label}")
        ax.fill_between(p, mean - 2 * s, mean + 2 * s, color=colour, alpha=0.2, label="±2s")
        ax.plot(np.repeat(p, dev.shape[1]), dev.ravel(), ".", color=colour, alpha=0.5, ms=3)
    ax.plot(p, result.mean_bidir_um, "--", color="black", label="x̄ bidirectional")
    ax.set_xlabel("target position (mm)")
    ax.set_ylabel("positional deviation measured − target (µm)")
    ax.set_title(
        f"{title}\nA={result.A_um:.1f} E={result.E_um:.1f} M={result.M_um:.1f} "
        f"R={result.R_um:.1f} B={result.B_um:.1f} µm"
    )
    ax.grid(True, alpha=0.3)
    ax.legend(fontsize=8)
    fig.tight_layout()
    fig.savefig(path, format="png")
    return path
