"""The batch correction path of a grid: N indicated points with their styli and signals, the
compiled kernels run serially or on the thread pool, and the status of every point
(:mod:`.status`). ``CorrectionGrid.correct``, ``pose`` and ``error_um`` go through here.

Positions mm, translations µm, quaternions (w, x, y, z).
"""

from __future__ import annotations

import math
import os
from collections.abc import Mapping, Sequence
from typing import Any, NamedTuple

import numpy as np
from numpy.typing import ArrayLike, NDArray

from . import kernels as kern
from .inputs import GridSignal, signal_deviations
from .status import INVALID, MISSING_INPUT, NO_TEMPERATURE, OUTSIDE, VOLUME_TOL_MM, statuses

__all__ = ["PARALLEL_MIN", "BatchCorrector", "BatchResult"]

FloatArray = NDArray[np.float64]
PARALLEL_MIN = 256
"""Points from which the kernels run on the thread pool (fewer: not worth waking it)."""
_WARMED = [False]  # numba's compiled code is per process: so is its warm-up


class BatchResult(NamedTuple):
    """Corrected positions (N, 3) mm (NaN where refused), status (N,), the indicated points
    (N, 3) mm as read, and (``want_pose``) the error quaternions (N, 4) and translations
    (N, 3) µm (else (1, ·) placeholders)."""

    corrected_mm: FloatArray
    status: NDArray[np.str_]
    points_mm: FloatArray
    q: FloatArray
    translation_um: FloatArray


class BatchCorrector:
    """Corrects batches of points with one grid's kernel tables (:class:`.kernels.KernelTables`)
    over the volume ``lower_mm`` … ``upper_mm`` with the grid's ``signals``. Stateless between
    calls (safe from any thread)."""

    def __init__(
        self,
        tables: kern.KernelTables,
        lower_mm: FloatArray,
        upper_mm: FloatArray,
        signals: Sequence[GridSignal],
    ) -> None:
        self._args = tables.args()
        self.lower_mm = lower_mm
        self.upper_mm = upper_mm
        self.signals = tuple(signals)
        self._placeholders = (np.zeros((1, 4)), np.zeros((1, 3)))
        if not _WARMED[0]:  # compile or load the serial kernel now, not on the first reading
            # Only the serial kernel: single readings and batches below PARALLEL_MIN (all the
            # daemon ever sends) run it. The thread-pool kernel is compiled or loaded on its
            # first batch of PARALLEL_MIN points or more: a start without a numba cache (the
            # unprivileged daemon) would otherwise spend ~60 % of its compile time on a kernel
            # it never calls (measured: serial 10.7 s, parallel +17.5 s of CPU).
            p = np.array([0.5 * (lower_mm + upper_mm)])
            self.run(p, np.zeros((1, 3)), np.zeros((1, len(self.signals))), 3, parallel=False)
            _WARMED[0] = True

    def run(
        self,
        points: FloatArray,
        stylus: FloatArray,
        dev: FloatArray,
        ncomp: int,
        parallel: bool,
        want_pose: bool = False,
    ) -> tuple[FloatArray, FloatArray, FloatArray]:
        """The kernels on points (N, 3) mm inside the volume, stylus (1 or N, 3) mm, signal
        deviations (N, S): corrected (N, 3) mm, and if ``want_pose`` the pose (N, 4), (N, 3) µm."""
        n = points.shape[0]
        out = np.empty((n, 3))
        out_q, out_t = (np.empty((n, 4)), np.empty((n, 3))) if want_pose else self._placeholders
        outputs = (out, out_q, out_t)
        if parallel:
            threads = max(1, (os.cpu_count() or 1))
            chunk = max(512, math.ceil(n / (8 * threads)))
            kern.eval_parallel(self._args, points, stylus, dev, outputs, ncomp, want_pose, chunk)
        else:
            kern.eval_serial(self._args, points, stylus, dev, outputs, ncomp, want_pose)
        return out, out_q, out_t

    def __call__(
        self,
        points_mm: ArrayLike,
        stylus_mm: ArrayLike,
        temps_C: Mapping[str, Any] | None,
        inputs: Mapping[str, Any] | None,
        refuse: bool,
        want_pose: bool = False,
    ) -> BatchResult:
        """Correct indicated ``points_mm`` ((3,) or (N, 3)) for ``stylus_mm`` ((3,) or (N, 3))
        and the signals (scalars or (N,) arrays by name, in either mapping); ``refuse``: policy
        ``"refuse"`` (outside points get NaN) rather than ``"clamp"``."""
        pts = np.asarray(points_mm, dtype=np.float64)
        if pts.ndim == 1 and pts.shape[0] == 3:
            pts = pts[None, :]
        if pts.ndim != 2 or pts.shape[1] != 3:
            raise ValueError(f"points_mm must be an (N, 3) array of mm, got shape {pts.shape}")
        n = pts.shape[0]
        stylus = np.asarray(stylus_mm, dtype=np.float64)
        stylus = stylus.reshape(1, 3) if stylus.shape == (3,) else stylus
        if stylus.ndim != 2 or stylus.shape[1] != 3 or stylus.shape[0] not in (1, n):
            raise ValueError(f"stylus_mm must be (3,) or ({n}, 3) mm, got shape {stylus.shape}")
        bad = ~np.isfinite(pts).all(axis=1)
        sty_bad = ~np.isfinite(stylus).all(axis=1)
        bad = bad | np.broadcast_to(sty_bad, (n,))
        clamped = np.clip(pts, self.lower_mm, self.upper_mm)
        outside_mask = np.any(np.abs(clamped - pts) > VOLUME_TOL_MM, axis=1) & ~bad
        if bad.any():
            clamped[bad] = self.lower_mm
            stylus = np.where(np.isfinite(stylus), stylus, 0.0)
        dev, no_temp, no_input = signal_deviations(self.signals, n, temps_C, inputs)
        ncomp = 3 + 6 * len(self.signals) if (dev.size and np.any(dev != 0.0)) else 3
        stylus = np.ascontiguousarray(stylus)
        out, q, t = self.run(clamped, stylus, dev, ncomp, n >= PARALLEL_MIN, want_pose)
        if outside_mask.any():
            out[outside_mask] += pts[outside_mask] - clamped[outside_mask]
        flags = (
            np.where(bad, INVALID, 0)
            | np.where(outside_mask, OUTSIDE, 0)
            | np.where(no_temp, NO_TEMPERATURE, 0)
            | np.where(no_input, MISSING_INPUT, 0)
        )
        status, refused_mask = statuses(flags, refuse)
        out[refused_mask] = np.nan
        return BatchResult(out, status, pts, q, t)
