"""Exact rigid-body chain of the ten kinematic models, written from docs/conventions.md only.

This is the generator's own physics; it imports nothing of cmm-comp (a test checks it). It meets
the project only in tests: against ``Machine.volumetric_error`` of the machine.toml it writes and
against the first-order chain of ``tests/independent_generator/chains.py`` (second-order
agreement), itself checked against the paper's appendix A.1.

* Positions mm, linear errors µm, angles µrad (rad inside the matrices).
* ``u = q − reference``: the axis travels from the reference point (the volume's lower corner).
* A carriage's error is a rigid motion applied after its nominal travel: ``Tr(u·d)·E`` with
  ``E = (R(ε), δ)``, ``R = Rx(εx)·Ry(εy)·Rz(εz)`` (active, exact sin/cos).
* Tool axes (base → stylus): ``p_base = Π_k Tr(u_k·d_k)·E_k · p`` (rigid motions as (R, t) pairs).
* Workpiece axes (base → table): ``T_base_work = Π_k Tr(−u_k·d_k)·E'_k`` with ``E' = (R(ε), −δ)``
  (a table's linear errors are those of the relative motion, its angles its own rotations);
  ``p_work = T_base_work⁻¹ · p_base``.
* Squareness tilts the nominal travel: X along ``(cos α, −sin α, 0)``, Y along ``e_y``, Z along
  ``Ry(−β1)·Rx(β2)·e_z ≈ (−β1, −β2, 1)``.
* Error = ``p_work − (u + p)`` (true − indicated), µm.
"""

from __future__ import annotations

from collections.abc import Mapping

import numpy as np
from independent_generator.chains import MODELS as CHAIN_MODELS
from numpy.typing import NDArray

FloatArray = NDArray[np.float64]

AXES = ("x", "y", "z")

#: model → (tool axes base → stylus, workpiece axes base → table), docs/formats.md §1.2; the table
#: of the independent first-order chain (a test checks both chains against the project's model)
MODEL_AXES: dict[str, tuple[tuple[str, ...], tuple[str, ...]]] = CHAIN_MODELS


def rotation_matrices(angles_urad: FloatArray) -> FloatArray:
    """(N, 3, 3) ``Rx(εx)·Ry(εy)·Rz(εz)`` for angles (N, 3) µrad, exact."""
    a = np.asarray(angles_urad, dtype=float) * 1e-6
    cx, sx = np.cos(a[:, 0]), np.sin(a[:, 0])
    cy, sy = np.cos(a[:, 1]), np.sin(a[:, 1])
    cz, sz = np.cos(a[:, 2]), np.sin(a[:, 2])
    n = a.shape[0]
    rx = np.zeros((n, 3, 3))
    ry = np.zeros((n, 3, 3))
    rz = np.zeros((n, 3, 3))
    rx[:, 0, 0] = 1.0
    rx[:, 1, 1], rx[:, 1, 2], rx[:, 2, 1], rx[:, 2, 2] = cx, -sx, sx, cx
    ry[:, 1, 1] = 1.0
    ry[:, 0, 0], ry[:, 0, 2], ry[:, 2, 0], ry[:, 2, 2] = cy, sy, -sy, cy
    rz[:, 2, 2] = 1.0
    rz[:, 0, 0], rz[:, 0, 1], rz[:, 1, 0], rz[:, 1, 1] = cz, -sz, sz, cz
    return rx @ ry @ rz


def travel_directions(squareness_urad: Mapping[str, float]) -> FloatArray:
    """(3, 3) unit directions of travel of X, Y, Z (rows) for α, β1, β2 (µrad)."""
    alpha = squareness_urad.get("alpha", 0.0) * 1e-6
    beta1 = squareness_urad.get("beta1", 0.0) * 1e-6
    beta2 = squareness_urad.get("beta2", 0.0) * 1e-6
    d_x = np.array([np.cos(alpha), -np.sin(alpha), 0.0])
    d_y = np.array([0.0, 1.0, 0.0])
    # Rx(β2)·e_z = (0, −sin β2, cos β2); then Ry(−β1)
    v = np.array([0.0, -np.sin(beta2), np.cos(beta2)])
    c, s = np.cos(-beta1), np.sin(-beta1)
    d_z = np.array([c * v[0] + s * v[2], v[1], -s * v[0] + c * v[2]])
    return np.stack([d_x, d_y, d_z])


