"""Cos/sin columns of a cyclic error at many periods at once (the diagnosis' period scans).

:func:`harmonic_columns` gives, for positions ``q`` (mm) along an axis and T periods, the
columns ``cos(n·ω·q) − cos(n·ω·ref)`` and ``sin(n·ω·q) − sin(n·ω·ref)`` (ω = 2π/period) of
harmonics n = 1…H, each zero at the reference position (as :class:`.periodic.PeriodicEffect`).
The phases are the products numpy forms in ``np.outer(q, n·ω)``; a compiled loop evaluates the
cosine and sine of each phase together (libm's, as numpy's ``cos``/``sin``: the same values,
in half the time of two array passes) for scans of at least :data:`COMPILED_FROM` values; a
smaller scan is not worth numba's import and cache load (~0.5 s of CPU once per process) and is
evaluated by numpy (the same expression). numba is imported on the first large scan only.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import numpy as np
from numpy.typing import NDArray

__all__ = ["COMPILED_FROM", "harmonic_columns"]

FloatArray = NDArray[np.float64]
_KERNEL: Any = None
#: Phase values (N·T·harmonics) from which a call uses the compiled loop: saving ~15 ns a value,
#: it repays the one-time ~0.5 s in well under 100 such calls (a dense record's scan makes
#: hundreds of 2·10⁶-value calls; a 700-point session's stays with numpy).
COMPILED_FROM = 1_000_000


def _kernel() -> Any:
    global _KERNEL
    if _KERNEL is None:
        import math

        from ..jit import njit_cached

        @njit_cached()
        def fill(q, w, c0, s0, out, col):  # type: ignore[no-untyped-def]
            for i in range(q.shape[0]):
                for j in range(w.shape[0]):
                    ph = q[i] * w[j]
                    out[i, j, col] = math.cos(ph) - c0[j]
                    out[i, j, col + 1] = math.sin(ph) - s0[j]

        _KERNEL = fill
    return _KERNEL


def harmonic_columns(
    q_mm: FloatArray, periods_mm: Sequence[Any], ref_mm: float, harmonics: int
) -> FloatArray:
    """(N, T, 2·harmonics) columns: for each period (mm) and harmonic n, ``cos(n·ω·q) −
    cos(n·ω·ref)`` then ``sin(n·ω·q) − sin(n·ω·ref)``, ω = 2π/period, q (N,) positions mm."""
    q = np.ascontiguousarray(q_mm, dtype=np.float64)
    w = 2.0 * np.pi / np.asarray([float(p) for p in periods_mm])
    out = np.empty((q.shape[0], len(w), 2 * harmonics))
    fill = _kernel() if out.size // 2 >= COMPILED_FROM else None
    for h in range(1, harmonics + 1):
        hw = np.ascontiguousarray(h * w)
        ph0 = h * w * ref_mm
        if fill is not None:
            fill(q, hw, np.cos(ph0), np.sin(ph0), out, 2 * h - 2)
        else:
            ph = np.outer(q, hw)
            out[:, :, 2 * h - 2] = np.cos(ph) - np.cos(ph0)
            out[:, :, 2 * h - 1] = np.sin(ph) - np.sin(ph0)
    return out
