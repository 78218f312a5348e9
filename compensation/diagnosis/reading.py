"""The reference's reading as a coordinate: what the sensor looked at, without its noise.

A term locked to the reference instrument (a sensor's cyclic nonlinearity, its smooth
linearity error) is a function of the distance the sensor *looks at*; its reading is that
distance plus the sensor's own noise and its own errors (the cyclic one itself). Evaluated at
the raw reading, a cyclic term of a short period carries both into its phase: the noise as
2π·σ/p rad (a 0.035 mm ripple read with 0.6 µm of noise loses ~0.1 rad per point), the ripple
as a phase modulation of index 2π·A/p (0.4 for 2.3 µm on 0.035 mm: a noise-free ripple then
missed its own shape by ~70 noise variances over 850 points, more than the reversal's shift
between the directions it is to be told by). The position-locked hypothesis, whose coordinate —
the axis' own encoder — is clean, then wins whatever the truth. The two are compared on equal
terms only with the reading taken as the position plus the *smooth* part of the error.

The smooth part: per *piece of a pass* (consecutive samples of one direction of travel — the
direction is that of the last motion — cut where the position steps back against that
direction, a return that was not recorded as between one-directional scans, and where the
carriage moves again after a gap in time of more than :data:`GAP_FACTOR` median intervals),
the observed error fitted by a Legendre series of the position of order ≤ :data:`PASS_ORDER`
(at most a quarter of the piece's distinct positions), plus a term proportional to the
velocity where the piece has more than one (a latency's −v·τ: zero at rest, the sensor looked
behind the axis while it moved). Within a pass the position is monotonic in time, so a drift
is a smooth function of it too. A stop is part of the piece that brought the carriage there,
whatever the gap in time before it (the importers drop the rows taken while accelerating);
it is never a piece of its own.

The sensor's own named cyclic error (``sensor_um``: a ``reference_ripple`` once fitted) is left
out of the smoothing and out of the coordinate: it is an error of the reading, not of where the
sensor looked. Left in, the smooth part of a stop — one position, the ripple's value there not
averaged away, and the velocity term free to take the difference from the moving rows — is its
mean error *with* that value: the coordinate moved by up to the ripple's amplitude (2π·A/p rad
of phase; on `ripple_triangulation/bidirectional-separable/s1` the stops' coordinate was off by
6.3 µm RMS against an 8.6 µm ripple of 0.092 mm, 0.2 µm once it is left out), and small cyclic
terms of the machine took up the ripple's misfit there (docs/discovery.md, item 7).
Where a position has one reading (one direction of travel) the map between the two
coordinates stays exact (:func:`.coordinate_map.through_map`), as physics says.
"""

from __future__ import annotations

import itertools

import numpy as np
from numpy.polynomial import legendre
from numpy.typing import NDArray

from ..formats.measurements import Measurements

FloatArray = NDArray[np.float64]

__all__ = ["BACK_STEP_MM", "GAP_FACTOR", "PASS_ORDER", "denoised_reading", "passes"]

#: Largest Legendre order of the smooth error along one pass (a positioning curve of order ≤ 5
#: or a correlated curve of 1/6 of the travel).
PASS_ORDER = 6
#: A step of the position against the direction of travel longer than this (mm) starts a new
#: pass (a return not recorded); shorter ones are an encoder's jitter at rest (ESS: ≤ 0.04 µm).
BACK_STEP_MM = 1e-3
#: A gap in time longer than this many median sample intervals, followed by motion, starts a
#: new piece of the pass.
GAP_FACTOR = 20.0


def passes(
    direction: FloatArray,
    q_mm: FloatArray,
    t_s: FloatArray | None = None,
    v_mm_s: FloatArray | None = None,
) -> list[slice]:
    """Pieces of passes of consecutive samples (already in time order) of one direction of
    travel: cut where the direction changes or the position steps back against it by more
    than :data:`BACK_STEP_MM`, and where the carriage moves again after a gap in time of more
    than :data:`GAP_FACTOR` median intervals (a restart: the smooth part stays local along a
    long pass). A stop — the rows at rest after a gap, at rest where ``v_mm_s`` is 0, else
    where the position does not move — is never cut from the motion that brought it there."""
    n = len(q_mm)
    brk = np.zeros(n, dtype=bool)
    brk[1:] |= direction[1:] != direction[:-1]
    brk[1:] |= direction[1:] * np.diff(q_mm) < -BACK_STEP_MM
    if t_s is not None and n > 1:
        dt = np.diff(t_s)
        med = float(np.median(dt))
        if med > 0:
            if v_mm_s is not None:
                moving = v_mm_s[1:] != 0
            else:
                after = np.r_[np.abs(np.diff(q_mm[1:])), np.inf]
                moving = after >= BACK_STEP_MM
            brk[1:] |= (dt > GAP_FACTOR * med) & moving
    cuts = np.r_[0, np.flatnonzero(brk), n]
    return [slice(int(a), int(b)) for a, b in itertools.pairwise(cuts) if b > a]


def _smooth_pass(q_mm: FloatArray, err_um: FloatArray, v: FloatArray | None) -> FloatArray:
    """The smooth part of one pass' error (module docstring)."""
    distinct = len(np.unique(np.round(q_mm, 6)))
    order = min(PASS_ORDER, max(distinct // 4, 0))
    lo, hi = float(np.min(q_mm)), float(np.max(q_mm))
    s = 2.0 * (q_mm - lo) / (hi - lo) - 1.0 if hi > lo else np.zeros_like(q_mm)
    cols = legendre.legvander(s, order)
    if v is not None and float(np.ptp(v)) > 0:
        cols = np.column_stack([cols, v])
    beta, *_ = np.linalg.lstsq(cols, err_um, rcond=None)
    return cols @ beta


def denoised_reading(
    data: Measurements,
    carried_um: FloatArray | None = None,
    sensor_um: FloatArray | None = None,
) -> FloatArray | None:
    """(N, 3) the reference's reading as the position plus each measured axis' smooth error
    (module docstring), or ``None`` when the session has no times or no direction of travel
    (points, not a stream: the raw reading is used). ``carried_um`` (N, 3): what the carriage
    is known to carry beyond a smooth curve (the machine's named cyclic errors, fitted): kept in
    the coordinate — the sensor looks at the carriage — and left out of the smoothing.
    ``sensor_um`` (N, 3): the sensor's own named errors of its reading (fitted): left out of
    both (µm)."""
    t = data.t_s
    if t is None or data.n < 3:
        return None
    out = np.array(data.reference_mm, dtype=float, copy=True)
    order = np.argsort(t, kind="stable")
    done = False
    for k, a in enumerate("xyz"):
        direction = data.directions.get(f"dir_{a}")
        if direction is None or not np.any(direction != 0):
            continue
        speed = data.velocities.get(f"v_{a}")
        q = data.indicated_mm[order, k]
        err = (data.reference_mm[order, k] - q) * 1000.0
        known = np.zeros_like(err) if carried_um is None else carried_um[order, k]
        own = np.zeros_like(err) if sensor_um is None else sensor_um[order, k]
        v = None if speed is None else speed[order]
        runs = passes(direction[order], q, t[order], v)
        smooth = np.empty_like(err)
        for run in runs:
            smooth[run] = _smooth_pass(
                q[run], err[run] - known[run] - own[run], None if v is None else v[run]
            )
        out[order, k] = q + (smooth + known) / 1000.0
        done = True
    return out if done else None
