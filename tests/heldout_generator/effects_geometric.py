"""Geometric hidden effects: coupling, parametric, periodic, reversal, unexplained.

Each drawer picks a physically plausible variant (a machine builder's list, not a fitter's) and
returns its forward model with a unit-free knob (the amplitude, µm or µrad) left to the scaler.
"""

from __future__ import annotations

import numpy as np
from numpy.polynomial import legendre as leg
from numpy.typing import NDArray

from .chain import AXES, MODEL_AXES, TABLE_NAMES, table_slot
from .design import Session
from .effect_base import Contribution, HiddenEffect, axis_index, normalised
from .identity import Identity
from .machine import SQUARENESS, RandomMachine

FloatArray = NDArray[np.float64]


def relation(model: str, a: str, b: str) -> str:
    """How axis ``a``'s carriage relates to axis ``b``: ``rides`` (a is carried by b), ``carries``
    (a carries b) or ``cross`` (one on the tool side, the other under the workpiece)."""
    tool, work = MODEL_AXES[model]
    for side in (tool, work):
        if a in side and b in side:
            return "rides" if side.index(b) < side.index(a) else "carries"
    return "cross"


def _shape_along(kind: str, s: FloatArray, end: int) -> FloatArray:
    """Shapes on s ∈ [0, 1] (``end`` 0/1: which end a one-sided shape starts from)."""
    se = s if end == 0 else 1.0 - s
    if kind == "linear":
        return 2.0 * s - 1.0
    if kind == "from_end":
        return se
    if kind == "sag":
        return 4.0 * s * (1.0 - s)
    if kind == "uniform":
        return np.ones_like(s)
    if kind == "growing":
        return se
    if kind == "bow":
        return 4.0 * s * (1.0 - s)
    raise ValueError(f"unknown shape {kind!r}")


# ---------------------------------------------------------------------------- coupling
def draw_coupling(
    rng: np.random.Generator, machine: RandomMachine, session: Session
) -> HiddenEffect:
    """A carriage's error that also depends on another axis' position (non-rigid structure).

    * ``rides``: a's guideway is carried by b, which twists or bends it as b travels (bridge twist:
      the carriage pitches by an amount that changes with the bridge's position);
    * ``carries``: a's carriage carries b, whose weight shifts as b travels (load shift), more so
      where a's support is softer (grows along a);
    * ``cross``: tool and table sides, coupled through the base deforming under the moving mass.

    Angular (85 %): ε_r of a += A·g(s_b)·h(s_a), g ∈ linear / from an end / sag (zero at both
    ends), h ∈ uniform / growing from one end of a. Straightness (15 %): δ_r of a += A·g(s_b)·bow(s_a)
    (a beam's sag that changes with b).
    """
    weights = {"rides": 0.5, "carries": 0.3, "cross": 0.2}
    options = []
    for a in AXES:
        for b in AXES:
            if a == b:
                continue
            rel = relation(machine.model, a, b)
            for r in AXES:
                options.append((a, "e", r, b, rel, weights[rel] * 0.85 / 3))
                if r != a:
                    options.append((a, "d", r, b, rel, weights[rel] * 0.15 / 2))
    p = np.array([o[5] for o in options])
    a, kind, r, b, rel, _ = options[int(rng.choice(len(options), p=p / p.sum()))]
    g_kind = str(rng.choice(["linear", "from_end", "sag"]))
    h_kind = str(rng.choice(["uniform", "growing"])) if kind == "e" else "bow"
    g_end, h_end = int(rng.integers(2)), int(rng.integers(2))
    sign = float(rng.choice([-1.0, 1.0]))
    s = normalised(machine, session)
    shape = (
        sign
        * _shape_along(g_kind, s[:, axis_index(b)], g_end)
        * _shape_along(h_kind, s[:, axis_index(a)], h_end)
    )
    component = f"{kind}{r}_{a}"
    k, slot = table_slot(component)

    def forward(amplitude: float) -> Contribution:
        c = Contribution.zeros(session.n)
        c.errors[:, k, slot] += amplitude * shape
        return c

    return HiddenEffect(
        identity=Identity("coupling", component=component, varies_with=b),
        variant=f"{rel}/{g_kind}x{h_kind}",
        params={"relation": rel, "g": g_kind, "g_end": g_end, "h": h_kind, "h_end": h_end},
        forward=forward,
        knob_name="amplitude_" + ("urad" if kind == "e" else "um"),
        knob_range=(0.05, 60.0 if kind == "e" else 25.0),
    )


