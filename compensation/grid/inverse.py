"""The inverse of the correction: the indicated (command) position whose corrected position is
a given target, for machine-tool users. Positions mm.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from .inputs import subset
from .status import REFUSED_STATUSES

__all__ = ["CorrectFn", "command_for_target"]

FloatArray = NDArray[np.float64]
#: ``correct(points_mm, stylus_mm, temps_C, inputs, outside=...) → (corrected_mm, status)``,
#: e.g. :meth:`CorrectionGrid.correct <.correction_grid.CorrectionGrid.correct>`.
CorrectFn = Callable[..., tuple[FloatArray, NDArray[np.str_]]]


def command_for_target(
    correct: CorrectFn,
    targets_mm: ArrayLike,
    stylus_mm: ArrayLike = (0.0, 0.0, 0.0),
    temps_C: Mapping[str, Any] | None = None,
    inputs: Mapping[str, Any] | None = None,
    *,
    tol_mm: float = 1e-6,
    max_iter: int = 20,
) -> tuple[FloatArray, NDArray[np.str_]]:
    """Indicated (command) positions whose corrected position is ``targets_mm`` (N, 3).

    The inverse for machine-tool users: solves ``c + e(c) = target`` by the fixed-point
    iteration ``c ← target − e(c)`` (contracts because ‖∂e/∂c‖ ≈ 10⁻⁵). Stops when every
    step is below ``tol_mm``; points that have not converged after ``max_iter`` iterations
    get NaN and status ``"not_converged"``. Other statuses as in :meth:`correct` (a target
    outside the volume is refused whatever the policy). ``correct`` is the correction
    (:data:`CorrectFn`).
    """
    tgt = np.asarray(targets_mm, dtype=np.float64).reshape(-1, 3)
    cmd = tgt.copy()
    _, status = correct(tgt, stylus_mm, temps_C, inputs, outside="refuse")
    active = ~np.isin(status, sorted(REFUSED_STATUSES))
    converged = ~active
    for _ in range(max_iter):
        idx = np.flatnonzero(~converged)
        if idx.size == 0:
            break
        sty = np.asarray(stylus_mm, dtype=np.float64)
        sty_i = sty[idx] if sty.ndim == 2 and sty.shape[0] == tgt.shape[0] else sty
        sub_t = subset(temps_C, idx, tgt.shape[0])
        sub_i = subset(inputs, idx, tgt.shape[0])
        corr, _ = correct(cmd[idx], sty_i, sub_t, sub_i, outside="clamp")
        new = tgt[idx] - (corr - cmd[idx])
        step = np.abs(new - cmd[idx]).max(axis=1)
        cmd[idx] = new
        converged[idx[step < tol_mm]] = True
    fail = ~converged
    cmd[fail] = np.nan
    status[fail] = "not_converged"
    cmd[~active] = np.nan
    return cmd, status
