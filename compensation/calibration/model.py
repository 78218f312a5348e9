"""The machine model the observation models evaluate: the project's exact kinematic chain
(:func:`..kinematics.exact_pose`, full rigid-body transforms) of the errors given by θ
(:class:`.basis.Layout`), plus the plan's thermal terms, and its first-order Jacobian
(:func:`..kinematics.first_order_jacobian`, the paper's appendix A.1) with respect to θ.

The fit's residuals are always exact; the Jacobian is first order (its relative error is of the
order of the angles, 10⁻⁴, so Gauss–Newton still converges to the exact least-squares solution in
a few steps). Units: positions mm, errors µm, rotations µrad.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import NDArray

from ..kinematics import Chain, exact_pose, first_order_jacobian
from ..parametric_errors import AXES, SQUARENESS
from .basis import Layout

__all__ = ["MachineModel", "PointSet", "rotation_vector_urad"]

FloatArray = NDArray[np.float64]


def rotation_vector_urad(rotation: FloatArray) -> FloatArray:
    """(N, 3) small rotation vector (µrad) of (N, 3, 3) rotations: the skew part (exact to
    second order in the angle, 10⁻¹⁰ relative at 100 µrad)."""
    r = rotation
    w = np.empty((*r.shape[:-2], 3))
    w[..., 0] = 0.5 * (r[..., 2, 1] - r[..., 1, 2])
    w[..., 1] = 0.5 * (r[..., 0, 2] - r[..., 2, 0])
    w[..., 2] = 0.5 * (r[..., 1, 0] - r[..., 0, 1])
    return 1e6 * w


@dataclass(frozen=True)
class PointSet:
    """Fixed measuring conditions of N readings: indicated points (mm), stylus or optic offset
    (N, 3) mm, last direction of travel per axis (N, 3; 0 unknown) and the thermal terms (N, 3)
    µm of the plan's ``[thermal]`` data at the readings' temperatures (zero without them)."""

    q_mm: FloatArray
    stylus_mm: FloatArray
    direction: FloatArray
    thermal_um: FloatArray
    bases: tuple[tuple[Any, FloatArray], ...] = ()  # (function, (N, size) basis): computed once


class MachineModel:
    """Exact evaluation and first-order Jacobians of the model with errors θ on ``chain``."""

    def __init__(self, layout: Layout, chain: Chain, reference_mm: FloatArray, base: object):
        self.layout = layout
        self.chain = chain
        self.reference_mm = np.asarray(reference_mm, dtype=float)
        self.base = base  # the plan's machine without errors: its thermal terms

    def points(
        self,
        q_mm: FloatArray,
        stylus_mm: FloatArray,
        direction: FloatArray | None = None,
        temps_C: Mapping[str, FloatArray] | None = None,
    ) -> PointSet:
        """The :class:`PointSet` of readings at ``q_mm`` with ``stylus_mm`` ((3,) or (N, 3))."""
        q = np.asarray(q_mm, dtype=float)
        n = q.shape[0]
        p = np.broadcast_to(np.asarray(stylus_mm, dtype=float), (n, 3)).copy()
        d = np.zeros((n, 3)) if direction is None else np.asarray(direction, dtype=float)
        thermal = np.zeros((n, 3))
        if temps_C:
            thermal = self.base.volumetric_error(q, p, dict(temps_C))  # type: ignore[attr-defined]
        bases = tuple(self.layout.blocks(q, d))
        return PointSet(q_mm=q, stylus_mm=p, direction=d, thermal_um=thermal, bases=bases)

    def exact(self, theta: FloatArray, pts: PointSet) -> tuple[FloatArray, FloatArray]:
        """(volumetric error (N, 3) µm at the stylus, rotation vector (N, 3) µrad of
        ``R_work_stylus``), exact."""
        errors = np.zeros((pts.q_mm.shape[0], 3, 6))
        for fn, m in pts.bases:
            errors[:, fn.axis, fn.slot] += m @ theta[fn.cols]
        sq = self.layout.squareness_values(theta)
        u = pts.q_mm - self.reference_mm
        rot, t_um = exact_pose(self.chain, u, errors, np.broadcast_to(sq, (u.shape[0], 3)))
        err = t_um + 1000.0 * np.einsum("nij,nj->ni", rot - np.eye(3), pts.stylus_mm)
        return err + pts.thermal_um, rotation_vector_urad(rot)

    def error_jacobian(self, pts: PointSet) -> FloatArray:
        """(N, 3, P) first-order derivative of the volumetric error (µm) with respect to θ."""
        u = pts.q_mm - self.reference_mm
        jac, sq = first_order_jacobian(self.chain, u, pts.stylus_mm)
        out = np.zeros((u.shape[0], 3, self.layout.n))
        for fn, m in pts.bases:
            out[:, :, fn.cols] += jac[:, :, fn.axis, fn.slot][:, :, None] * m[:, None, :]
        for j, name in enumerate(SQUARENESS):
            if name in self.layout.squareness:
                out[:, :, self.layout.squareness[name]] += sq[:, :, j]
        return out

    def rotation_jacobian(self, pts: PointSet) -> FloatArray:
        """(N, 3, P) first-order derivative of the rotation vector of ``R_work_stylus`` (µrad):
        a tool-side carriage's angular error adds its own rotation, a table's subtracts it."""
        out = np.zeros((pts.q_mm.shape[0], 3, self.layout.n))
        for fn, m in pts.bases:
            if fn.slot < 3:
                continue
            sign = 1.0 if AXES[fn.axis] in self.chain.tool else -1.0
            out[:, fn.slot - 3, fn.cols] += sign * m
        return out
