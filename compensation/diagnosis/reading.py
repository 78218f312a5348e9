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

The smooth part: per *segment* (consecutive samples of one direction of travel — the direction
is that of the last motion — cut also where the time stamps jump by more than
:data:`GAP_FACTOR` median intervals), the observed error fitted by a Legendre series of the
position of order ≤ :data:`PASS_ORDER` (at most a quarter of the segment's distinct
positions), plus a term proportional to the velocity where the segment has more than one (a
latency's −v·τ: zero at rest, the sensor looked behind the axis while it moved). Within a
segment the position is monotonic in time, so a drift is a smooth function of it too.

Known limit: where the rows taken while accelerating are dropped (the importer's default),
the time gap cuts every stop of an ISO test into a segment of its own, whose coordinate is the
stop's mean error — the sensor's own ripple value there included, which the moving rows' fit
leaves out (docs/discovery.md, item 7).
Where a position has one reading (one direction of travel) the map between the two
coordinates stays exact (:func:`.reference_candidates.through_map`), as physics says.
"""

from __future__ import annotations

import itertools

import numpy as np
from numpy.polynomial import legendre
from numpy.typing import NDArray

from ..formats.measurements import Measurements

FloatArray = NDArray[np.float64]

__all__ = ["PASS_ORDER", "denoised_reading"]

#: Largest Legendre order of the smooth error along one pass (a positioning curve of order ≤ 5
#: or a correlated curve of 1/6 of the travel).
PASS_ORDER = 6
#: A gap in time longer than this many median sample intervals starts a new pass.
GAP_FACTOR = 20.0


def _passes(direction: FloatArray, t: FloatArray) -> list[slice]:
    """Passes of consecutive samples (already in time order) of one direction of travel."""
    n = len(t)
    brk = np.zeros(n, dtype=bool)
    brk[1:] |= direction[1:] != direction[:-1]
    dt = np.diff(t)
    med = float(np.median(dt)) if len(dt) else 0.0
    if med > 0:
        brk[1:] |= dt > GAP_FACTOR * med
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


def denoised_reading(data: Measurements, carried_um: FloatArray | None = None) -> FloatArray | None:
    """(N, 3) the reference's reading as the position plus each measured axis' smooth error
    (module docstring), or ``None`` when the session has no times or no direction of travel
    (points, not a stream: the raw reading is used). ``carried_um`` (N, 3): what the carriage
    is known to carry beyond a smooth curve (the machine's named cyclic errors, fitted): kept in
    the coordinate — the sensor looks at the carriage — and left out of the smoothing."""
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
        v = None if speed is None else speed[order]
        smooth = np.empty_like(err)
        for run in _passes(direction[order], t[order]):
            smooth[run] = _smooth_pass(q[run], err[run] - known[run], None if v is None else v[run])
        out[order, k] = q + (smooth + known) / 1000.0
        done = True
    return out if done else None
