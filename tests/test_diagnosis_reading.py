"""The reference's reading as a coordinate (compensation/diagnosis/reading.py, issue 24).

Sessions built here with numpy alone (not the reference generator, not the diagnosis): one axis
run back and forth with a stop at each end, the rows taken while accelerating dropped (a gap in
time before and after every stop, as the importers write them), a reversal, a smooth machine
error, a latency of the reference's time stamps and a sensor ripple whose period follows the
triangulation law p(r) = p0·(r/d0)². The oracle is the simulation's own truth: the distance
the sensor looked at.
"""

from __future__ import annotations

import numpy as np

from cmm_comp.compensation.diagnosis.reading import denoised_reading, passes
from cmm_comp.compensation.formats.measurements import Measurements

SPEED_MM_S = 0.3
RATE_HZ = 35.0
TAU_S = 0.04  # the reference's time stamps late by this much
NOISE_UM = 0.2
STOP_MM = 0.62  # beyond the last moving row (the deceleration's rows are dropped)


def _motion(cycles: int) -> tuple[np.ndarray, ...]:
    """(q mm, t s, v mm/s, direction) of ``cycles`` back-and-forth cycles with end stops."""
    out: list[list[np.ndarray]] = [[], [], [], []]
    t = 0.0
    step = SPEED_MM_S / RATE_HZ
    for c in range(2 * cycles):
        sense = 1.0 if c % 2 == 0 else -1.0
        q = sense * np.arange(-0.5, 0.5, step)
        for part, (qq, vv) in enumerate(
            [(q, np.full(q.size, sense * SPEED_MM_S)), (np.full(60, sense * STOP_MM), np.zeros(60))]
        ):
            out[0].append(qq)
            out[1].append(t + np.arange(qq.size) / RATE_HZ)
            out[2].append(vv)
            out[3].append(np.full(qq.size, sense))
            t += qq.size / RATE_HZ + 0.7 * (part + 1)  # a gap: rows while accelerating dropped
    return tuple(np.concatenate(o) for o in out)


def _session(seed: int, cycles: int = 3) -> tuple[Measurements, np.ndarray, np.ndarray]:
    """(data, distance the sensor looked at (mm), the sensor's ripple (µm)) of one session."""
    rng = np.random.default_rng(seed)
    q, t_s, v, d = _motion(cycles)
    machine_um = np.where(d > 0, -12.0, 12.0) + 3.0 * q**2  # a reversal and a smooth curve
    looked = q - v * TAU_S + machine_um / 1000.0
    r = looked + 6.0  # the sensor's own distance (mm); period 0.09 mm at r = d0 = 6
    ripple_um = 8.0 * np.sin(2 * np.pi * 6.0**2 / 0.09 * (1 / 6.0 - 1 / r))
    reading = looked + (ripple_um + rng.normal(0.0, NOISE_UM, q.size)) / 1000.0
    zeros = np.zeros_like(q)
    data = Measurements(
        indicated_mm=np.column_stack([q, zeros, zeros]),
        reference_mm=np.column_stack([reading, zeros, zeros]),
        t_s=t_s,
        directions={"dir_x": d},
        velocities={"v_x": v},
    )
    return data, looked, ripple_um


def test_a_stop_is_part_of_its_pass_and_a_return_not_recorded_cuts() -> None:
    """Passes are physical: one per direction of travel, the stop (after a gap in time) in
    the pass that brought the carriage there (cut off on its own, its smooth part would be its
    mean error, the sensor's ripple value there included); a one-directional scan's unrecorded return (the
    position jumps back, the direction stays) starts a new pass."""
    q, t_s, v, d = _motion(3)
    runs = passes(d, q, t_s, v)
    assert len(runs) == 6
    assert passes(d, q, t_s) == runs  # at rest told by the position, without velocities
    for r in runs:
        assert np.all(d[r] == d[r.start])
        assert np.any(np.abs(q[r]) == STOP_MM)  # the stop went with its pass
    one_way = np.r_[q[d > 0], q[d > 0]]  # two forward scans, the return not recorded
    assert len(passes(np.ones_like(one_way), one_way)) == 2 * 3


def test_the_coordinate_is_where_the_sensor_looked_at_stops_and_while_moving() -> None:
    """With the sensor's own ripple known (as once it is named), the coordinate is the distance
    the sensor looked at within the noise's reach — at the stops too, where the ripple's value
    at that one place is not averaged away, and while moving, where the latency moved it by
    v·τ = 12 µm. Without the ripple left out, a stop's coordinate carries the ripple's value
    there (the old behaviour, in which a triangulation ripple left spurious cyclic errors of
    the machine beside it): checked to be far off, so the comparison can fail."""
    data, looked, ripple_um = _session(5)
    sensor = np.zeros((data.n, 3))
    sensor[:, 0] = ripple_um
    got = denoised_reading(data, None, sensor)
    assert got is not None
    err_um = (got[:, 0] - looked) * 1000.0
    at_rest = data.velocities["v_x"] == 0
    # a least-squares mean of ≥ 60 rows of 0.2 µm noise: a few tenths of a µm at most
    assert np.sqrt(np.mean(err_um[at_rest] ** 2)) < 0.3, np.sqrt(np.mean(err_um[at_rest] ** 2))
    assert np.sqrt(np.mean(err_um[~at_rest] ** 2)) < 0.3
    raw_um = (data.reference_mm[:, 0] - looked) * 1000.0
    assert np.sqrt(np.mean(raw_um**2)) > 3.0  # the raw reading is far from it
    kept = denoised_reading(data)
    assert kept is not None
    kept_um = (kept[:, 0] - looked) * 1000.0
    assert np.sqrt(np.mean(kept_um[at_rest] ** 2)) > 1.0  # the ripple's value at the stops
