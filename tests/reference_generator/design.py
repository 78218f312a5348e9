"""Drawing a session: which axis, travel, targets, speeds, stops, cycles and sample rate.

Ranges are those of a stage or CMM axis checked with a displacement sensor or interferometer
streaming beside the axis' own position (the ESS camonitor record: ±20 mm, ISO 230-2 targets every
5 mm, 0.2 mm/s, 10 Hz, stops of a few seconds, 5 bidirectional cycles). Sessions here are smaller
(500–3000 rows) so that a benchmark of a hundred runs in minutes.

Units: mm, mm/s, mm/s², s, Hz.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .motion import MotionPlan, Profile, build_profile, recorded_time

AXES = ("x", "y", "z")
# models whose chain carries the measured axis on the tool side (docs/formats.md §1.2): the
# axis' positional error then adds to the tip's error with the sign the generator uses
TOOL_SIDE_MODELS = {
    "x": ("MB1", "MB2", "MH1", "MH2", "FB1", "FH2"),
    "y": ("MB1", "MB2", "MH1", "MH2", "FB2", "FH1"),
    "z": ("MB1", "MB2", "MH1", "MH2", "FB1", "FB2", "FH1", "FH2", "CX1", "CY1"),
}
ROWS = (500, 3000)  # rows per session
RATE_HZ = (1.0, 100.0)
SPEED_MM_S = (0.02, 2.0)


class DesignError(RuntimeError):
    """No session satisfies the constraints after many draws (a bug in the plan's ranges)."""


@dataclass(frozen=True)
class Constraints:
    """What a hidden effect needs of the session.

    ``mode``: ``bidirectional`` | ``one-directional``; ``layout``: ``iso`` | ``scan`` | None
    (drawn); ``rest``: rows at rest wanted (True), refused (False) or drawn (None); ``speeds``:
    1 or 2 (None: drawn, mostly 1); ``travel_mm``: range of the travel (log-uniform);
    ``ds_max_mm``: largest distance between rows while moving (a ripple must be sampled);
    ``min_cycles``/``max_cycles``; ``min_duration_s`` (a thermal drift needs minutes).
    """

    mode: str
    layout: str | None = None
    rest: bool | None = None
    speeds: int | None = None
    travel_mm: tuple[float, float] = (5.0, 80.0)
    ds_max_mm: float | None = None
    min_cycles: int = 1
    min_duration_s: float = 0.0
    max_cycles: int = 5


@dataclass(frozen=True)
class SessionDesign:
    """A drawn session: the motion, the sample clock and the fixed coordinates."""

    axis: str
    model: str
    plan: MotionPlan
    profile: Profile
    rate_hz: float
    rest_recorded: bool
    fixed_mm: tuple[float, float, float]  # the other two axes' positions (the axis' own unused)
    expected_rows: int

    @property
    def bidirectional(self) -> bool:
        return self.plan.mode == "bidirectional"

    @property
    def n_speeds(self) -> int:
        return len(set(self.plan.speeds))

    @property
    def travel_mm(self) -> float:
        return self.plan.hi - self.plan.lo

    @property
    def centre_mm(self) -> float:
        return 0.5 * (self.plan.lo + self.plan.hi)

    def describe(self) -> dict[str, object]:
        p = self.plan
        return {
            "axis": self.axis,
            "model": self.model,
            "mode": p.mode,
            "sense": p.sense,
            "layout": p.layout,
            "travel_mm": [round(p.lo, 4), round(p.hi, 4)],
            "overrun_mm": round(p.overrun, 4),
            "targets": len(p.targets),
            "cycles": p.cycles,
            "speeds_mm_s": [round(v, 5) for v in p.speeds],
            "accel_mm_s2": round(p.accel, 4),
            "dwell_s": round(p.dwell_s, 3),
            "rest_recorded": self.rest_recorded,
            "rate_hz": round(self.rate_hz, 4),
            "expected_rows": self.expected_rows,
        }


def _loguniform(rng: np.random.Generator, lo: float, hi: float) -> float:
    return float(np.exp(rng.uniform(np.log(lo), np.log(hi))))


def _draw_plan(rng: np.random.Generator, c: Constraints, speed: float) -> tuple[MotionPlan, bool]:
    layout = c.layout or ("iso" if rng.random() < 0.6 else "scan")
    travel = _loguniform(rng, *c.travel_mm) if c.travel_mm[1] > c.travel_mm[0] else c.travel_mm[0]
    centre = float(rng.choice([0.0, rng.uniform(-300.0, 300.0)]))
    lo, hi = centre - travel / 2, centre + travel / 2
    n_speeds = c.speeds or (2 if rng.random() < 0.25 else 1)
    # the second speed must reach both directions: per move (iso) or per cycle (scan)
    min_cycles = max(c.min_cycles, 2 if (n_speeds == 2 and layout == "scan") else 1)
    lo_c = max(2, min_cycles) if c.mode == "one-directional" else min_cycles
    hi_c = max(lo_c, c.max_cycles + (1 if c.mode == "one-directional" else 0))
    cycles = int(rng.integers(lo_c, hi_c + 1))
    speeds = (speed,) if n_speeds == 1 else (speed, speed * rng.uniform(1.6, 3.0))
    n_targets = int(rng.integers(5, 12))
    step = travel / (n_targets - 1)
    # ISO 230-2 §5.3.2: targets not equally spaced, so periodic errors are sampled fairly
    jitter = rng.uniform(-0.15, 0.15, n_targets) * step
    jitter[0] = jitter[-1] = 0.0
    targets = tuple(float(v) for v in np.linspace(lo, hi, n_targets) + jitter)
    rest = c.rest if c.rest is not None else bool(rng.random() < 0.8)
    plan = MotionPlan(
        lo=lo,
        hi=hi,
        overrun=float(rng.uniform(0.02, 0.06) * travel),
        targets=targets,
        layout=layout,
        mode=c.mode,
        sense=int(rng.choice([1, -1])) if c.mode == "one-directional" else 1,
        cycles=cycles,
        speeds=speeds,
        accel=0.0,  # set by the caller once the speeds are known
        dwell_s=_loguniform(rng, 1.5, 8.0),
        return_speed=max(speeds) * rng.uniform(3.0, 10.0),
        t_start=float(rng.uniform(0.0, 20.0)),
    )
    return plan, rest


def draw_design(rng: np.random.Generator, c: Constraints, tries: int = 400) -> SessionDesign:
    """A session meeting the constraints, with 500–3000 expected rows."""
    axis = str(rng.choice(AXES))
    model = str(rng.choice(TOOL_SIDE_MODELS[axis]))
    rows_target = int(_loguniform(rng, ROWS[0] * 1.1, ROWS[1] * 0.9))
    for _ in range(tries):
        speed = _loguniform(rng, *SPEED_MM_S)
        plan, rest = _draw_plan(rng, c, speed)
        step = min(np.diff((plan.lo - plan.overrun, *plan.targets, plan.hi + plan.overrun)))
        shortest = step if plan.layout == "iso" else plan.hi - plan.lo
        vmax = max(plan.speeds)
        # accelerating over at most a fifth of the shortest move, and at most 2 mm/s²
        a_min = vmax**2 / (0.2 * shortest)
        if a_min > 2.0:
            continue
        accel = _loguniform(rng, a_min, max(2.0, a_min * 1.01))
        plan = MotionPlan(**{**plan.__dict__, "accel": accel})
        profile = build_profile(plan)
        cruise_s, rest_s = recorded_time(profile, rest)
        rate = rows_target / (cruise_s + rest_s)
        if not RATE_HZ[0] <= rate <= RATE_HZ[1]:
            continue
        if c.ds_max_mm is not None and vmax / rate > c.ds_max_mm:
            continue
        if profile.t_end - plan.t_start < c.min_duration_s:
            continue
        if rest and rest_s * rate < 2 * plan.cycles:  # a few rows at rest per cycle at least
            continue
        fixed = tuple(float(rng.uniform(-200.0, 200.0)) if a != axis else 0.0 for a in AXES)
        return SessionDesign(
            axis=axis,
            model=model,
            plan=plan,
            profile=profile,
            rate_hz=float(rate),
            rest_recorded=rest,
            fixed_mm=(fixed[0], fixed[1], fixed[2]),
            expected_rows=rows_target,
        )
    raise DesignError(f"no session meets {c} in {tries} draws")
