"""What a correction grid is made of: the working volume, the error pose at every node and one
sensitivity grid per runtime signal, checked once (:func:`check_nodes`), whoever made them
(a machine model, measured poses, a grid file).

Units: volume mm, translations µm at stylus offset 0, rotation sensitivities µrad (rotation
vector) per signal unit, quaternions (w, x, y, z) of ``R_work_stylus``.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from typing import Any, NamedTuple

import numpy as np
from numpy.typing import ArrayLike, NDArray

from .inputs import GridSignal
from .interpolation import make_grid_continuous

__all__ = [
    "MAX_NODES",
    "MAX_STEPS_PER_AXIS",
    "MAX_UM",
    "MIN_STEPS_PER_AXIS",
    "NodeData",
    "check_nodes",
    "check_steps",
]

FloatArray = NDArray[np.float64]

MIN_STEPS_PER_AXIS = 4  # the not-a-knot cubic spline needs 4 nodes per axis
MAX_STEPS_PER_AXIS = 1000
MAX_NODES = 2_000_000  # ~0.5 GB with 4 signals; beyond this is not a sensible grid
MAX_UM = 1e9  # largest |translation| µm (1 km) and |sensitivity| per signal unit of a grid


class NodeData(NamedTuple):
    """A grid's node data, in the order :class:`~.correction_grid.CorrectionGrid` takes it:
    volume corners (3,) mm, node quaternions (nx, ny, nz, 4), translations (nx, ny, nz, 3) µm,
    the signals, their sensitivity grids (S, nx, ny, nz, 3) (µm and µrad per unit, None
    without signals) and the metadata that goes into the file header."""

    lower_mm: ArrayLike
    upper_mm: ArrayLike
    q_work_stylus: ArrayLike
    translation_um: ArrayLike
    signals: Sequence[GridSignal] = ()
    sensitivity_translation_um: ArrayLike | None = None
    sensitivity_rotation_urad: ArrayLike | None = None
    metadata: Mapping[str, Any] | None = None


class CheckedNodes(NamedTuple):
    """:class:`NodeData` as :func:`check_nodes` returns it: float arrays of the right shapes,
    node quaternions unit and sign-continuous, zero sensitivity grids when there are no
    signals, the node counts ``steps`` and the node coordinates ``axes`` (mm)."""

    lower_mm: FloatArray
    upper_mm: FloatArray
    steps: tuple[int, int, int]
    axes: tuple[FloatArray, FloatArray, FloatArray]
    q_work_stylus: FloatArray
    translation_um: FloatArray
    signals: tuple[GridSignal, ...]
    sensitivity_translation_um: FloatArray
    sensitivity_rotation_urad: FloatArray


def check_steps(steps: Sequence[int]) -> tuple[int, int, int]:
    """``steps`` as three node counts per axis; ValueError when out of range or too many."""
    vals = tuple(int(s) for s in steps)
    if len(vals) != 3 or any(s != t for s, t in zip(vals, steps, strict=False)):
        raise ValueError(f"steps must be three integers (nodes per axis), got {tuple(steps)!r}")
    for axis, s in zip("xyz", vals, strict=True):
        if not MIN_STEPS_PER_AXIS <= s <= MAX_STEPS_PER_AXIS:
            raise ValueError(
                f"steps along {axis} = {s}: allowed {MIN_STEPS_PER_AXIS}…{MAX_STEPS_PER_AXIS} "
                "nodes per axis (the cubic spline needs at least 4)"
            )
    total = vals[0] * vals[1] * vals[2]
    if total > MAX_NODES:
        raise ValueError(
            f"steps {vals} give {total} nodes; at most {MAX_NODES} are allowed "
            "(a grid this size would not fit in memory; use fewer steps)"
        )
    return vals  # type: ignore[return-value]


def check_nodes(
    lower_mm: ArrayLike,
    upper_mm: ArrayLike,
    q_work_stylus: ArrayLike,
    translation_um: ArrayLike,
    signals: Sequence[GridSignal] = (),
    sensitivity_translation_um: ArrayLike | None = None,
    sensitivity_rotation_urad: ArrayLike | None = None,
) -> CheckedNodes:
    """The node data checked (ValueError naming the problem): shapes, an increasing volume,
    finite values, translations and sensitivities within :data:`MAX_UM`, unit quaternions
    (renormalised and made sign-continuous, :func:`.interpolation.make_grid_continuous`)."""
    lo = np.asarray(lower_mm, dtype=np.float64).reshape(3)
    hi = np.asarray(upper_mm, dtype=np.float64).reshape(3)
    q = np.asarray(q_work_stylus, dtype=np.float64)
    t = np.asarray(translation_um, dtype=np.float64)
    if q.ndim != 4 or q.shape[-1] != 4:
        raise ValueError(f"q_work_stylus must be (nx, ny, nz, 4), got {q.shape}")
    steps = check_steps(q.shape[:3])
    if t.shape != (*steps, 3):
        raise ValueError(f"translation_um must be {(*steps, 3)}, got {t.shape}")
    if not (np.all(np.isfinite(lo)) and np.all(np.isfinite(hi)) and np.all(hi > lo)):
        raise ValueError(f"volume axes must increase: lower {lo.tolist()}, upper {hi.tolist()}")
    if not (np.all(np.isfinite(q)) and np.all(np.isfinite(t))):
        raise ValueError("node quaternions and translations must be finite")
    if np.abs(t).max() > MAX_UM:  # 1e300 µm gave corrected coordinates of 1e297 mm
        raise ValueError(
            f"node translations reach {np.abs(t).max():g} µm, beyond ±{MAX_UM:g} µm: no "
            "machine error (check the model's tables and effects)"
        )
    norm_dev = np.abs(np.linalg.norm(q, axis=-1) - 1.0).max()
    if norm_dev > 1e-9:
        raise ValueError(f"node quaternions must be unit (largest |‖q‖ − 1| = {norm_dev:.3g})")
    sigs = tuple(signals)
    st, sr = _sensitivities(len(sigs), steps, sensitivity_translation_um, sensitivity_rotation_urad)
    axes = (
        np.linspace(lo[0], hi[0], steps[0]),
        np.linspace(lo[1], hi[1], steps[1]),
        np.linspace(lo[2], hi[2], steps[2]),
    )
    q_continuous = make_grid_continuous(q / np.linalg.norm(q, axis=-1, keepdims=True))
    return CheckedNodes(lo, hi, steps, axes, q_continuous, t, sigs, st, sr)


def _sensitivities(
    n_sig: int,
    steps: tuple[int, int, int],
    translation: ArrayLike | None,
    rotation: ArrayLike | None,
) -> tuple[FloatArray, FloatArray]:
    """The sensitivity grids (S, nx, ny, nz, 3) checked; zeros (0, …) without signals."""
    if not n_sig:
        return np.zeros((0, *steps, 3)), np.zeros((0, *steps, 3))
    if translation is None or rotation is None:
        raise ValueError("signals given without sensitivity grids")
    st = np.asarray(translation, dtype=np.float64)
    sr = np.asarray(rotation, dtype=np.float64)
    for name, arr in (("translation", st), ("rotation", sr)):
        if arr.shape != (n_sig, *steps, 3):
            raise ValueError(f"sensitivity_{name} must be {(n_sig, *steps, 3)}, got {arr.shape}")
        if not np.all(np.isfinite(arr)):
            raise ValueError(f"sensitivity_{name} grid must be finite")
        if np.abs(arr).max(initial=0.0) > MAX_UM:
            raise ValueError(
                f"sensitivity_{name} reaches {np.abs(arr).max():g} per unit of a signal, "
                f"beyond ±{MAX_UM:g}: no machine error"
            )
    return st, sr