Pose = tuple[FloatArray, FloatArray]  # (rotation (N, 3, 3), translation (N, 3) mm)


def _compose(a: Pose, b: Pose) -> Pose:
    """``a·b`` of rigid motions: (Ra·Rb, ta + Ra·tb)."""
    return a[0] @ b[0], a[1] + np.einsum("nij,nj->ni", a[0], b[1])


def chain_poses(
    model: str,
    u_mm: FloatArray,
    linear_um: Mapping[str, FloatArray],
    angular_urad: Mapping[str, FloatArray],
    squareness_urad: Mapping[str, float],
) -> tuple[Pose, Pose]:
    """``(pose_base_tool, pose_base_work)``: rigid motions (R, t mm) of the stylus carrier and
    of the workpiece carrier relative to the base.

    ``linear_um[a]`` (N, 3) is (δx, δy, δz) of axis a, ``angular_urad[a]`` (N, 3) its (εx, εy, εz),
    both at the points' positions of axis a; ``u_mm`` (N, 3) travels from the reference.
    """
    tool, work = MODEL_AXES[model]
    u = np.asarray(u_mm, dtype=float)
    n = u.shape[0]
    d = travel_directions(squareness_urad)
    identity: Pose = (np.broadcast_to(np.eye(3), (n, 3, 3)), np.zeros((n, 3)))
    poses = []
    for axes, sign in ((tool, 1.0), (work, -1.0)):
        pose = identity
        for a in axes:
            k = AXES.index(a)
            travel: Pose = (identity[0], sign * u[:, k : k + 1] * d[k])
            error: Pose = (rotation_matrices(angular_urad[a]), sign * linear_um[a] / 1000.0)
            pose = _compose(_compose(pose, travel), error)
        poses.append(pose)
    return poses[0], poses[1]


def tip_error_um(tool: Pose, work: Pose, u_mm: FloatArray, stylus_mm: FloatArray) -> FloatArray:
    """Error (N, 3) µm of the tip at stylus offset ``stylus_mm`` ((3,) or (N, 3), mm):
    ``p_work = R_wᵀ·(t_t + R_t·p − t_w)`` minus the nominal ``u + p``."""
    u = np.asarray(u_mm, dtype=float)
    p = np.broadcast_to(np.asarray(stylus_mm, dtype=float), u.shape)
    p_base = tool[1] + np.einsum("nij,nj->ni", tool[0], p)
    p_work = np.einsum("nji,nj->ni", work[0], p_base - work[1])
    return (p_work - (u + p)) * 1000.0


def rotation_vector_urad(rotation: FloatArray) -> FloatArray:
    """(N, 3) rotation vectors µrad of rotation matrices (N, 3, 3) (the log map, exact)."""
    r = np.asarray(rotation, dtype=float)
    axis = np.stack([r[:, 2, 1] - r[:, 1, 2], r[:, 0, 2] - r[:, 2, 0], r[:, 1, 0] - r[:, 0, 1]], 1)
    sin_angle = np.linalg.norm(axis, axis=1) / 2.0
    cos_angle = (np.trace(r, axis1=1, axis2=2) - 1.0) / 2.0
    angle = np.arctan2(sin_angle, cos_angle)
    # angle / sin(angle) → 1 as the angle vanishes
    factor = np.where(sin_angle > 1e-12, angle / np.maximum(sin_angle, 1e-300), 1.0)
    return axis / 2.0 * factor[:, None] * 1e6