# ---------------------------------------------------------------------------- parametric
def _stale_shape(
    rng: np.random.Generator, kind: str, s: FloatArray, straightness: bool
) -> tuple[str, FloatArray]:
    if kind == "bump":
        c, w = rng.uniform(0.2, 0.8), rng.uniform(0.08, 0.25)
        y = np.exp(-0.5 * ((s - c) / w) ** 2)
    elif kind == "bow":
        y = 4.0 * s * (1.0 - s)
    elif kind == "s_curve":
        x = 2 * s - 1
        y = 0.5 * (5 * x**3 - 3 * x)
    elif kind == "linear":
        y = 2 * s - 1
    else:  # smooth_random
        order = int(rng.integers(2, 5))
        coef = rng.normal(0, 1, order + 1)
        coef[:2] *= 0.5
        y = leg.legval(2 * s - 1, coef)
    if straightness:  # a straightness keeps no line: that would be a squareness
        design = np.vstack([np.ones_like(s), s]).T
        coef_line = np.linalg.lstsq(design, y, rcond=None)[0]
        y = y - design @ coef_line
    return kind, y


def draw_parametric(
    rng: np.random.Generator, machine: RandomMachine, session: Session
) -> HiddenEffect:
    """A calibration gone stale: one of the 18 tables changed by a smooth shape (a local bump after
    a crash, a bow after re-levelling, wear in the most-used middle, an S-curve, a smooth random
    change; a linear change for positional and angular tables), or a squareness shifted."""
    names = list(TABLE_NAMES) + list(SQUARENESS)
    component = str(rng.choice(names, p=[0.9 / 18] * 18 + [0.1 / 3] * 3))
    n = session.n
    if component in SQUARENESS:
        j = SQUARENESS.index(component)

        def forward_sq(amplitude: float) -> Contribution:
            c = Contribution.zeros(n)
            c.squareness_urad[:, j] += amplitude
            return c

        return HiddenEffect(
            identity=Identity("parametric", component=component),
            variant="squareness",
            params={},
            forward=forward_sq,
            knob_name="amplitude_urad",
            knob_range=(0.05, 40.0),
        )
    k, slot = table_slot(component)
    straightness = slot < 3 and slot != k
    kinds = ["bump", "bow", "s_curve", "smooth_random"] + ([] if straightness else ["linear"])
    s = normalised(machine, session)[:, k]
    kind, shape = _stale_shape(rng, str(rng.choice(kinds)), s, straightness)
    shape = shape / max(np.abs(shape).max(), 1e-12)

    def forward(amplitude: float) -> Contribution:
        c = Contribution.zeros(n)
        c.errors[:, k, slot] += amplitude * shape
        return c

    return HiddenEffect(
        identity=Identity("parametric", component=component),
        variant=kind,
        params={},
        forward=forward,
        knob_name="amplitude_" + ("urad" if slot >= 3 else "um"),
        knob_range=(0.05, 40.0 if slot >= 3 else 25.0),
    )


# ---------------------------------------------------------------------------- periodic
def draw_periodic(
    rng: np.random.Generator, machine: RandomMachine, session: Session
) -> HiddenEffect:
    """A cyclic positional error (screw pitch, rack, encoder interpolation) on any axis.

    Period log-uniform in [max(8 mm, travel/60), travel/4]. Variants: ``sine``; ``harmonics``
    (2nd and 3rd at 20–60 % and 0–30 % with their own phases); ``modulated`` (amplitude changes
    along the travel, a worn screw); ``wobble`` (the nut also rocks the carriage about an axis
    across its travel with the same period: a periodic angle with Abbe arms).
    """
    axis = str(rng.choice(AXES))
    k = axis_index(axis)
    span = float(machine.span_mm[k])
    period = float(np.exp(rng.uniform(np.log(max(8.0, span / 60)), np.log(span / 4))))
    variant = str(rng.choice(["sine", "harmonics", "modulated", "wobble"]))
    q = session.q_mm[:, k]
    phase = rng.uniform(0, 2 * np.pi, 3)
    wave = np.cos(2 * np.pi * q / period + phase[0])
    params: dict[str, float | str] = {"period_mm": period}
    if variant == "harmonics":
        r2, r3 = rng.uniform(0.2, 0.6), rng.uniform(0.0, 0.3)
        wave = (
            wave
            + r2 * np.cos(4 * np.pi * q / period + phase[1])
            + r3 * np.cos(6 * np.pi * q / period + phase[2])
        )
        params.update(r2=r2, r3=r3)
    elif variant == "modulated":
        end = int(rng.integers(2))
        s = normalised(machine, session)[:, k]
        wave = wave * (0.3 + 1.4 * (s if end == 0 else 1 - s))
    wobble = np.zeros_like(q)
    wobble_axis = -1
    if variant == "wobble":
        wobble_axis = int(rng.choice([j for j in range(3) if j != k]))
        ratio = rng.uniform(0.5, 2.0) * rng.choice([-1.0, 1.0])  # µrad per µm
        wobble = ratio * np.sin(2 * np.pi * q / period + phase[0] + rng.uniform(-0.5, 0.5))
        params.update(wobble_about=AXES[wobble_axis], urad_per_um=ratio)
    n = session.n

    def forward(amplitude: float) -> Contribution:
        c = Contribution.zeros(n)
        c.errors[:, k, k] += amplitude * wave
        if wobble_axis >= 0:
            c.errors[:, k, 3 + wobble_axis] += amplitude * wobble
        return c

    return HiddenEffect(
        identity=Identity("periodic", axis=axis),
        variant=variant,
        params=params,
        forward=forward,
        knob_name="amplitude_um",
        knob_range=(0.02, 10.0),
    )


