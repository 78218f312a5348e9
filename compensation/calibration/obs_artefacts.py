"""Observation models of a ball plate and of sequential multilateration (docs/formats.md §10.3,
§10.4), with the project's exact chain (:class:`.model.MachineModel`).

Plate: the true stylus tip at the indicated centre q, ``q + e(q)/1000``, is the calibrated
ball b (plus its calibration error c, µm, prior N(0, u²)) placed by the placement's unknown
pose: ``R·(b + c/1000) + t``. Residual ``1000·(q − R·b' − t) + e(q)`` µm per coordinate.
Nuisance per placement: a small rotation (µrad, composed onto R) and a translation (µm).

Multilateration: ``length = |p − s| + d`` with p the reflector's true position, s the station
(mm) and d its dead path. Residual ``1000·(|p − s| + d − length)`` µm. Nuisance per station:
its position (µm) and dead path (µm); per point measured from several stations a random offset
c (µm, prior N(0, σ_point²), σ_point estimated): what the machine's state at that stop adds for
every station alike (its reversal after the program's last moves, a settling error) is one
error shared by all the stations' lengths, not independent noise — taken as noise it would
overstate what the lengths say about θ.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import NDArray

from .model import MachineModel
from .multilateration import MultilaterationData
from .observation import (
    Block,
    Linearization,
    VarianceGroup,
    kabsch,
    rotation_from_vector,
    skew,
)
from .plate import PlateData

__all__ = ["MultilaterationBlock", "PlateBlock", "PlateState", "StationState"]

FloatArray = NDArray[np.float64]
MIN_BALL_U_UM = 1e-4  # a ball "known exactly" still gets a (tiny) prior, so the maths stays finite


@dataclass(frozen=True)
class PlateState:
    """Poses (R (K, 3, 3), t (K, 3) mm) of the K placements and ball corrections (B, 3) µm."""

    rotation: FloatArray
    translation_mm: FloatArray
    ball_um: FloatArray


class PlateBlock(Block):
    """The measured centres of one ``[[plate]]`` entry."""

    def __init__(self, data: PlateData, dataset: int, model: MachineModel) -> None:
        super().__init__(kind="plate", dataset=dataset, source=data.source)
        self.data = data
        self.variance_groups = [VarianceGroup(dataset, "probing_um", "um", data.spec.probe_um)]
        self.groups = np.zeros(3 * data.n, dtype=np.intp)
        self.lines = tuple(line for line in data.lines for _ in range(3))
        self.pts = model.points(data.q_mm, data.spec.stylus_mm, None, data.temps_C or None)
        self.k = len(data.placements)
        self.b = len(data.ball_ids)
        self._jac: FloatArray | None = None

    @property
    def n_nuisance(self) -> int:
        return 6 * self.k + 3 * self.b

    def nuisance_precision(self) -> FloatArray:
        u = np.maximum(self.data.ball_u_um, MIN_BALL_U_UM)
        return np.concatenate([np.zeros(6 * self.k), np.repeat(1.0 / u**2, 3)])

    def initial_state(self, model: MachineModel, theta: FloatArray) -> PlateState:
        d = self.data
        err, _ = model.exact(theta, self.pts)
        true = d.q_mm + err / 1000.0
        rot = np.empty((self.k, 3, 3))
        trans = np.empty((self.k, 3))
        for k in range(self.k):
            rows = d.placement == k
            rot[k], trans[k] = kabsch(d.ball_mm[d.ball[rows]], true[rows])
        return PlateState(rot, trans, np.zeros((self.b, 3)))

    def linearize(self, model: MachineModel, theta: FloatArray, state: Any) -> Linearization:
        d = self.data
        st: PlateState = state
        err, _ = model.exact(theta, self.pts)
        rot = st.rotation[d.placement]  # (N, 3, 3)
        ball = d.ball_mm[d.ball] + st.ball_um[d.ball] / 1000.0
        placed = np.einsum("nij,nj->ni", rot, ball)
        resid = 1000.0 * (d.q_mm - placed - st.translation_mm[d.placement]) + err
        if self._jac is None:
            self._jac = model.error_jacobian(self.pts).reshape(3 * d.n, -1)
        n = d.n
        jn = np.zeros((n, 3, self.n_nuisance))
        for k in range(self.k):
            rows = np.flatnonzero(d.placement == k)
            jn[rows, :, 6 * k : 6 * k + 3] = 1e-3 * skew(placed[rows])
            jn[rows, :, 6 * k + 3 : 6 * k + 6] = -np.eye(3)
        for j in range(self.b):
            rows = np.flatnonzero(d.ball == j)
            c0 = 6 * self.k + 3 * j
            jn[rows, :, c0 : c0 + 3] = -rot[rows]
        return Linearization(resid.reshape(-1), self._jac, jn.reshape(3 * n, -1))

    def advance(self, state: Any, delta: FloatArray) -> PlateState:
        st: PlateState = state
        rot = st.rotation.copy()
        trans = st.translation_mm.copy()
        for k in range(self.k):
            rot[k] = rotation_from_vector(delta[6 * k : 6 * k + 3] * 1e-6) @ rot[k]
            trans[k] = trans[k] + delta[6 * k + 3 : 6 * k + 6] / 1000.0
        ball = st.ball_um + delta[6 * self.k :].reshape(self.b, 3)
        return PlateState(rot, trans, ball)

    def describe_state(self, state: Any, covariance: FloatArray | None) -> dict[str, Any]:
        st: PlateState = state
        sd = np.sqrt(np.diag(covariance)) if covariance is not None else None
        out = []
        for k, name in enumerate(self.data.placements):
            entry: dict[str, Any] = {
                "placement": name,
                "rotation_matrix": st.rotation[k].tolist(),
                "translation_mm": st.translation_mm[k].tolist(),
            }
            if sd is not None:
                entry["u_rotation_urad"] = sd[6 * k : 6 * k + 3].tolist()
                entry["u_translation_um"] = sd[6 * k + 3 : 6 * k + 6].tolist()
            out.append(entry)
        return {"placements": out, "ball_corrections_um": st.ball_um.tolist()}


@dataclass(frozen=True)
class StationState:
    """Station centres (S, 3) mm, dead paths (S,) mm and the shared points' offsets (P, 3) µm."""

    position_mm: FloatArray
    dead_path_mm: FloatArray
    point_um: FloatArray


