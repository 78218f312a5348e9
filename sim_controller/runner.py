"""Run probing programs through a compensation daemon and evaluate before/after compensation.

:func:`build_program` assembles the demo's program (ISO 10360-2 length test, ball plate,
random points); :func:`make_readings` turns its true points into indicated readings on a
:class:`SimulatedMachine`; :func:`run_can` exchanges them over CAN (lock-step, temperatures
re-sent every ``temp_period_s``); :func:`evaluate` computes E0 before (indicated) and after
(the daemon's corrected coordinates), the ball-plate and random-point errors and the latency
percentiles. Transport-agnostic pieces take lists of :class:`AnswerRecord`.
"""

from __future__ import annotations

import time
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from numpy.typing import NDArray

from . import iso10360
from .controller import AnswerRecord, CanController, RawReading
from .programs import BallPlate, ProbePoint, random_points
from .sim_machine import Environment, SimulatedMachine

FloatArray = NDArray[np.float64]
GEOMETRY_APPLIED = frozenset({"ok", "not_thermally_corrected", "missing_direction"})


@dataclass
class Program:
    """The points to probe and how to evaluate them."""

    lengths: list[iso10360.LengthMeasurement]
    plate: BallPlate | None
    n_random: int
    points: list[ProbePoint] = field(default_factory=list)

    @property
    def slices(self) -> dict[str, slice]:
        """Index ranges of each part in ``points``."""
        n_len = 2 * len(self.lengths)
        n_plate = 5 * self.plate.n**2 if self.plate is not None else 0
        return {
            "lengths": slice(0, n_len),
            "plate": slice(n_len, n_len + n_plate),
            "random": slice(n_len + n_plate, n_len + n_plate + self.n_random),
        }


def build_program(
    lower_mm: FloatArray,
    upper_mm: FloatArray,
    rng: np.random.Generator,
    n_random: int = 500,
    plate: bool = True,
    repetitions: int = iso10360.REPETITIONS,
) -> Program:
    """ISO 10360-2 length test + a 5×5 ball plate + ``n_random`` random points."""
    lengths = iso10360.length_test(lower_mm, upper_mm, repetitions=repetitions)
    bp = BallPlate.fitting(lower_mm, upper_mm) if plate else None
    pts = iso10360.probe_points(lengths)
    if bp is not None:
        pts += bp.points()
    pts += random_points(lower_mm, upper_mm, n_random, rng)
    return Program(lengths, bp, n_random, pts)


def make_readings(
    sim: SimulatedMachine, env: Environment, points: list[ProbePoint], seq0: int = 0
) -> tuple[FloatArray, list[RawReading]]:
    """Indicated positions (N, 3) mm at the environment's t = 0 temperatures, and the readings."""
    true = np.array([p.true_mm for p in points], dtype=float)
    dirs = np.array([p.probe_dir if p.probe_dir is not None else (0.0, 0.0, 0.0) for p in points])
    indicated = sim.indicated_from_true(true, env.at(0.0), dirs)
    readings = [
        RawReading(
            (seq0 + i) & 0xFFFF,
            (float(q[0]), float(q[1]), float(q[2])),
            p.travel_dir,
            p.probe_dir,
        )
        for i, (q, p) in enumerate(zip(indicated, points, strict=True))
    ]
    return indicated, readings


def run_can(
    controller: CanController,
    readings: list[RawReading],
    env: Environment,
    temp_period_s: float = 0.1,
    progress: Callable[[int, int], None] | None = None,
) -> list[AnswerRecord]:
    """Exchange every reading in lock-step; temperatures first and every ``temp_period_s``."""
    out: list[AnswerRecord] = []
    last_temps = -1e9
    n = len(readings)
    for i, r in enumerate(readings):
        now = time.monotonic()
        if now - last_temps >= temp_period_s:
            controller.send_temperatures(env.samples(0.0))
            last_temps = now
            if i == 0:
                time.sleep(0.01)  # let the daemon take the first samples before the first reading
        out.append(controller.exchange(r))
        if progress is not None and (i % 200 == 0 or i == n - 1):
            progress(i + 1, n)
    return out


def corrected_array(answers: list[AnswerRecord]) -> FloatArray:
    """(N, 3) corrected positions, NaN where the daemon did not apply the geometry."""
    out = np.full((len(answers), 3), np.nan)
    for i, a in enumerate(answers):
        if a.corrected_mm is not None and a.status in GEOMETRY_APPLIED:
            out[i] = a.corrected_mm
    return out


def evaluate(
    program: Program, indicated_mm: FloatArray, answers: list[AnswerRecord]
) -> dict[str, Any]:
    """Before/after figures of one run (µm), counts and latency percentiles (µs)."""
    corrected = corrected_array(answers)
    sl = program.slices
    true = np.array([p.true_mm for p in program.points])
    e_before = iso10360.length_errors_um(program.lengths, indicated_mm[sl["lengths"]])
    e_after = iso10360.length_errors_um(program.lengths, corrected[sl["lengths"]])
    lat = np.array([a.latency_us for a in answers], dtype=float)
    lat = lat[np.isfinite(lat)]
    out: dict[str, Any] = {
        "readings": len(answers),
        "corrected": sum(a.status == "ok" for a in answers),
        "e0_before_um": iso10360.e0_um(e_before),
        "e0_after_um": iso10360.e0_um(e_after),
        "latency_us": {
            "p50": float(np.percentile(lat, 50)) if lat.size else float("nan"),
            "p99": float(np.percentile(lat, 99)) if lat.size else float("nan"),
        },
        "statuses": {s: sum(a.status == s for a in answers) for s in {a.status for a in answers}},
    }
    if program.plate is not None:
        b = program.plate.distance_errors_um(indicated_mm[sl["plate"]])
        a = program.plate.distance_errors_um(corrected[sl["plate"]])
        out["ball_plate_max_um"] = {
            "before": float(np.abs(b).max()),
            "after": float(np.abs(a).max()),
        }
    if program.n_random:
        r = sl["random"]
        before = np.linalg.norm((indicated_mm[r] - true[r]) * 1000, axis=1)
        after = np.linalg.norm((corrected[r] - true[r]) * 1000, axis=1)
        out["random_rms_um"] = {
            "before": float(np.sqrt(np.mean(before**2))),
            "after": float(np.sqrt(np.mean(after**2))),
        }
    return out
