"""Exact rigid-body chain of a three-axis CMM, written apart from ``compensation/kinematics.py``.

Written from the contract only (docs/formats.md §1.2 for which axes carry the stylus and which the
workpiece, docs/conventions.md for frames and signs); the one place where this generator and the
project must meet is here: the *nominal* model (the 21 parametric errors through the chain) has
to agree, which ``tests/test_heldout_generator.py`` checks against ``Machine.volumetric_error``.

Method: full 4×4 homogeneous transforms (exact, no small-angle step), rotations built by scipy
(``Rotation.from_euler("XYZ", …)``, intrinsic, i.e. R = Rx·Ry·Rz), the workpiece side inverted
with ``numpy.linalg.inv``.

* Positions from the reference point ``u = q − reference`` (mm); linear errors µm, angles µrad.
* Tool side (base → stylus): ``T_base_stylus = Π_k Tr(u_k·d_k)·E_k``, ``E_k = (R(ε_k), δ_k)``.
* Workpiece side (base → workpiece): ``T_base_work = Π_k Tr(−u_k·d_k)·E'_k``, ``E'_k = (R(ε_k), −δ_k)``
  (a table's linear errors are those of the relative motion, its angles its own rotations).
* Squareness tilts the nominal travel: X along Rz(−α)·e_x, Z along Ry(−β1)·Rx(β2)·e_z.
* Error = p_work − (u + p), true − indicated.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray
from scipy.spatial.transform import Rotation

FloatArray = NDArray[np.float64]

AXES = ("x", "y", "z")

#: Tool axes (base → stylus) and workpiece axes (base → table) of the ten models,
#: copied by hand from the table of docs/formats.md §1.2.
MODEL_AXES: dict[str, tuple[tuple[str, ...], tuple[str, ...]]] = {
    "MB1": (("y", "x", "z"), ()),
    "MB2": (("x", "y", "z"), ()),
    "FB1": (("x", "z"), ("y",)),
    "FB2": (("y", "z"), ("x",)),
    "MH1": (("y", "z", "x"), ()),
    "MH2": (("x", "z", "y"), ()),
    "FH1": (("y", "z"), ("x",)),
    "FH2": (("x", "z"), ("y",)),
    "CX1": (("z",), ("x", "y")),
    "CY1": (("z",), ("y", "x")),
}

#: The 18 tables in (axis, slot) order: slot 0..2 linear δx δy δz (µm), 3..5 angular εx εy εz (µrad).
TABLE_NAMES: tuple[str, ...] = tuple(
    f"{kind}{direction}_{axis}" for axis in AXES for kind in ("d", "e") for direction in AXES
)


def table_slot(name: str) -> tuple[int, int]:
    """``"ey_x"`` → (axis index 0, slot 4)."""
    kind, direction, axis = name[0], name[1], name[3]
    return AXES.index(axis), (3 if kind == "e" else 0) + AXES.index(direction)


def _homogeneous(rotation: FloatArray, translation_mm: FloatArray) -> FloatArray:
    n = translation_mm.shape[0]
    out = np.zeros((n, 4, 4))
    out[:, :3, :3] = rotation
    out[:, :3, 3] = translation_mm
    out[:, 3, 3] = 1.0
    return out


def _translation(v_mm: FloatArray) -> FloatArray:
    return _homogeneous(np.broadcast_to(np.eye(3), (v_mm.shape[0], 3, 3)), v_mm)


def travel_directions(squareness_urad: FloatArray) -> FloatArray:
    """(N, 3 axes, 3) unit directions of travel for squareness (α, β1, β2) µrad."""
    sq = np.asarray(squareness_urad, dtype=float) * 1e-6
    n = sq.shape[0]
    e = np.eye(3)
    d = np.empty((n, 3, 3))
    d[:, 0] = Rotation.from_rotvec(np.outer(-sq[:, 0], e[2])).apply(e[0])
    d[:, 1] = e[1]
    rz = Rotation.from_rotvec(np.outer(-sq[:, 1], e[1])) * Rotation.from_rotvec(
        np.outer(sq[:, 2], e[0])
    )
    d[:, 2] = rz.apply(e[2])
    return d


def stylus_error_um(
    model: str,
    u_mm: FloatArray,
    stylus_mm: FloatArray,
    errors: FloatArray,
    squareness_urad: FloatArray,
) -> FloatArray:
    """Exact volumetric error (N, 3) µm of the stylus tip relative to the workpiece.

    ``u_mm`` (N, 3) positions from the reference; ``stylus_mm`` (N, 3); ``errors`` (N, 3 axes, 6)
    (δ µm, ε µrad); ``squareness_urad`` (N, 3).
    """
    tool, work = MODEL_AXES[model]
    n = u_mm.shape[0]
    d = travel_directions(squareness_urad)
    t_base_stylus = np.broadcast_to(np.eye(4), (n, 4, 4)).copy()
    for axis in tool:
        k = AXES.index(axis)
        e_k = _homogeneous(
            Rotation.from_euler("XYZ", errors[:, k, 3:] * 1e-6).as_matrix(), errors[:, k, :3] / 1e3
        )
        t_base_stylus = t_base_stylus @ _translation(u_mm[:, k : k + 1] * d[:, k]) @ e_k
    t_base_work = np.broadcast_to(np.eye(4), (n, 4, 4)).copy()
    for axis in work:
        k = AXES.index(axis)
        e_k = _homogeneous(
            Rotation.from_euler("XYZ", errors[:, k, 3:] * 1e-6).as_matrix(), -errors[:, k, :3] / 1e3
        )
        t_base_work = t_base_work @ _translation(-u_mm[:, k : k + 1] * d[:, k]) @ e_k
    p_h = np.concatenate([stylus_mm, np.ones((n, 1))], axis=1)
    p_base = np.einsum("nij,nj->ni", t_base_stylus, p_h)
    p_work = np.einsum("nij,nj->ni", np.linalg.inv(t_base_work), p_base)[:, :3]
    return (p_work - (u_mm + stylus_mm)) * 1e3
