"""Sequential multilateration with a tracking interferometer (the issue's ``trac.csv``).

Physics: the tracker stands at station s (workpiece frame: on the table, or raised on a stand)
and follows a reflector the machine carries at ``stylus_mm``. The machine runs one program of
indicated points from every station (points closer than ``min_range_mm`` to the station skipped).
At each stop the reflector's true position is ``p = q + e(q, stylus, last directions)/1000`` plus
the machine's repeatability; the tracker reports ``|p − s| + d`` with d the station's unknown
dead-path offset (the interferometer is zeroed at its home position, so a length may be
negative) and the interferometer's noise N(0, a + b·L). The machine's reversal enters through
each axis' last direction of travel in the program's order (the same at every station). Station
guesses are the true centres ± up to ``guess_mm`` per coordinate.

Units: mm (positions, lengths), µm (noise).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from .kinematics import AXES
from .machine import TrueMachine

FloatArray = NDArray[np.float64]


@dataclass(frozen=True)
class TracDesign:
    """Stations, points and noise of a multilateration."""

    stations: int = 5
    points: int = 70  # the program's points (each station skips the ones too near it)
    min_range_mm: float = 150.0
    guess_mm: float = 50.0
    length_um: float = 0.10  # interferometer noise, σ = a + b·L
    length_um_per_m: float = 0.15
    repeat_um: float = 0.15  # machine repeatability, each axis, each stop
    dead_path_mm: tuple[float, float] = (-700.0, 50.0)


@dataclass
class Trac:
    """A multilateration data set (true stations and dead paths are the hidden truth)."""

    rows: list[tuple[int, int, float, float, float, float]]  # station, point, x, y, z, length
    stations_mm: FloatArray
    dead_path_mm: FloatArray
    guesses_mm: FloatArray
    stylus_mm: FloatArray
    program_mm: FloatArray  # (points, 3) the indicated points in the order run
    directions: dict[str, FloatArray]  # each axis' last direction of travel at each point


def station_positions(rng: np.random.Generator, machine: TrueMachine, n: int) -> FloatArray:
    """Stations near the table's corners (alternately low and raised), the middle, elsewhere."""
    lo, hi = machine.lower_mm, machine.upper_mm
    span = hi - lo
    corners = [(0.15, 0.15), (0.85, 0.15), (0.85, 0.85), (0.15, 0.85)]
    out = []
    for i in range(n):
        if i < 4:
            fx, fy = corners[i]
            fz = rng.uniform(-0.15, 0.05) if i % 2 == 0 else rng.uniform(0.2, 0.5)
        elif i == 4:
            fx, fy, fz = 0.5, 0.5, rng.uniform(0.0, 0.3)
        else:
            fx, fy, fz = rng.uniform(0.1, 0.9), rng.uniform(0.1, 0.9), rng.uniform(0.0, 0.5)
        f = np.array([fx, fy, fz]) + rng.uniform(-0.05, 0.05, 3)
        out.append(lo + f * span)
    return np.round(np.array(out), 3)


def program(rng: np.random.Generator, machine: TrueMachine, n: int) -> FloatArray:
    """``n`` indicated points filling the volume (stratified), in the order the machine runs them."""
    lo, hi = machine.lower_mm, machine.upper_mm
    strata = np.stack([rng.permutation(n) for _ in range(3)], axis=1)  # Latin hypercube
    f = (strata + rng.uniform(0.0, 1.0, (n, 3))) / n
    q = lo + (0.02 + 0.96 * f) * (hi - lo)
    return np.round(q, 3)


def last_directions(q_mm: FloatArray) -> dict[str, FloatArray]:
    """Each axis' last direction of travel (+1/−1) along a path of points (the first: +1)."""
    out: dict[str, FloatArray] = {}
    for k, a in enumerate(AXES):
        step = np.diff(q_mm[:, k], prepend=q_mm[0, k] - 1.0)
        d = np.sign(step)
        for i in range(1, d.size):  # no move: the previous direction holds
            if d[i] == 0:
                d[i] = d[i - 1]
        out[a] = d
    return out


def simulate_trac(
    machine: TrueMachine,
    rng: np.random.Generator,
    stylus_mm: FloatArray,
    design: TracDesign = TracDesign(),
) -> Trac:
    """One multilateration data set at one reflector offset."""
    stations = station_positions(rng, machine, design.stations)
    dead = rng.uniform(*design.dead_path_mm, design.stations)
    guesses = np.round(stations + rng.uniform(-design.guess_mm, design.guess_mm, stations.shape), 1)
    q_all = program(rng, machine, design.points)
    dirs = last_directions(q_all)
    p_true = machine.true_position_mm(q_all, stylus_mm, dirs)
    rows = []
    for s_idx, s in enumerate(stations):
        station_id = s_idx + 1
        rep = rng.normal(0.0, design.repeat_um / 1000.0, p_true.shape)
        dist = np.linalg.norm(p_true + rep - s, axis=1)
        sigma_um = design.length_um + design.length_um_per_m * dist / 1000.0
        length = dist + dead[s_idx] + rng.normal(0.0, 1.0, dist.size) * sigma_um / 1000.0
        for i in range(q_all.shape[0]):
            if np.linalg.norm(q_all[i] - s) < design.min_range_mm:
                continue
            rows.append((station_id, i + 1, *map(float, q_all[i]), float(length[i])))
    return Trac(
        rows=rows,
        stations_mm=stations,
        dead_path_mm=dead,
        guesses_mm=guesses,
        stylus_mm=np.asarray(stylus_mm, dtype=float),
        program_mm=q_all,
        directions=dirs,
    )
