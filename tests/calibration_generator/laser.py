"""Laser interferometer runs (the issue's ``laser.csv``, the contract's meaning of every quantity).

Physics, per run: the two other axes stand at ``line_*``; the optic sits at ``optic_offset_*``
from the stylus reference point (its Abbe arms are those of a stylus there); the moving axis visits
its targets in bidirectional passes (forward, then the same targets backward, ``cycles`` times),
each axis' last direction of travel setting the machine's reversal.

* ``linear_um``: the moving axis' component of the optic's error (true − indicated), plus the run's
  wavelength-compensation error (a scale of ``scale_ppm``·displacement) and white noise, minus the
  reading at the run's first row (the first target of the first forward pass; the backward passes
  share that zero, so the reversal stays in the data).
* ``straightness_<d>_um``: the <d> component of the optic's error plus white noise, with the
  least-squares line in position removed from each pass separately.
* ``pitch/yaw/roll_urad``: the rotation of the moving body carrying the optic (the ram for a tool
  axis, the table top for a table axis), relative to the base, as a rotation vector of
  ``R(q)·R(q_first)ᵀ`` (exact), the component the issue's mapping names; plus white noise, minus
  the first row's reading.
* ``squareness_urad`` (one row per plane xy, xz, yz): the angle between the least-squares lines
  through the optic's true paths along the two axes (each over its full travel in [volume], 201
  points, crossing at ``line_*``), minus 90° (positive when obtuse), plus white noise.

Every reading also carries the machine's repeatability (white, per axis) where it enters a
position. Units: mm, µm, µrad.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import NDArray

from .kinematics import AXES, rotation_vector_urad
from .machine import TrueMachine

FloatArray = NDArray[np.float64]

HEADER = [
    "axis",
    "quantity",
    "position_mm",
    "value",
    "direction",
    "run",
    "line_x_mm",
    "line_y_mm",
    "line_z_mm",
    "optic_offset_x_mm",
    "optic_offset_y_mm",
    "optic_offset_z_mm",
]

#: per moving axis, the rotation component (0 = about x …) each angle quantity reads (the issue)
ANGLE_COMPONENT = {
    "x": {"roll_urad": 0, "pitch_urad": 1, "yaw_urad": 2},
    "y": {"roll_urad": 1, "pitch_urad": 0, "yaw_urad": 2},
    "z": {"roll_urad": 2, "pitch_urad": 1, "yaw_urad": 0},
}
PLANES = ("xy", "xz", "yz")


@dataclass(frozen=True)
class LaserNoise:
    """Standard deviations (k = 1) of a laser calibration's readings."""

    linear_um: float = 0.10
    scale_ppm: float = 0.20  # per run: air refraction compensation left over (µm/m)
    straightness_um: float = 0.25
    angle_urad: float = 0.15
    roll_urad: float = 0.40  # roll needs a level or a straightness pair: less precise
    squareness_urad: float = 0.80
    repeat_um: float = 0.10  # machine repeatability, each axis, each stop


@dataclass(frozen=True)
class LaserDesign:
    """Which runs, how many targets, how far from the ends of travel."""

    targets: int = 11
    cycles: int = 2
    margin: float = 0.03  # fraction of the travel left at each end
    quantities: tuple[str, ...] = ("linear", "straightness", "angles")
    squareness: bool = True


@dataclass
class Run:
    """One run's rows (dicts keyed by ``HEADER``)."""

    axis: str
    quantity: str
    rows: list[dict[str, Any]]


def _targets(rng: np.random.Generator, lo: float, hi: float, design: LaserDesign) -> FloatArray:
    a = lo + design.margin * (hi - lo)
    b = hi - design.margin * (hi - lo)
    nominal = np.linspace(a, b, design.targets)
    step = (b - a) / (design.targets - 1)
    jitter = rng.uniform(-0.3, 0.3, design.targets) * step  # ISO 230-2: irregular spacing
    jitter[0] = jitter[-1] = 0.0
    return np.round(nominal + jitter, 3)


def _line(rng: np.random.Generator, machine: TrueMachine) -> FloatArray:
    span = machine.upper_mm - machine.lower_mm
    return np.round(machine.lower_mm + rng.uniform(0.2, 0.8, 3) * span, 1)


def _optic(rng: np.random.Generator) -> FloatArray:
    return np.round(
        np.array([rng.uniform(-150, 150), rng.uniform(-150, 150), rng.uniform(-250, 0)]), 1
    )


def _row(
    axis: str,
    quantity: str,
    position: Any,
    value: float,
    direction: int,
    run: int,
    line: FloatArray,
    optic: FloatArray,
) -> dict[str, Any]:
    return dict(
        zip(
            HEADER,
            [axis, quantity, position, value, direction, run, *line.tolist(), *optic.tolist()],
            strict=True,
        )
    )


def _passes(targets: FloatArray, cycles: int) -> tuple[FloatArray, FloatArray, FloatArray]:
    """Positions, directions and pass index of the rows of ``cycles`` bidirectional cycles."""
    pos, dirs, passes = [], [], []
    for c in range(cycles):
        for sense, seq in ((1, targets), (-1, targets[::-1])):
            pos.append(seq)
            dirs.append(np.full(seq.size, sense))
            passes.append(np.full(seq.size, 2 * c + (sense < 0)))
    return np.concatenate(pos), np.concatenate(dirs), np.concatenate(passes)


