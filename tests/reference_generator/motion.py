"""The axis' commanded motion: ISO 230-2 cycles or continuous scans, trapezoidal moves, dwells.

A profile is a list of moves (start time, start and end position, cruise speed, acceleration),
the axis standing still between them. Everything is evaluated exactly at any time (the reference
instrument samples at t − latency, not on the indicated stream's clock).

Units: positions mm, speeds mm/s, accelerations mm/s², times s.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

FloatArray = NDArray[np.float64]


@dataclass(frozen=True)
class Profile:
    """Moves of one axis; between moves the axis stands still.

    ``t0`` (s) start of each move, ``q0``/``q1`` (mm) its ends, ``v`` (mm/s, > 0) cruise speed,
    ``a`` (mm/s², > 0) acceleration and deceleration, ``recorded`` whether the samples taken
    during the move and the dwell after it belong to the session, ``group`` the cycle/pass label
    of those samples. ``dir_before`` (±1) the direction of the motion that brought the axis to
    ``q0[0]`` before the first move.
    """

    t0: FloatArray
    q0: FloatArray
    q1: FloatArray
    v: FloatArray
    a: FloatArray
    recorded: NDArray[np.bool_]
    group: tuple[str, ...]
    dir_before: int
    t_end: float

    @property
    def duration(self) -> FloatArray:
        """Time of each move (s): trapezoid, accelerations included."""
        dist = np.abs(self.q1 - self.q0)
        return dist / self.v + self.v / self.a

    def _move_index(self, t: FloatArray) -> NDArray[np.intp]:
        """Index of the last move started at or before t (−1 before the first)."""
        return np.searchsorted(self.t0, t, side="right") - 1

    def evaluate(self, t: FloatArray) -> tuple[FloatArray, FloatArray, FloatArray, FloatArray]:
        """Position (mm), velocity (mm/s, signed), last direction (±1) and |acceleration| (mm/s²)
        at times t (s)."""
        t = np.asarray(t, dtype=float)
        k = self._move_index(t)
        kk = np.clip(k, 0, None)
        before = k < 0
        q0, q1, v, a = self.q0[kk], self.q1[kk], self.v[kk], self.a[kk]
        sign = np.sign(q1 - q0)
        dist = np.abs(q1 - q0)
        ta = v / a
        tc = dist / v - ta  # cruise time (≥ 0 by construction)
        tau = np.clip(t - self.t0[kk], 0.0, None)
        s = np.where(
            tau < ta,
            0.5 * a * tau**2,
            np.where(
                tau < ta + tc,
                0.5 * a * ta**2 + v * (tau - ta),
                dist - 0.5 * a * np.clip(2 * ta + tc - tau, 0.0, None) ** 2,
            ),
        )
        moving = tau < 2 * ta + tc
        s = np.where(moving, s, dist)
        speed = np.where(
            tau < ta, a * tau, np.where(tau < ta + tc, v, a * np.clip(2 * ta + tc - tau, 0, None))
        )
        speed = np.where(moving, speed, 0.0)
        accel = np.where(moving & ((tau < ta) | (tau >= ta + tc)), a, 0.0)
        q = np.where(before, self.q0[0], q0 + sign * s)
        vel = np.where(before, 0.0, sign * speed)
        accel = np.where(before, 0.0, accel)
        direction = np.where(before, float(self.dir_before), sign)
        return q, vel, direction, accel

    def sample_info(self, t: FloatArray) -> tuple[NDArray[np.bool_], NDArray[np.str_]]:
        """Whether each time lies in a recorded move or the dwell after it, and its group."""
        k = self._move_index(np.asarray(t, dtype=float))
        ok = (k >= 0) & (np.asarray(t) <= self.t_end)
        kk = np.clip(k, 0, None)
        rec = ok & self.recorded[kk]
        groups = np.array(self.group, dtype=str)[kk]
        return rec, groups


@dataclass(frozen=True)
class MotionPlan:
    """What the session does (drawn in :mod:`.design`).

    ``layout``: ``iso`` (ISO 230-2: stop at every target) or ``scan`` (end to end without stops);
    ``mode``: ``bidirectional`` or ``one-directional`` (``sense`` ±1 is the measured direction of a
    one-directional session); ``cycles``: bidirectional cycles or one-directional passes;
    ``speeds`` (mm/s): one or two cruise speeds; two alternate per move (iso) or per cycle/pass
    (scan); ``return_speed`` (mm/s) the unrecorded rapid return of one-directional sessions.
    """

    lo: float
    hi: float
    overrun: float
    targets: tuple[float, ...]
    layout: str
    mode: str
    sense: int
    cycles: int
    speeds: tuple[float, ...]
    accel: float
    dwell_s: float
    return_speed: float
    t_start: float


def _speed(plan: MotionPlan, move: int, cycle: int) -> float:
    if len(plan.speeds) == 1:
        return plan.speeds[0]
    return plan.speeds[(move if plan.layout == "iso" else cycle) % len(plan.speeds)]


def _stops(plan: MotionPlan, sense: int) -> list[float]:
    """Stops of one pass in direction ``sense`` (ends at the overrun)."""
    inner = list(plan.targets) if plan.layout == "iso" else []
    end = plan.hi + plan.overrun if sense > 0 else plan.lo - plan.overrun
    return (inner if sense > 0 else inner[::-1]) + [end]


def build_profile(plan: MotionPlan) -> Profile:
    """The moves of the whole session."""
    start = plan.lo - plan.overrun if plan.sense > 0 else plan.hi + plan.overrun
    t, q = plan.t_start, start
    rows: list[tuple[float, float, float, float, float, bool, str]] = []
    move = 0

    def add(target: float, speed: float, recorded: bool, group: str) -> None:
        nonlocal t, q, move
        rows.append((t, q, target, speed, plan.accel, recorded, group))
        t += abs(target - q) / speed + speed / plan.accel + plan.dwell_s
        q = target
        move += 1

    for c in range(plan.cycles):
        group = f"cycle-{c + 1}"
        senses = (plan.sense, -plan.sense) if plan.mode == "bidirectional" else (plan.sense,)
        for sense in senses:
            for stop in _stops(plan, sense):
                add(stop, _speed(plan, move, c), True, group)
        if plan.mode != "bidirectional":
            add(start, plan.return_speed, False, group)
    arr = np.array([r[:5] for r in rows], dtype=float)
    return Profile(
        t0=arr[:, 0],
        q0=arr[:, 1],
        q1=arr[:, 2],
        v=arr[:, 3],
        a=arr[:, 4],
        recorded=np.array([r[5] for r in rows], dtype=bool),
        group=tuple(r[6] for r in rows),
        dir_before=-plan.sense,
        t_end=t - plan.dwell_s * 0.5,
    )


def recorded_time(profile: Profile, rest_recorded: bool) -> tuple[float, float]:
    """Seconds of cruise and of (recorded) rest in the session: what sets the number of rows."""
    dur = profile.duration
    dist = np.abs(profile.q1 - profile.q0)
    cruise = dist / profile.v - profile.v / profile.a
    rec = profile.recorded
    gaps = np.diff(np.r_[profile.t0, profile.t_end]) - dur
    rest = float(np.sum(np.clip(gaps[rec], 0, None))) if rest_recorded else 0.0
    return float(np.sum(cruise[rec])), rest