# ---------------------------------------------------------------------------- reversal
def draw_reversal(
    rng: np.random.Generator, machine: RandomMachine, session: Session
) -> HiddenEffect:
    """Backlash or hysteresis: the positional error depends on the last direction of travel.

    ``constant`` (half reversal B/2); ``growing`` (B grows along the travel away from the drive:
    a long screw winds up); ``hysteresis`` (a short move reverses only part of it:
    B/2·(1 − e^(−run/d0)), run = travel since the axis last reversed, d0 0.5–3 mm).
    """
    axis = str(rng.choice(AXES))
    k = axis_index(axis)
    variant = str(rng.choice(["constant", "growing", "hysteresis"]))
    s = normalised(machine, session)[:, k]
    params: dict[str, float] = {}
    if variant == "growing":
        end = int(rng.integers(2))
        shape = 0.25 + 0.75 * (s if end == 0 else 1 - s)
        params["from_end"] = end
    elif variant == "hysteresis":
        d0 = rng.uniform(0.5, 3.0)
        shape = 1.0 - np.exp(-session.run_mm[:, k] / d0)
        params["d0_mm"] = d0
    else:
        shape = np.ones_like(s)
    direction = session.dirs[:, k]
    n = session.n

    def forward(half_um: float) -> Contribution:
        c = Contribution.zeros(n)
        c.errors[:, k, k] += half_um * shape * direction
        return c

    return HiddenEffect(
        identity=Identity("reversal", axis=axis),
        variant=variant,
        params=params,
        forward=forward,
        knob_name="half_reversal_um",
        knob_range=(0.02, 10.0),
    )


# ---------------------------------------------------------------------------- unexplained
def draw_unexplained(
    rng: np.random.Generator, machine: RandomMachine, session: Session
) -> HiddenEffect:
    """A local defect: an error field confined to one region of the volume, no global cause (a
    heat plume across the reference beam, a distorted region of the artefact's support).

    ``blob`` (isotropic Gaussian, random direction); ``elongated`` (an ellipsoid, each semi-axis
    its own width); ``axis_blob`` (along one machine axis). Its width is set so that 5–30 % of the
    session's points are inside the half-height region.
    """
    variant = str(rng.choice(["blob", "elongated", "axis_blob"]))
    q = session.q_mm
    centre = q[int(rng.integers(session.n))].copy()
    diag = float(np.linalg.norm(machine.span_mm))
    widths = np.full(3, diag * rng.uniform(0.08, 0.2))
    if variant == "elongated":
        widths = widths * rng.uniform(0.5, 2.0, 3)
    target = rng.uniform(0.05, 0.3)
    for _ in range(30):
        weight = np.exp(-0.5 * np.sum(((q - centre) / widths) ** 2, axis=1))
        inside = float(np.mean(weight > 0.5))
        if inside < 0.05:
            widths *= 1.15
        elif inside > 0.3:
            widths /= 1.15
        else:
            break
        if abs(inside - target) < 0.02:
            break
    if variant == "axis_blob":
        v = np.zeros(3)
        v[int(rng.integers(3))] = 1.0
    else:
        v = rng.normal(size=3)
        v /= np.linalg.norm(v)
    n = session.n

    def forward(peak_um: float) -> Contribution:
        c = Contribution.zeros(n)
        c.direct_um += peak_um * weight[:, None] * v
        return c

    return HiddenEffect(
        identity=Identity("unexplained"),
        variant=variant,
        params={
            "centre_mm": centre,
            "widths_mm": widths,
            "direction": v,
            "inside_fraction": inside,
        },
        forward=forward,
        knob_name="peak_um",
        knob_range=(0.05, 15.0),
    )
