"""Observation model of laser interferometer runs (docs/formats.md §10.2), with the project's
exact chain (:class:`.model.MachineModel`):

* ``linear_um``: the moving axis' component of the volumetric error at the optic (a stylus
  offset) on the line; a run's zero is unknown (its constant is removed from data and model);
  each run's scale κ (ppm, the air-refraction compensation's error) is a nuisance parameter with
  the prior N(0, ``u_scale_ppm``²): the reading is the error plus κ·10⁻³·position µm. One run per
  axis cannot tell κ from the axis' own scale error, so that scale keeps κ's uncertainty;
* ``straightness_<d>_um``: the d component at the optic; each pass' least-squares line removed;
* ``pitch/yaw/roll_urad``: the carriage's own angular error as the optic on it sees it, with the
  sign of its ``eI_J`` table (the contract): on a tool axis the component about the mapped axis
  of the rotation vector of ``R_work_stylus``, on a table axis its negative (the workpiece
  frame turns by ``R_work``, so ``R_work_stylus`` turns by its inverse; the tool side is fixed
  during the run, so the difference is second order in the angles); a run's constant removed;
* ``squareness_urad``: the angle between the least-squares lines through the optic's true paths
  along the two axes through the crossing point (each over the axis' travel in the plan's
  volume, :data:`SQUARENESS_SAMPLES` points), minus 90°, positive when it exceeds 90°.

Residual = model − data (µm, µrad).
"""

from __future__ import annotations

from typing import Any

import numpy as np
from numpy.typing import NDArray

from ..parametric_errors import AXES
from .laser import LaserData, LaserRun
from .model import MachineModel, PointSet
from .observation import Block, Linearization, Projection, VarianceGroup, project

__all__ = ["SQUARENESS_SAMPLES", "LaserBlock"]

FloatArray = NDArray[np.float64]
SQUARENESS_SAMPLES = 101
_QUANTITY_GROUPS = {
    "linear": ("linear_um", "um", "u_linear_um"),
    "straightness": ("straightness_um", "um", "u_straightness_um"),
    "angle": ("angle_urad", "urad", "u_angle_urad"),
    "squareness": ("squareness_urad", "urad", "u_squareness_urad"),
}


