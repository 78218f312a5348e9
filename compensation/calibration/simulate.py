"""Readings a machine would give for a plan's data sets, through the public machine API
(:meth:`Machine.volumetric_error`, :meth:`Machine.pose_error`) — a path independent of the
solver's own evaluation (:mod:`.model`). Used by the planner (simulated calibrations of a
virtual machine) and by the re-simulation check of a written machine.

Each function returns the data set with its values replaced (same geometry); ``noise`` the
standard uncertainty of a reading (µm, µrad), drawn from ``rng`` (None: no noise).
A plate's indicated centres are solved for: the indicated position at which the true stylus tip
is on the placed ball (fixed-point iteration on the machine's error).
"""

from __future__ import annotations

from dataclasses import replace
from typing import TYPE_CHECKING

import numpy as np
from numpy.typing import NDArray

from .laser import LaserData, LaserRun
from .model import rotation_vector_urad
from .multilateration import MultilaterationData
from .obs_laser import SQUARENESS_SAMPLES
from .observation import rotation_from_vector
from .plate import PlateData

if TYPE_CHECKING:
    from ..machine import Machine

__all__ = [
    "random_pose",
    "run_values",
    "simulate_laser",
    "simulate_multilateration",
    "simulate_plate",
    "trac_inputs",
]

FloatArray = NDArray[np.float64]


def _noise(rng: np.random.Generator | None, sigma: float, shape: tuple[int, ...]) -> FloatArray:
    return np.zeros(shape) if rng is None else sigma * rng.standard_normal(shape)


def _inputs(run: LaserRun) -> dict[str, FloatArray]:
    name = f"dir_{'xyz'[run.axis]}"
    return {name: run.direction} if run.kind != "squareness" else {}


def trac_inputs(data: MultilaterationData) -> dict[str, FloatArray]:
    """The machine API's runtime inputs at a multilateration's rows: each axis' last direction
    of travel (``dir_x`` …, which the reversal follows), when the file's order gives them."""
    if data.direction.shape != data.q_mm.shape:
        return {}
    return {f"dir_{a}": data.direction[:, k] for k, a in enumerate("xyz")}


def run_values(machine: Machine, run: LaserRun) -> FloatArray:
    """The run's noise-free readings (µm, µrad), relative as the instrument reports them."""
    temps = dict(run.temps_C) or None
    if run.kind == "squareness":
        return np.array([_squareness(machine, run, i) for i in range(run.n)])
    if run.kind == "angle":
        rot = machine.pose_error(run.points_mm, temps, inputs=_inputs(run)).rotation
        # the carriage's own angular error: a table turns R_work_stylus by minus its rotation
        sign = -1.0 if "xyz"[run.axis] in machine.chain.workpiece else 1.0
        values = sign * rotation_vector_urad(rot)[:, run.component]
    else:
        err = machine.volumetric_error(run.points_mm, run.optic_mm, temps, inputs=_inputs(run))
        values = err[:, run.component]
    if run.kind == "straightness":
        out = values.copy()
        for p in run.passes:
            pos = run.position_mm[p]
            out[p] = values[p] - np.polyval(np.polyfit(pos, values[p], 1), pos)
        return out
    return values - values[0]


def _squareness(machine: Machine, run: LaserRun, i: int) -> float:
    lo, hi = machine.volume.lower_mm, machine.volume.upper_mm
    dirs = []
    for axis in (run.axis, run.component):
        q = np.repeat(run.points_mm[i][None], SQUARENESS_SAMPLES, 0)
        q[:, axis] = np.linspace(lo[axis], hi[axis], SQUARENESS_SAMPLES)
        true = q + machine.volumetric_error(q, run.optic_mm) / 1000.0
        s = q[:, axis] - q[:, axis].mean()
        d = s @ (true - true.mean(axis=0)) / (s @ s)
        dirs.append(d / np.linalg.norm(d))
    return float((np.arccos(np.clip(dirs[0] @ dirs[1], -1, 1)) - np.pi / 2) * 1e6)


def simulate_laser(
    machine: Machine,
    data: LaserData,
    rng: np.random.Generator | None = None,
    *,
    scale_ppm: float | None = None,
) -> LaserData:
    """``data`` with the readings ``machine`` gives (plus noise of the plan's a-priori σ and a
    scale error per linear run of σ ``scale_ppm``, default the plan's ``u_scale_ppm``; 0: none)."""
    u = data.spec.u
    u_scale = u["u_scale_ppm"] if scale_ppm is None else scale_ppm
    sigma = {
        "linear": u["u_linear_um"],
        "straightness": u["u_straightness_um"],
        "angle": u["u_angle_urad"],
        "squareness": u["u_squareness_urad"],
    }
    runs = []
    for run in data.runs:
        values = run_values(machine, run) + _noise(rng, sigma[run.kind], (run.n,))
        if run.kind == "linear" and u_scale > 0:  # the run's scale error (air compensation)
            scale = float(_noise(rng, u_scale, (1,))[0])
            values = values + scale * 1e-3 * (run.position_mm - run.position_mm[0])
        runs.append(replace(run, value=values))
    return replace(data, runs=tuple(runs))


def simulate_plate(
    machine: Machine,
    data: PlateData,
    poses: list[tuple[FloatArray, FloatArray]] | None = None,
    rng: np.random.Generator | None = None,
) -> PlateData:
    """``data`` with the indicated centres at which ``machine`` puts the stylus on each ball,
    the placements at ``poses`` ((R, t mm) each; default: the poses that best fit the file's
    centres), probing noise of the plan's ``probe_um``."""
    from .observation import kabsch

    p = data.spec.stylus_mm
    target = np.empty_like(data.q_mm)
    for k in range(len(data.placements)):
        rows = data.placement == k
        if poses is None:
            r, t = kabsch(data.ball_mm[data.ball[rows]], data.q_mm[rows])
        else:
            r, t = poses[k]
        target[rows] = data.ball_mm[data.ball[rows]] @ r.T + t
    temps = dict(data.temps_C) or None
    q = target.copy()
    for _ in range(6):  # q + e(q)/1000 = target: a contraction (|∂e/∂q| ≪ 1000)
        q = target - machine.volumetric_error(q, p, temps) / 1000.0
    q = q + _noise(rng, data.spec.probe_um, q.shape) / 1000.0
    return replace(data, q_mm=q)


def simulate_multilateration(
    machine: Machine,
    data: MultilaterationData,
    stations_mm: FloatArray | None = None,
    dead_path_mm: FloatArray | None = None,
    rng: np.random.Generator | None = None,
) -> MultilaterationData:
    """``data`` with the lengths ``machine`` gives from stations at ``stations_mm`` (default the
    plan's guesses) with dead paths (default zero), noise of the plan's ``u_um``."""
    s = data.spec.station_guess_mm if stations_mm is None else stations_mm
    d = np.zeros(len(data.stations)) if dead_path_mm is None else dead_path_mm
    temps = dict(data.temps_C) or None
    err = machine.volumetric_error(data.q_mm, data.spec.stylus_mm, temps, inputs=trac_inputs(data))
    true = data.q_mm + err / 1000.0
    length = np.linalg.norm(true - s[data.station], axis=1) + d[data.station]
    length = length + _noise(rng, data.spec.u_um, length.shape) / 1000.0
    return replace(data, length_mm=length)


def random_pose(rng: np.random.Generator, angle_rad: float) -> FloatArray:
    """A random rotation of at most ``angle_rad`` about a random axis (for simulated set-ups)."""
    axis = rng.standard_normal(3)
    return rotation_from_vector(axis / np.linalg.norm(axis) * angle_rad * rng.uniform(-1, 1))