def _remove_line_per_pass(pos: FloatArray, raw: FloatArray, passes: FloatArray) -> FloatArray:
    out = raw.copy()
    for p in np.unique(passes):
        m = passes == p
        a = np.stack([np.ones(m.sum()), pos[m]], axis=1)
        coef = np.linalg.lstsq(a, raw[m], rcond=None)[0]
        out[m] = raw[m] - a @ coef
    return out


def simulate_run(
    machine: TrueMachine,
    rng: np.random.Generator,
    axis: str,
    quantity: str,
    run: int,
    line: FloatArray,
    optic: FloatArray,
    targets: FloatArray,
    cycles: int,
    noise: LaserNoise,
) -> Run:
    """One bidirectional run of one quantity along one line (rows in the order measured)."""
    k = AXES.index(axis)
    pos, dirs, passes = _passes(targets, cycles)
    q = np.tile(line, (pos.size, 1))
    q[:, k] = pos
    travel = {a: (dirs if a == axis else np.ones(pos.size)) for a in AXES}
    n = pos.size
    if quantity in ANGLE_COMPONENT[axis]:
        rot = machine.body_rotation(q, axis, travel)
        rel = rot @ np.swapaxes(rot[:1], 1, 2)
        sigma = noise.roll_urad if quantity == "roll_urad" else noise.angle_urad
        raw = rotation_vector_urad(rel)[:, ANGLE_COMPONENT[axis][quantity]] + rng.normal(
            0.0, sigma, n
        )
        value = raw - raw[0]
    else:
        err = machine.error_um(q, optic, travel) + rng.normal(0.0, noise.repeat_um, (n, 3))
        if quantity == "linear_um":
            kappa = rng.normal(0.0, noise.scale_ppm)
            raw = err[:, k] + kappa * (pos - pos[0]) / 1000.0 + rng.normal(0.0, noise.linear_um, n)
            value = raw - raw[0]
        else:
            kd = AXES.index(quantity.split("_")[1])
            raw = err[:, kd] + rng.normal(0.0, noise.straightness_um, n)
            value = _remove_line_per_pass(pos, raw, passes)
    line_row = line.copy()
    line_row[k] = pos[0]  # the moving axis' own column: where the run starts
    rows = [
        _row(axis, quantity, float(pos[i]), float(value[i]), int(dirs[i]), run, line_row, optic)
        for i in range(n)
    ]
    return Run(axis, quantity, rows)


def squareness_value_urad(
    machine: TrueMachine, plane: str, crossing_mm: FloatArray, optic_mm: FloatArray
) -> float:
    """The contract's squareness reading (no noise): angle of the two LS lines − 90°, µrad."""
    directions = []
    for axis in plane:
        k = AXES.index(axis)
        s = np.linspace(machine.lower_mm[k], machine.upper_mm[k], 201)
        q = np.tile(crossing_mm, (s.size, 1))
        q[:, k] = s
        path = machine.true_position_mm(q, optic_mm)
        a = np.stack([np.ones(s.size), s - s.mean()], axis=1)
        slope = np.linalg.lstsq(a, path, rcond=None)[0][1]
        directions.append(slope / np.linalg.norm(slope))
    d1, d2 = directions
    angle = np.arctan2(np.linalg.norm(np.cross(d1, d2)), float(d1 @ d2))
    return float((angle - np.pi / 2.0) * 1e6)


def laser_runs(
    machine: TrueMachine,
    rng: np.random.Generator,
    design: LaserDesign = LaserDesign(),
    noise: LaserNoise = LaserNoise(),
    first_run: int = 1,
) -> list[Run]:
    """The runs of a laser calibration: per axis linear, two straightnesses, three angles, plus
    one squareness row per plane (each its own run)."""
    runs: list[Run] = []
    run = first_run
    for k, axis in enumerate(AXES):
        others = [a for a in AXES if a != axis]
        quantities = []
        if "linear" in design.quantities:
            quantities.append("linear_um")
        if "straightness" in design.quantities:
            quantities += [f"straightness_{d}_um" for d in others]
        if "angles" in design.quantities:
            quantities += ["pitch_urad", "yaw_urad", "roll_urad"]
        line = _line(rng, machine)
        targets = _targets(rng, machine.lower_mm[k], machine.upper_mm[k], design)
        for quantity in quantities:
            runs.append(
                simulate_run(
                    machine,
                    rng,
                    axis,
                    quantity,
                    run,
                    line,
                    _optic(rng),
                    targets,
                    design.cycles,
                    noise,
                )
            )
            run += 1
    if design.squareness:
        for plane in PLANES:
            crossing = _line(rng, machine)
            optic = _optic(rng)
            value = squareness_value_urad(machine, plane, crossing, optic)
            value += float(rng.normal(0.0, noise.squareness_urad))
            row = _row(plane, "squareness_urad", "", value, 1, run, crossing, optic)
            runs.append(Run(plane, "squareness_urad", [row]))
            run += 1
    return runs