class LaserBlock(Block):
    """All runs of one ``[[laser]]`` entry."""

    def __init__(self, data: LaserData, dataset: int, model: MachineModel) -> None:
        super().__init__(kind="laser", dataset=dataset, source=data.source)
        self.data = data
        runs = data.runs
        # one variance group per kind of reading, the angles one per quantity: a roll is read
        # by other means (a level, a straightness pair) than pitch and yaw (angular optics) and
        # is less precise; one σ for all three would make the U of the pitches too large and
        # of the rolls too small
        kinds = sorted({_group_key(r) for r in runs}, key=_group_order)
        self.variance_groups = [
            VarianceGroup(
                dataset,
                k if _kind(k) == "angle" else _QUANTITY_GROUPS[k][0],
                _QUANTITY_GROUPS[_kind(k)][1],
                float(data.spec.u[_QUANTITY_GROUPS[_kind(k)][2]]),
            )
            for k in kinds
        ]
        self.row_runs = [r for r in runs if r.kind != "squareness"]
        self.square_runs = [r for r in runs if r.kind == "squareness"]
        self.value = np.concatenate(
            [r.value for r in self.row_runs] + [r.value for r in self.square_runs]
        )
        groups: list[NDArray[np.intp]] = []
        lines: list[int] = []
        projections: list[Projection] = []
        start = 0
        for r in self.row_runs:
            groups.append(np.full(r.n, kinds.index(_group_key(r)), dtype=np.intp))
            lines.extend(r.lines)
            if r.kind == "straightness":
                for p in r.passes:
                    pos = r.position_mm[p]
                    design = np.column_stack([np.ones(len(p)), pos - pos.mean()])
                    projections.append(Projection(rows=start + p, design=design))
            else:
                projections.append(
                    Projection(rows=start + np.arange(r.n), design=np.ones((r.n, 1)))
                )
            start += r.n
        for r in self.square_runs:
            groups.append(np.full(r.n, kinds.index("squareness"), dtype=np.intp))
            lines.extend(r.lines)
        self.groups = np.concatenate(groups) if groups else np.zeros(0, dtype=np.intp)
        self.lines = tuple(lines)
        self.projections = projections
        self.scale_rows = [
            (start_i, r)
            for start_i, r in zip(
                np.cumsum([0] + [r.n for r in self.row_runs])[:-1], self.row_runs, strict=True
            )
            if r.kind == "linear"
        ]
        self.u_scale_ppm = float(data.spec.u["u_scale_ppm"])
        self._rows = self._row_points(model)
        self._square = [self._square_points(model, r) for r in self.square_runs]
        self._jac: FloatArray | None = None

    # ---------------------------------------------------------------- geometry (fixed)
    def _row_points(self, model: MachineModel) -> tuple[PointSet, FloatArray, FloatArray] | None:
        if not self.row_runs:
            return None
        q = np.concatenate([r.points_mm for r in self.row_runs])
        optic = np.concatenate([np.repeat(r.optic_mm[None], r.n, 0) for r in self.row_runs])
        direction = np.zeros_like(q)
        start = 0
        for r in self.row_runs:
            direction[start : start + r.n, r.axis] = r.direction
            start += r.n
        temps = _temps(self.row_runs)
        pts = model.points(q, optic, direction, temps)
        comp = np.concatenate([np.full(r.n, r.component) for r in self.row_runs])
        # an angle row reads +1 × the rotation of R_work_stylus on a tool axis, −1 on a table
        sign = np.concatenate(
            [
                np.full(r.n, -1.0 if AXES[r.axis] in model.chain.workpiece else 1.0)
                for r in self.row_runs
            ]
        )
        is_angle = np.concatenate([np.full(r.n, r.kind == "angle") for r in self.row_runs])
        return pts, comp.astype(np.intp), np.where(is_angle, sign, 0.0)

    def _square_points(
        self, model: MachineModel, run: LaserRun
    ) -> list[tuple[PointSet, FloatArray]]:
        """Per squareness row: the sampled points of both lines and the slope weights."""
        lower, upper = model.layout.lower_mm, model.layout.upper_mm
        out = []
        for i in range(run.n):
            c = run.points_mm[i]
            pts_list = []
            for axis in (run.axis, run.component):
                s = np.linspace(lower[axis], upper[axis], SQUARENESS_SAMPLES)
                q = np.repeat(c[None], SQUARENESS_SAMPLES, 0)
                q[:, axis] = s
                pts_list.append(q)
            q_all = np.concatenate(pts_list)
            pts = model.points(q_all, run.optic_mm)
            weights = []
            for q, axis in zip(pts_list, (run.axis, run.component), strict=True):
                s = q[:, axis] - q[:, axis].mean()
                weights.append(s / (s @ s))  # least-squares slope = weights @ values
            out.append((pts, np.stack(weights)))
        return out

    # ---------------------------------------------------------------- model
    def predict(self, model: MachineModel, theta: FloatArray) -> FloatArray:
        """The model's readings (before removing a run's constant / a pass' line)."""
        parts = []
        if self._rows is not None:
            pts, comp, angle_sign = self._rows
            err, rot = model.exact(theta, pts)
            n = np.arange(comp.shape[0])
            parts.append(np.where(angle_sign != 0, angle_sign * rot[n, comp], err[n, comp]))
        for run, samples in zip(self.square_runs, self._square, strict=True):
            vals = [self._squareness_exact(model, theta, run, pts) for pts, _ in samples]
            parts.append(np.asarray(vals))
        return np.concatenate(parts) if parts else np.zeros(0)

    @staticmethod
    def _squareness_exact(
        model: MachineModel, theta: FloatArray, run: LaserRun, pts: PointSet
    ) -> float:
        err, _ = model.exact(theta, pts)
        true = pts.q_mm + err / 1000.0
        k = SQUARENESS_SAMPLES
        dirs = []
        for part, axis in ((slice(0, k), run.axis), (slice(k, 2 * k), run.component)):
            s = pts.q_mm[part, axis]
            sc = s - s.mean()
            d = (sc @ (true[part] - true[part].mean(axis=0))) / (sc @ sc)
            dirs.append(d / np.linalg.norm(d))
        cosang = float(np.clip(dirs[0] @ dirs[1], -1.0, 1.0))
        return (np.arccos(cosang) - np.pi / 2.0) * 1e6

    def jacobian(self, model: MachineModel) -> FloatArray:
        """(n, P) first-order derivative of the readings (constant in θ: computed once)."""
        if self._jac is not None:
            return self._jac
        parts = []
        if self._rows is not None:
            pts, comp, angle_sign = self._rows
            n = np.arange(comp.shape[0])
            dE = model.error_jacobian(pts)[n, comp]
            dW = model.rotation_jacobian(pts)[n, comp]
            parts.append(np.where(angle_sign[:, None] != 0, angle_sign[:, None] * dW, dE))
        for run, samples in zip(self.square_runs, self._square, strict=True):
            rows = []
            k = SQUARENESS_SAMPLES
            for pts, w in samples:
                d = model.error_jacobian(pts)
                slope_ab = w[0] @ d[:k, run.component, :]
                slope_ba = w[1] @ d[k:, run.axis, :]
                rows.append(-1e3 * (slope_ab + slope_ba))
            parts.append(np.asarray(rows).reshape(run.n, -1))
        self._jac = np.concatenate(parts) if parts else np.zeros((0, model.layout.n))
        return self._jac

    @property
    def n_nuisance(self) -> int:
        return len(self.scale_rows)

    def nuisance_precision(self) -> FloatArray:
        return np.full(self.n_nuisance, 1.0 / self.u_scale_ppm**2)

    def initial_state(self, model: MachineModel, theta: FloatArray) -> FloatArray:
        return np.zeros(self.n_nuisance)  # the linear runs' scales, ppm

    def advance(self, state: Any, delta: FloatArray) -> FloatArray:
        return np.asarray(state) + delta

    def _scale_jacobian(self) -> FloatArray:
        """(rows, runs) µm per ppm of each linear run's scale."""
        out = np.zeros((self.value.shape[0], self.n_nuisance))
        for j, (start, r) in enumerate(self.scale_rows):
            out[start : start + r.n, j] = 1e-3 * r.position_mm
        return out

    def linearize(self, model: MachineModel, theta: FloatArray, state: Any) -> Linearization:
        scale = self._scale_jacobian()
        model_values = self.predict(model, theta) + scale @ np.asarray(state)
        resid = project(model_values - self.value, self.projections)
        jac = project(self.jacobian(model), self.projections)
        return Linearization(resid, jac, project(scale, self.projections))

    def describe_state(self, state: Any, covariance: FloatArray | None) -> dict[str, Any]:
        if not self.n_nuisance:
            return {}
        sd = np.sqrt(np.diag(covariance)) if covariance is not None else None
        return {
            "run_scale_ppm": {
                r.run: {
                    "value": float(state[j]),
                    "u": None if sd is None else float(sd[j]),
                    "prior_u": self.u_scale_ppm,
                }
                for j, (_, r) in enumerate(self.scale_rows)
            }
        }

    def removed_dof(self) -> FloatArray:
        """(groups,) rows' degrees of freedom taken by the removed constants and lines."""
        out = np.zeros(len(self.variance_groups))
        for p in self.projections:
            out[self.groups[p.rows[0]]] += p.design.shape[1]
        return out


def _group_key(run: LaserRun) -> str:
    """The variance group of a run: its kind, an angle's quantity (``roll_urad`` …)."""
    return run.quantity if run.kind == "angle" else run.kind


def _kind(key: str) -> str:
    return key if key in _QUANTITY_GROUPS else "angle"


def _group_order(key: str) -> tuple[int, str]:
    return list(_QUANTITY_GROUPS).index(_kind(key)), key


def _temps(runs: list[LaserRun]) -> dict[str, FloatArray] | None:
    names = set().union(*(r.temps_C.keys() for r in runs))
    if not names:
        return None
    out = {}
    for t in names:
        out[t] = np.concatenate([r.temps_C.get(t, np.full(r.n, np.nan)) for r in runs])
    return out
