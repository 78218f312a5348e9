"""What a controller's tables leave of a machine's error: the model error minus what the tables
take off, evaluated as the control interpolates, over an evaluation grid and every combination
of travel directions of the axes whose error depends on it (docs/export.md). Units: mm, µm.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from itertools import product
from typing import Any

import numpy as np

from ..machine import Machine
from ..parametric_errors import AXES
from .decompose import direction_axes, model_error_um
from .limits import ExportError
from .splines import FloatArray

__all__ = ["direction_combinations", "error_stats", "evaluation_points", "measure_residual"]

_CHUNK = 100_000  # points per model evaluation (bounds the memory)


def error_stats(r: FloatArray, what: str) -> dict[str, Any]:
    """RMS and max µm of the 3-D vector and per axis; :class:`ExportError` naming ``what`` when
    one is not a finite number (an error so large that its square overflows, or a table value
    beyond what the control's arithmetic holds): never a NaN/inf figure reported as a result."""
    with np.errstate(over="ignore", invalid="ignore"):
        norm = np.linalg.norm(r, axis=1)
        rms, peak = float(np.sqrt(np.mean(norm**2))), float(np.max(norm))
        per_axis = {
            AXES[k]: {
                "rms": float(np.sqrt(np.mean(r[:, k] ** 2))),
                "max": float(np.max(np.abs(r[:, k]))),
            }
            for k in range(3)
        }
    figures = [rms, peak] + [v for a in per_axis.values() for v in a.values()]
    if not all(math.isfinite(v) for v in figures):
        raise ExportError(
            f"{what} over the working volume is not a finite number (RMS {rms:g} µm, "
            f"max {peak:g} µm): the machine description's errors are too large to "
            "export; check its error tables (µm, µrad)"
        )
    return {"rms": rms, "max": peak, "per_axis": per_axis}


def evaluation_points(machine: Machine, steps: Sequence[int]) -> FloatArray:
    """The evaluation grid (N, 3) mm: ``steps`` nodes per axis over the volume, C order."""
    nodes = machine.volume.nodes(tuple(int(s) for s in steps))  # type: ignore[arg-type]
    mesh = np.meshgrid(*nodes, indexing="ij")
    return np.stack([m.ravel() for m in mesh], axis=1)


def direction_combinations(dir_axes: Sequence[int]) -> list[dict[int, float]]:
    """Every combination of ±1 for the axes whose error depends on the direction ({} if none)."""
    return [dict(zip(dir_axes, c, strict=True)) for c in product((1.0, -1.0), repeat=len(dir_axes))]


def measure_residual(
    machine: Machine,
    tool_mm: FloatArray,
    represented_um: Callable[[FloatArray, FloatArray], FloatArray],
    steps: Sequence[int],
) -> tuple[dict[str, Any], dict[str, Any]]:
    """(residual, uncompensated) statistics µm over the evaluation grid and direction
    combinations: residual = model error − the error the tables take off."""
    q_all = evaluation_points(machine, steps)
    res, raw = [], []
    for combo in direction_combinations(direction_axes(machine)):
        for start in range(0, len(q_all), _CHUNK):
            q = q_all[start : start + _CHUNK]
            e = model_error_um(machine, q, tool_mm, combo)
            dirs = np.ones_like(q)
            for a, s in combo.items():
                dirs[:, a] = s
            with np.errstate(over="ignore", invalid="ignore"):
                res.append(e - represented_um(q, dirs))
            raw.append(e)
    raw_stats = error_stats(np.concatenate(raw), "the model's error")
    return error_stats(np.concatenate(res), "the residual after the written tables"), raw_stats
