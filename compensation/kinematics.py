"""Kinematic chains of three-axis CMMs, evaluated exactly (homogeneous transforms) and to first order.

Frames and signs (see docs/conventions.md, stated once there and summarised here):

* Right-handed machine frame; positions in mm, linear errors in µm, angles in µrad.
* ``u = q − reference``: axis positions measured from the reference point (the paper's x, y, z).
* A carriage's error is a rigid motion ``E = (R(εx, εy, εz), δ)`` applied *after* its nominal
  translation: ``T_parent_carriage = Tr(u·d) · E``. ``R = Rx(εx)·Ry(εy)·Rz(εz)`` (active,
  pre-multiplying, exact sin/cos), the matrix printed by Hermann (seed 002) with its two typos fixed.
* Tool side (axes that carry the probe, listed base → tip)::

      p_base = Tr(u1·d1)·E1 · Tr(u2·d2)·E2 · … · p_stylus

* Workpiece side (tables that carry the workpiece, listed base → workpiece): the table moves by
  −u along its axis and its error is ``E' = (R(ε), −δ)``, i.e. the linear errors of a table are
  the errors of the *relative* motion (what an interferometer between tool and table reads) while
  its angular errors are the table's own rotations. This is the convention that reproduces the
  paper's appendix A.1 (its ``+δx(y)`` and ``+y·Ez(y)`` terms for FB1)::

      T_base_work = Tr(−u1·d1)·E'1 · Tr(−u2·d2)·E'2 · …
      p_work = T_base_work⁻¹ · p_base

* Squareness tilts the nominal directions of travel: ``d_x = (cos α, −sin α, 0)``, ``d_y = e_y``,
  ``d_z = Ry(−β1)·Rx(β2)·e_z ≈ (−β1, −β2, 1)``; to first order ΔY = −α·x, ΔX = −β1·z, ΔY = −β2·z.
* Volumetric error = p_work − (u + p_stylus): error = true − indicated.

The error pose of the stylus-carrying frame relative to the workpiece is ``(R_work_stylus, t)`` with
``error(p) = t + (R_work_stylus − I)·p`` exactly, because every step of the chain is rigid.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from .parametric_errors import AXES, AXIS_INDEX

FloatArray = NDArray[np.float64]

UM_PER_MM = 1000.0
RAD_PER_URAD = 1e-6


@dataclass(frozen=True)
class Chain:
    """Which axes carry the stylus (``tool``, base → tip) and which the workpiece (base → work)."""

    tool: tuple[str, ...]
    workpiece: tuple[str, ...]

    def __post_init__(self) -> None:
        axes = list(self.tool) + list(self.workpiece)
        if sorted(axes) != sorted(AXES):
            raise ValueError(
                f"a chain must name each of x, y, z exactly once, got tool={list(self.tool)} "
                f"workpiece={list(self.workpiece)}"
            )

    def describe(self) -> str:
        tool = " → ".join(["base", *self.tool, "stylus"])
        work = " → ".join(["base", *self.workpiece, "workpiece"])
        return f"tool: {tool}; workpiece: {work}"


#: The ten kinematic models of the paper (section 2), as chains. Derived from the machine
#: descriptions and checked term by term against appendix A.1 (docs/seed-equations.md).
MODEL_CHAINS: dict[str, Chain] = {
    # moving bridge: bridge on the base, carriage on the bridge, ram in the carriage
    "MB1": Chain(tool=("y", "x", "z"), workpiece=()),
    "MB2": Chain(tool=("x", "y", "z"), workpiece=()),
    # fixed bridge: carriage along the bridge, ram; the table moves the workpiece
    "FB1": Chain(tool=("x", "z"), workpiece=("y",)),
    "FB2": Chain(tool=("y", "z"), workpiece=("x",)),
    # moving horizontal arm: column on the bed, carriage up the column, arm through the carriage
    "MH1": Chain(tool=("y", "z", "x"), workpiece=()),
    "MH2": Chain(tool=("x", "z", "y"), workpiece=()),
    # fixed horizontal arm: column on the bed with its carriage; a table on the bed
    "FH1": Chain(tool=("y", "z"), workpiece=("x",)),
    "FH2": Chain(tool=("x", "z"), workpiece=("y",)),
    # column type: a two-axis table (primary = lower guideway first) and a vertical ram
    "CX1": Chain(tool=("z",), workpiece=("x", "y")),
    "CY1": Chain(tool=("z",), workpiece=("y", "x")),
}

#: For the horizontal-arm models, the axis of the arm (for the optional φ arm-deflection terms).
ARM_AXIS: dict[str, str] = {"MH1": "x", "MH2": "y"}


def rotation_from_angles(angles_urad: FloatArray) -> FloatArray:
    """``R = Rx(εx)·Ry(εy)·Rz(εz)`` for (…, 3) angles in µrad → (…, 3, 3), exact sin/cos."""
    a = np.asarray(angles_urad, dtype=float) * RAD_PER_URAD
    cx, cy, cz = np.cos(a[..., 0]), np.cos(a[..., 1]), np.cos(a[..., 2])
    sx, sy, sz = np.sin(a[..., 0]), np.sin(a[..., 1]), np.sin(a[..., 2])
    r = np.empty((*a.shape[:-1], 3, 3))
    r[..., 0, 0] = cy * cz
    r[..., 0, 1] = -cy * sz
    r[..., 0, 2] = sy
    r[..., 1, 0] = cx * sz + sx * sy * cz
    r[..., 1, 1] = cx * cz - sx * sy * sz
    r[..., 1, 2] = -sx * cy
    r[..., 2, 0] = sx * sz - cx * sy * cz
    r[..., 2, 1] = sx * cz + cx * sy * sz
    r[..., 2, 2] = cx * cy
    return r


def travel_directions(squareness_urad: FloatArray) -> FloatArray:
    """Unit directions of travel of X, Y, Z for (N, 3) squareness (α, β1, β2) µrad → (N, 3, 3).

    ``out[:, k]`` is the direction of axis k.
    """
    sq = np.asarray(squareness_urad, dtype=float) * RAD_PER_URAD
    alpha, beta1, beta2 = sq[:, 0], sq[:, 1], sq[:, 2]
    d = np.zeros((sq.shape[0], 3, 3))
    d[:, 0, 0] = np.cos(alpha)
    d[:, 0, 1] = -np.sin(alpha)
    d[:, 1, 1] = 1.0
    d[:, 2, 0] = -np.sin(beta1) * np.cos(beta2)
    d[:, 2, 1] = -np.sin(beta2)
    d[:, 2, 2] = np.cos(beta1) * np.cos(beta2)
    return d


def _matvec(r: FloatArray, v: FloatArray) -> FloatArray:
    return np.einsum("nij,nj->ni", r, v)


def exact_pose(
    chain: Chain, u_mm: FloatArray, errors: FloatArray, squareness_urad: FloatArray
) -> tuple[FloatArray, FloatArray]:
    """Exact error pose of the stylus frame relative to the workpiece.

    ``u_mm`` (N, 3) positions from the reference; ``errors`` (N, 3, 6): per axis x, y, z the
    (δx, δy, δz) µm and (εx, εy, εz) µrad; ``squareness_urad`` (N, 3).
    Returns ``(R_work_stylus (N, 3, 3), t_um (N, 3))`` with ``error(p) = t + (R − I)·p``.
    """
    n = u_mm.shape[0]
    d = travel_directions(squareness_urad)
    rot = rotation_from_angles(errors[..., 3:])  # (N, 3 axes, 3, 3)
    delta_mm = errors[..., :3] / UM_PER_MM
    v = np.zeros((n, 3))
    r_acc = np.broadcast_to(np.eye(3), (n, 3, 3)).copy()
    for axis in reversed(chain.tool):
        k = AXIS_INDEX[axis]
        v = _matvec(rot[:, k], v) + delta_mm[:, k] + u_mm[:, k : k + 1] * d[:, k]
        r_acc = np.einsum("nij,njk->nik", rot[:, k], r_acc)
    for axis in chain.workpiece:
        k = AXIS_INDEX[axis]
        rt = np.swapaxes(rot[:, k], 1, 2)
        v = _matvec(rt, v + u_mm[:, k : k + 1] * d[:, k] + delta_mm[:, k])
        r_acc = np.einsum("nij,njk->nik", rt, r_acc)
    t_um = (v - u_mm) * UM_PER_MM
    return r_acc, t_um


def _cross_matrix_columns(arm_mm: FloatArray) -> FloatArray:
    """(N, 3 out, 3 k): column k is e_k × arm, so (ε × arm) = M @ ε."""
    n = arm_mm.shape[0]
    m = np.zeros((n, 3, 3))
    ax, ay, az = arm_mm[:, 0], arm_mm[:, 1], arm_mm[:, 2]
    # e_x × a = (0, −az, ay); e_y × a = (az, 0, −ax); e_z × a = (−ay, ax, 0)
    m[:, 1, 0], m[:, 2, 0] = -az, ay
    m[:, 0, 1], m[:, 2, 1] = az, -ax
    m[:, 0, 2], m[:, 1, 2] = -ay, ax
    return m


def first_order_jacobian(
    chain: Chain, u_mm: FloatArray, stylus_mm: FloatArray
) -> tuple[FloatArray, FloatArray]:
    """Coefficients of the first-order (small-angle, linear) volumetric error.

    Returns ``(J (N, 3 out, 3 axes, 6 slots), S (N, 3 out, 3 squareness))`` in µm per µm or per
    µrad, such that ``ΔX_i = Σ J[i, a, s]·E[a, s] + Σ S[i, j]·sq[j]`` — the paper's appendix A.1.
    """
    n = u_mm.shape[0]
    p = np.broadcast_to(np.asarray(stylus_mm, dtype=float), (n, 3))
    jac = np.zeros((n, 3, 3, 6))
    eye = np.eye(3)
    nominal = np.zeros((n, 3, 3))  # nominal displacement of each axis, u_k e_k
    for k in range(3):
        nominal[:, k, k] = u_mm[:, k]
    for pos, axis in enumerate(chain.tool):
        k = AXIS_INDEX[axis]
        arm = p.copy()
        for later in chain.tool[pos + 1 :]:
            arm += nominal[:, AXIS_INDEX[later]]
        jac[:, :, k, :3] = eye
        jac[:, :, k, 3:] = _cross_matrix_columns(arm) / UM_PER_MM
    tool_total = p + sum((nominal[:, AXIS_INDEX[a]] for a in chain.tool), np.zeros((n, 3)))
    for pos, axis in enumerate(chain.workpiece):
        k = AXIS_INDEX[axis]
        arm = tool_total.copy()
        for lower in chain.workpiece[: pos + 1]:
            arm += nominal[:, AXIS_INDEX[lower]]
        jac[:, :, k, :3] = eye
        jac[:, :, k, 3:] = -_cross_matrix_columns(arm) / UM_PER_MM
    sq = np.zeros((n, 3, 3))
    sq[:, 1, 0] = -u_mm[:, 0] / UM_PER_MM  # α: ΔY = −α·x
    sq[:, 0, 1] = -u_mm[:, 2] / UM_PER_MM  # β1: ΔX = −β1·z
    sq[:, 1, 2] = -u_mm[:, 2] / UM_PER_MM  # β2: ΔY = −β2·z
    return jac, sq


def first_order_error(
    chain: Chain,
    u_mm: FloatArray,
    errors: FloatArray,
    squareness_urad: FloatArray,
    stylus_mm: FloatArray,
) -> FloatArray:
    """First-order volumetric error (N, 3) µm: the paper's appendix A.1 form for this chain."""
    jac, sq = first_order_jacobian(chain, u_mm, stylus_mm)
    return np.einsum("nias,nas->ni", jac, errors) + np.einsum("nij,nj->ni", sq, squareness_urad)
