"""Rigid-body motions of the whole volume in the space of the identified parameters θ, and on a
grid of the volume — what no data kind sees (docs/calibration.md §gauge).

A rigid rotation ω (µrad) of the workpiece frame changes the volumetric error at indicated q
with stylus p by ``ω × (q − reference + p)·10⁻³`` µm, at *every* stylus. In the parametric
model it is a constant angular error of the carriage nearest the base together with straightness
slopes (to first order exactly); :func:`rotation_directions` finds the θ that produce it by
least squares over a grid and several styli (and reports how exactly they do). Translations are
fixed by the model itself: every linear error is zero at the reference point.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray

from .model import MachineModel

__all__ = ["grid_points", "line_basis", "rigid_basis", "rotation_directions"]

FloatArray = NDArray[np.float64]
_STYLI_MM = (
    (0.0, 0.0, 0.0),
    (150.0, 0.0, 0.0),
    (0.0, 150.0, 0.0),
    (0.0, 0.0, -150.0),
)


def grid_points(
    lower_mm: FloatArray, upper_mm: FloatArray, steps: tuple[int, int, int]
) -> FloatArray:
    """(N, 3) nodes of a regular grid of the volume, corners included, C order (z fastest)."""
    axes = [np.linspace(lower_mm[k], upper_mm[k], int(steps[k])) for k in range(3)]
    return np.stack(np.meshgrid(*axes, indexing="ij"), axis=-1).reshape(-1, 3)


def rigid_basis(points_mm: FloatArray) -> FloatArray:
    """(3N, 6) the volumetric error fields (µm) of unit rigid motions at ``points_mm``:
    translations of 1 µm along x, y, z and rotations of 1 µrad about x, y, z (about the
    points' centroid), component-major per point (x, y, z of point 0, then point 1 …)."""
    n = points_mm.shape[0]
    c = (points_mm - points_mm.mean(axis=0)) / 1000.0
    b = np.zeros((n, 3, 6))
    for k in range(3):
        b[:, k, k] = 1.0
    b[:, 1, 3], b[:, 2, 3] = -c[:, 2], c[:, 1]
    b[:, 0, 4], b[:, 2, 4] = c[:, 2], -c[:, 0]
    b[:, 0, 5], b[:, 1, 5] = -c[:, 1], c[:, 0]
    return b.reshape(3 * n, 6)


def line_basis(model: MachineModel) -> FloatArray:
    """(P, L) θ directions that make one function (or a squareness) a straight line: its
    constant (unless fixed at the reference) and its slope — what a rigid motion is built of."""
    lay = model.layout
    cols = []
    for fn in lay.functions:
        if fn.is_reversal:
            continue
        if fn.basis == "spline":
            assert fn.nodes_mm is not None
            s = (fn.nodes_mm - fn.lo_mm) / (fn.hi_mm - fn.lo_mm)
            shapes = [s] if fn.fixed_reference else [np.ones_like(s), s]
            values = [v[1:] if fn.fixed_reference else v for v in shapes]
        else:  # Legendre: P1 (and P0 when free)
            values = []
            for k in [1] if fn.fixed_reference else [0, 1]:
                v = np.zeros(fn.size)
                v[k - 1 if fn.fixed_reference else k] = 1.0
                values.append(v)
        for v in values:
            col = np.zeros(lay.n)
            col[fn.cols] = v
            cols.append(col)
    for j in lay.squareness.values():
        col = np.zeros(lay.n)
        col[j] = 1.0
        cols.append(col)
    return np.array(cols).T if cols else np.zeros((lay.n, 0))


def rotation_directions(model: MachineModel) -> tuple[FloatArray, float]:
    """(P, 3) θ producing a rigid rotation of 1 µrad about x, y, z — made of straight lines
    (:func:`line_basis`) — and the worst relative misfit of those fields on a grid at several
    styli (≈ 0 when the identified functions can express a rotation; large when they cannot,
    e.g. when straightness or angular errors are not identified)."""
    lay = model.layout
    lines = line_basis(model)
    q = grid_points(lay.lower_mm, lay.upper_mm, (4, 4, 4))
    rows, target = [], []
    for stylus in _STYLI_MM:
        pts = model.points(q, np.asarray(stylus))
        rows.append(model.error_jacobian(pts).reshape(-1, lay.n) @ lines)
        arm = (q - model.reference_mm + np.asarray(stylus)) / 1000.0
        field = np.zeros((q.shape[0], 3, 3))
        for k in range(3):
            w = np.zeros(3)
            w[k] = 1.0
            field[:, :, k] = np.cross(w, arm)
        target.append(field.reshape(-1, 3))
    g = np.vstack(rows)
    t = np.vstack(target)
    if lines.shape[1] == 0:
        return np.zeros((lay.n, 3)), float("inf")
    sol, *_ = np.linalg.lstsq(g, t, rcond=None)
    misfit = np.linalg.norm(g @ sol - t, axis=0) / np.linalg.norm(t, axis=0)
    return lines @ sol, float(np.max(misfit))
