"""The seed paper's 6-DOF capture (Hermann §5, Fig. 7): a node's error pose from six readings.

Geometry (the layout of Fig. 7, signs by the right-hand rule). The moving body carries an
artefact with three flat, mutually perpendicular faces; at zero error their outward normals
are the machine axes ``e_z`` (face Z), ``e_x`` (face X) and ``e_y`` (face Y). Fixed sensors
measure each face's displacement along its nominal normal, at nominal contact points:

* three interferometer beams along ``e_z`` on face Z at ``P1``, ``P2 = P1 + d1·e_x``,
  ``P3 = P1 + d2·e_y`` (readings m1, m2, m3);
* two capacitive sensors along ``e_x`` on face X at ``P4``, ``P5 = P4 + d3·e_y`` (m4, m5);
* one capacitive sensor along ``e_y`` on face Y at ``P6`` (m6).

Reading ``m_i`` (µm, positive along the normal) is where sensor line ``P_i + λ e`` meets the
displaced face, so the six measured points ``X_i = P_i + m_i e`` lie on the displaced faces.
The pose moves a body point ``X`` to ``O + R (X − O) + t`` about a reference point ``O``
(``origin_mm``: the probe reference point, so that ``t`` is the grid's translation at stylus
offset 0 and ``error(p) = t + 1000 (R − I) p``).

Exact inverse (no small-angle approximation), the paper's three plane determinants:

1. face Z passes through X1, X2, X3: ``n_z = (X2 − X1) × (X3 − X1) / ‖…‖``;
2. face X contains X4, X5 and is perpendicular to face Z: ``n_x = (X5 − X4) × n_z / ‖…‖``;
3. face Y is perpendicular to both: ``n_y = n_z × n_x``.

The face normals are the rotated axes, so ``R = [n_x n_y n_z]`` (columns), orthonormal by
construction. Each displaced face k passes through ``O + R (P − O) + t`` for its nominal
points P, hence ``n_k · t = n_k · (X_i − O) − e_k · (P_i − O)`` (using ``n_k · R v = e_k · v``):
three equations ``Rᵀ t = b``, i.e. ``t = R b``.

First order (the paper's "tg θ ≈ θ"): ``ω_x = (m3 − m1)/d2``, ``ω_y = −(m2 − m1)/d1``,
``ω_z = −(m5 − m4)/d3`` (rotation vector, rad) — available as :func:`pose_first_order`, for
comparison; it differs from the exact pose by terms of second order in the angles.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field

import numpy as np
from numpy.typing import ArrayLike, NDArray

from cmm_comp.compensation.grid import CorrectionGrid
from cmm_comp.compensation.grid import quaternion as qt

__all__ = [
    "SixDofLayout",
    "grid_from_readings",
    "pose_first_order",
    "pose_from_readings",
    "readings_from_pose",
]

FloatArray = NDArray[np.float64]
_E = np.eye(3)
_FACE_OF_SENSOR = (2, 2, 2, 0, 0, 1)  # sensor i measures along e_z, e_z, e_z, e_x, e_x, e_y


@dataclass(frozen=True)
class SixDofLayout:
    """Sensor layout: beam/sensor spacings d1, d2, d3 (mm) and nominal contact points (mm).

    ``p1_mm``: beam 1 on face Z; ``p4_mm``: sensor 4 on face X; ``p6_mm``: sensor 6 on face Y;
    ``origin_mm``: the point the pose refers to (probe reference point), all in the machine
    frame at the node's indicated position.
    """

    d1_mm: float = 50.0
    d2_mm: float = 50.0
    d3_mm: float = 50.0
    p1_mm: FloatArray = field(default_factory=lambda: np.array([0.0, 0.0, 60.0]))
    p4_mm: FloatArray = field(default_factory=lambda: np.array([60.0, 0.0, 0.0]))
    p6_mm: FloatArray = field(default_factory=lambda: np.array([0.0, 60.0, 0.0]))
    origin_mm: FloatArray = field(default_factory=lambda: np.zeros(3))

    def __post_init__(self) -> None:
        for name in ("d1_mm", "d2_mm", "d3_mm"):
            if not getattr(self, name) > 0:
                raise ValueError(f"{name} must be > 0 mm, got {getattr(self, name)!r}")

    def points_mm(self) -> FloatArray:
        """Nominal contact points (6, 3) mm of sensors 1…6."""
        p1 = np.asarray(self.p1_mm, float)
        p4 = np.asarray(self.p4_mm, float)
        return np.array(
            [
                p1,
                p1 + self.d1_mm * _E[0],
                p1 + self.d2_mm * _E[1],
                p4,
                p4 + self.d3_mm * _E[1],
                np.asarray(self.p6_mm, float),
            ]
        )

    def directions(self) -> FloatArray:
        """Measuring directions (6, 3) = nominal outward normals of the faces they touch."""
        return _E[list(_FACE_OF_SENSOR)]


def readings_from_pose(
    layout: SixDofLayout, rotation: ArrayLike, translation_um: ArrayLike
) -> FloatArray:
    """Exact sensor readings (N, 6) µm of poses ``rotation`` (N, 3, 3), ``translation_um`` (N, 3).

    Simulation of the instrument (the oracle for :func:`pose_from_readings`): the distance
    along each sensor line from the nominal to the displaced face.
    """
    rot = np.asarray(rotation, float).reshape(-1, 3, 3)
    t_mm = np.asarray(translation_um, float).reshape(-1, 3) / 1000.0
    origin = np.asarray(layout.origin_mm, float)
    pts = layout.points_mm()
    dirs = layout.directions()
    out = np.empty((rot.shape[0], 6))
    for i in range(6):
        n = rot @ dirs[i]  # displaced face normal (N, 3)
        on_face = origin + np.einsum("nij,j->ni", rot, pts[i] - origin) + t_mm
        out[:, i] = np.sum(n * (on_face - pts[i]), axis=1) / (n @ dirs[i])
    return out * 1000.0


def pose_from_readings(
    layout: SixDofLayout, readings_um: ArrayLike
) -> tuple[FloatArray, FloatArray]:
    """Exact pose from six readings (N, 6) µm: ``(rotation (N, 3, 3), translation_um (N, 3))``."""
    m_mm = np.asarray(readings_um, float).reshape(-1, 6) / 1000.0
    if not np.all(np.isfinite(m_mm)):
        raise ValueError("six-DOF readings must be finite")
    pts = layout.points_mm()
    dirs = layout.directions()
    x = pts[None] + m_mm[:, :, None] * dirs[None]  # measured points (N, 6, 3)
    n_z = np.cross(x[:, 1] - x[:, 0], x[:, 2] - x[:, 0])
    n_z /= np.linalg.norm(n_z, axis=1, keepdims=True)
    n_x = np.cross(x[:, 4] - x[:, 3], n_z)
    n_x /= np.linalg.norm(n_x, axis=1, keepdims=True)
    n_y = np.cross(n_z, n_x)
    rot = np.stack([n_x, n_y, n_z], axis=-1)  # columns: R e_x, R e_y, R e_z
    origin = np.asarray(layout.origin_mm, float)
    b = np.stack(
        [
            np.sum(n_x * (x[:, 3] - origin), axis=1) - (pts[3] - origin)[0],
            np.sum(n_y * (x[:, 5] - origin), axis=1) - (pts[5] - origin)[1],
            np.sum(n_z * (x[:, 0] - origin), axis=1) - (pts[0] - origin)[2],
        ],
        axis=-1,
    )
    t_mm = np.einsum("nij,nj->ni", rot, b)
    return rot, t_mm * 1000.0


def pose_first_order(layout: SixDofLayout, readings_um: ArrayLike) -> tuple[FloatArray, FloatArray]:
    """The small-angle reading of the same six values: ``(rotvec_urad (N, 3), translation_um)``."""
    m = np.asarray(readings_um, float).reshape(-1, 6)
    w = np.stack(
        [
            (m[:, 2] - m[:, 0]) / layout.d2_mm,
            -(m[:, 1] - m[:, 0]) / layout.d1_mm,
            -(m[:, 4] - m[:, 3]) / layout.d3_mm,
        ],
        axis=-1,
    )  # µm/mm = mrad → ×1000 µrad
    w_rad = w * 1e-3
    origin = np.asarray(layout.origin_mm, float)
    pts = layout.points_mm()
    t = np.empty_like(w)
    for i, axis in ((3, 0), (5, 1), (0, 2)):
        t[:, axis] = m[:, i] - 1000.0 * np.cross(w_rad, pts[i] - origin)[:, axis]
    return w_rad * 1e6, t


def grid_from_readings(
    axes_mm: Sequence[ArrayLike],
    readings_um: ArrayLike,
    layout: SixDofLayout,
    **kwargs: object,
) -> CorrectionGrid:
    """A :class:`CorrectionGrid` from 6-DOF captures at every node.

    ``readings_um`` (nx, ny, nz, 6); the layout's ``origin_mm`` must be the probe reference
    point (relative to the node). Extra keyword arguments go to
    :meth:`CorrectionGrid.from_poses` (``machine_name``, ``machine_model``, …).
    """
    r = np.asarray(readings_um, float)
    shape = r.shape[:3]
    rot, t_um = pose_from_readings(layout, r.reshape(-1, 6))
    q = qt.quaternion_from_matrix(rot).reshape(*shape, 4)
    return CorrectionGrid.from_poses(axes_mm, q, t_um.reshape(*shape, 3), **kwargs)  # type: ignore[arg-type]