class MultilaterationBlock(Block):
    """The lengths of one ``[[multilateration]]`` entry."""

    def __init__(self, data: MultilaterationData, dataset: int, model: MachineModel) -> None:
        super().__init__(kind="multilateration", dataset=dataset, source=data.source)
        self.data = data
        self.variance_groups = [VarianceGroup(dataset, "length_um", "um", data.spec.u_um)]
        self.groups = np.zeros(data.n, dtype=np.intp)
        self.lines = data.lines
        # each axis' last direction of travel (the reversal) from the program's order
        direction = data.direction if data.direction.shape == data.q_mm.shape else None
        self.pts = model.points(data.q_mm, data.spec.stylus_mm, direction, data.temps_C or None)
        self.s = len(data.stations)
        self.np = data.n_points
        self._jac: FloatArray | None = None

    @property
    def n_nuisance(self) -> int:
        return 4 * self.s + 3 * self.np

    def random_effects(self) -> list[tuple[NDArray[np.intp], str, float]]:
        # one σ per machine axis: the offsets are mostly each axis' reversal at that stop,
        # which differs from axis to axis (a pooled σ would shrink the largest too far)
        if not self.np:
            return []
        first = 4 * self.s + 3 * np.arange(self.np)
        return [(first + c, f"point_{a}_um", self.data.spec.u_um) for c, a in enumerate("xyz")]

    def local_nuisance(self) -> NDArray[np.intp]:
        return 4 * self.s + np.arange(3 * self.np, dtype=np.intp)  # each row: one point

    def initial_state(self, model: MachineModel, theta: FloatArray) -> StationState:
        d = self.data
        pos = np.asarray(d.spec.station_guess_mm, dtype=float).copy()
        dead = np.zeros(self.s)
        for k in range(self.s):
            rows = d.station == k
            dead[k] = float(
                np.median(d.length_mm[rows] - np.linalg.norm(d.q_mm[rows] - pos[k], axis=1))
            )
        return StationState(pos, dead, np.zeros((self.np, 3)))

    def linearize(self, model: MachineModel, theta: FloatArray, state: Any) -> Linearization:
        d = self.data
        st: StationState = state
        err, _ = model.exact(theta, self.pts)
        p = d.q_mm + err / 1000.0
        diff = p - st.position_mm[d.station]
        dist = np.linalg.norm(diff, axis=1)
        unit = diff / dist[:, None]
        resid = 1000.0 * (dist + st.dead_path_mm[d.station] - d.length_mm)
        if self._jac is None:
            self._jac = model.error_jacobian(self.pts)
        jm = np.einsum("ni,nip->np", unit, self._jac)
        jn = np.zeros((d.n, self.n_nuisance))
        rows = np.arange(d.n)
        for i in range(3):
            jn[rows, 4 * d.station + i] = -unit[:, i]
        jn[rows, 4 * d.station + 3] = 1.0
        shared = np.flatnonzero(d.point >= 0)
        if shared.size:
            resid[shared] += np.einsum("ni,ni->n", unit[shared], st.point_um[d.point[shared]])
            for i in range(3):
                jn[shared, 4 * self.s + 3 * d.point[shared] + i] = unit[shared, i]
        return Linearization(resid, jm, jn)

    def advance(self, state: Any, delta: FloatArray) -> StationState:
        st: StationState = state
        step = delta[: 4 * self.s].reshape(self.s, 4) / 1000.0
        point = st.point_um + delta[4 * self.s :].reshape(self.np, 3)
        return StationState(st.position_mm + step[:, :3], st.dead_path_mm + step[:, 3], point)

    def describe_state(self, state: Any, covariance: FloatArray | None) -> dict[str, Any]:
        st: StationState = state
        sd = np.sqrt(np.diag(covariance)) if covariance is not None else None
        out = []
        for k, name in enumerate(self.data.stations):
            entry: dict[str, Any] = {
                "station": name,
                "position_mm": st.position_mm[k].tolist(),
                "guess_mm": self.data.spec.station_guess_mm[k].tolist(),
                "dead_path_mm": float(st.dead_path_mm[k]),
            }
            if sd is not None:
                entry["u_position_um"] = sd[4 * k : 4 * k + 3].tolist()
                entry["u_dead_path_um"] = float(sd[4 * k + 3])
            out.append(entry)
        return {"stations": out, "point_offsets_rms_um": _rms3(st.point_um)}


def _rms3(values: FloatArray) -> float | None:
    return float(np.sqrt(np.mean(values**2))) if values.size else None
