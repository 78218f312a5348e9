"""An analytic rigid-body error field that behaves like a :class:`~compensation.machine.Machine`.

Used as an independent oracle (tests, the interpolation study in ``docs/interpolation.md``,
the grid benchmark): its error rotation and translation are closed-form smooth functions of
position, so the exact value is known at every point, and its size is a parameter (tens of
µrad for a realistic machine, mrad for the exaggerated study).

It implements the part of the machine contract the grid uses: ``name``, ``model``,
``volume`` (``lower_mm``, ``upper_mm``, ``reference_mm``, ``steps``), ``runtime_signals()``,
``pose_error(points_mm, temps_C, inputs)``, ``volumetric_error(points_mm, stylus_mm, temps_C)``
and ``identity_sha256()``. Signals: ``T_x`` (scale expansion, exactly linear in translation)
and ``T_top`` (a bending that adds a rotation about y proportional to ``T_top − 20`` °C;
composed exactly, so linear only to first order).
"""

from __future__ import annotations

import hashlib
import json
from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from ..machine_parts import Volume
from . import quaternion as qt

__all__ = ["AnalyticErrorField", "AnalyticPose"]

FloatArray = NDArray[np.float64]


@dataclass(frozen=True)
class AnalyticPose:
    """Error pose: ``rotation`` (N, 3, 3) R_work_stylus and ``translation_um`` (N, 3)."""

    rotation: FloatArray
    translation_um: FloatArray


class AnalyticErrorField:
    """Smooth analytic error field over a box; rotation amplitude ``rotation_urad`` (µrad).

    ``waves`` sets how many half-waves the field has across the volume (grid density needed).
    """

    def __init__(
        self,
        lower_mm: ArrayLike = (0.0, 0.0, 0.0),
        upper_mm: ArrayLike = (900.0, 1150.0, 400.0),
        rotation_urad: float = 30.0,
        translation_um: float = 5.0,
        expansion_um_per_m_C: float = 10.5,
        bending_urad_per_C: float = 2.0,
        waves: float = 1.5,
        name: str = "analytic",
    ) -> None:
        lo = np.asarray(lower_mm, dtype=float)
        hi = np.asarray(upper_mm, dtype=float)
        self.name = name
        self.model = "analytic"
        self.volume = Volume(lo, hi, lo.copy(), (20, 20, 10))
        self.rotation_urad = float(rotation_urad)
        self.translation_um = float(translation_um)
        self.expansion = float(expansion_um_per_m_C)
        self.bending = float(bending_urad_per_C)
        self.waves = float(waves)
        self.reference_C = 20.0

    def identity_sha256(self) -> str:
        """SHA-256 of the parameters (stands in for the machine description's hash)."""
        blob = json.dumps(
            {
                "name": self.name,
                "lo": self.volume.lower_mm.tolist(),
                "hi": self.volume.upper_mm.tolist(),
                "rot": self.rotation_urad,
                "tr": self.translation_um,
                "exp": self.expansion,
                "bend": self.bending,
                "waves": self.waves,
            },
            sort_keys=True,
        )
        return hashlib.sha256(blob.encode()).hexdigest()

    def runtime_signals(self) -> dict[str, float]:
        """Signals and reference values: ``T_x`` and ``T_top``, both 20 °C."""
        return {"T_x": self.reference_C, "T_top": self.reference_C}

    def _unit(self, points_mm: FloatArray) -> FloatArray:
        lo, hi = self.volume.lower_mm, self.volume.upper_mm
        return (points_mm - lo) / (hi - lo)

    def rotvec_urad(self, points_mm: ArrayLike) -> FloatArray:
        """Geometric error rotation vector (N, 3) µrad at reference temperature."""
        u = self._unit(np.atleast_2d(np.asarray(points_mm, dtype=float)))
        a, b, c = (np.pi * self.waves * u[:, k] for k in range(3))
        rv = np.stack(
            [
                np.sin(a + 0.3) * np.cos(0.8 * b) + 0.4 * np.sin(c + 0.5 * a),
                np.cos(0.7 * a) * np.sin(c + 0.5) + 0.3 * np.cos(b - 0.2),
                np.sin(b + 0.2) * np.cos(0.6 * a + c) - 0.2,
            ],
            axis=-1,
        )
        return self.rotation_urad * rv

    def translation_at(self, points_mm: ArrayLike) -> FloatArray:
        """Geometric error translation (N, 3) µm at reference temperature."""
        u = self._unit(np.atleast_2d(np.asarray(points_mm, dtype=float)))
        a, b, c = (np.pi * self.waves * u[:, k] for k in range(3))
        tr = np.stack(
            [
                np.sin(a + 0.1) + 0.3 * np.sin(b) * np.cos(c),
                np.cos(b + 0.4) * np.sin(0.5 * a + 0.2) + 0.2 * c,
                np.sin(c + 0.3 * a) - 0.5 * np.cos(b),
            ],
            axis=-1,
        )
        return self.translation_um * tr

    def pose_error(
        self,
        points_mm: ArrayLike,
        temps_C: Mapping[str, Any] | None = None,
        inputs: Mapping[str, Any] | None = None,
    ) -> AnalyticPose:
        """Exact error pose at indicated points (N, 3) mm and the given temperatures."""
        p = np.atleast_2d(np.asarray(points_mm, dtype=float))
        n = p.shape[0]
        sig = {**dict(inputs or {}), **dict(temps_C or {})}

        def value(name: str) -> FloatArray:
            v = sig.get(name)
            return np.broadcast_to(np.asarray(self.reference_C if v is None else v, float), (n,))

        dt_x = value("T_x") - self.reference_C
        dt_top = value("T_top") - self.reference_C
        rv = self.rotvec_urad(p)
        u = self._unit(p)
        rv[:, 1] += self.bending * dt_top * (0.5 + u[:, 0])
        tr = self.translation_at(p)
        tr[:, 0] += self.expansion * dt_x * (p[:, 0] - self.volume.reference_mm[0]) / 1000.0
        rot = qt.matrix_from_quaternion(qt.quaternion_from_rotvec(rv * 1e-6))
        return AnalyticPose(rotation=rot, translation_um=tr)

    def volumetric_error(
        self,
        points_mm: ArrayLike,
        stylus_mm: ArrayLike = (0.0, 0.0, 0.0),
        temps_C: Mapping[str, Any] | None = None,
        *,
        inputs: Mapping[str, Any] | None = None,
    ) -> FloatArray:
        """Volumetric error (N, 3) µm = t + 1000·(R − I)·p for stylus offset p (mm)."""
        pose = self.pose_error(points_mm, temps_C, inputs)
        p = np.broadcast_to(np.asarray(stylus_mm, dtype=float), pose.translation_um.shape)
        return pose.translation_um + 1000.0 * np.einsum("nij,nj->ni", pose.rotation - np.eye(3), p)
