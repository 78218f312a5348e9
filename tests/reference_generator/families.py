"""The hidden families and their variants: what each asks of the session, and its effects.

A draft is drawn before the session (a ripple's period decides how finely the session must
sample and how long its travel is; a thermal drift needs minutes), then builds its effects once
the session is known (a fixed point inside the travel, a sensor's optical centre beyond it).

Sizes are realistic magnitudes in µm (the ESS record: a ±35 µm curve, a 4–35 µm ripple, a 27 µm
reversal, 8–17 µm of thermal drift, a 31 ms latency at 0.2 mm/s = 6 µm), with a floor of a few
times the session's noise σ so that a miss is the diagnosis', not the data's.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from .design import Constraints, SessionDesign
from .machine_effects import PeriodicError, PositioningCurve, Reversal, ThermalExpansion
from .reference_effects import (
    Latency,
    ReferenceDrift,
    ReferenceNonlinearity,
    ReferenceRipple,
    ReferenceScale,
    cosine_scale_um_per_m,
)
from .shapes import draw_smooth, draw_time_curve

BI, ONE = "bidirectional", "one-directional"
RIPPLE_VARIANTS = ("bidirectional-separable", "bidirectional-unseparable", ONE)
MOTION_VARIANTS = ("bidirectional-rest", "bidirectional-two-speeds", "bidirectional-one-speed")
VARIANTS: dict[str, tuple[str, ...]] = {
    "smooth": (BI, ONE),
    "periodic": RIPPLE_VARIANTS,
    "reversal": (*MOTION_VARIANTS, ONE),
    "thermal_drift": (BI, ONE),
    "ripple_triangulation": RIPPLE_VARIANTS,
    "ripple_constant": RIPPLE_VARIANTS,
    "smooth_reference": (BI, ONE),
    "latency": (
        *MOTION_VARIANTS,
        "one-directional-rest",
        "one-directional-two-speeds",
        "one-directional-one-speed",
    ),
    "reference_scale": (BI, ONE),
    "reference_drift": (BI, ONE),
    "mixed": (BI, ONE),
    "clean": (BI, ONE),
}
FAMILIES = tuple(VARIANTS)
Effect = object
Builder = Callable[[SessionDesign, np.random.Generator], list[Effect]]


class Redraw(RuntimeError):
    """The drawn session cannot carry the effect at a realistic size: draw again."""


@dataclass(frozen=True)
class Draft:
    constraints: Constraints
    build: Builder


def mode_of(variant: str) -> str:
    return BI if variant.startswith(BI) else ONE


def _logu(rng: np.random.Generator, lo: float, hi: float) -> float:
    return float(np.exp(rng.uniform(np.log(lo), np.log(hi))))


def size_um(rng: np.random.Generator, lo: float, hi: float, floor: float) -> float:
    """A realistic size in [lo, hi] µm, raised to at least ``floor`` (a few noise σ)."""
    return _logu(rng, max(lo, floor), max(hi, 1.5 * floor))


def _sign(rng: np.random.Generator, p_negative: float = 0.5) -> float:
    return -1.0 if rng.random() < p_negative else 1.0


def _span(d: SessionDesign) -> tuple[float, float]:
    """The whole travel including the overrun (mm)."""
    return d.plan.lo - d.plan.overrun, d.plan.hi + d.plan.overrun


# ---------------------------------------------------------------- periodic and ripple families


def _ripple_period_and_reversal(rng: np.random.Generator, variant: str, machine: bool):
    """(period at the centre mm, reversal µm) steering the separability of the variant.

    The variant names the intent of the draw; the truth is decided by :mod:`.separability` (λ on
    the session's rows), so an ESS-like shift (r/p 0.02–0.12) drawn as ``unseparable`` is
    labelled the instrument's own when its many points and low noise separate it."""
    if variant == "bidirectional-separable":
        rev = rng.uniform(10.0, 80.0)
        return rev / rng.uniform(0.25, 0.75) / 1000.0, rev
    if variant == "bidirectional-unseparable":
        pick = rng.random()
        if pick < 0.4:  # no reversal at all
            return _logu(rng, 0.05, 5.0 if machine else 2.0), 0.0
        if pick < 0.8:  # the ESS case: a reversal much smaller than the period
            rev = rng.uniform(5.0, 40.0)
            return rev / rng.uniform(0.02, 0.12) / 1000.0, rev
        rev = rng.uniform(10.0, 60.0)  # a reversal of about one period
        return rev / rng.uniform(0.93, 1.07) / 1000.0, rev
    rev = 0.0 if rng.random() < 0.4 else rng.uniform(5.0, 40.0)
    return _logu(rng, 0.03, 5.0 if machine else 2.0), rev


def _ripple(
    kind: str,
    p_c: float,
    k: float,
    amp: float,
    h2: float,
    d: SessionDesign,
    rng: np.random.Generator,
) -> ReferenceRipple:
    """A reference ripple over the session's travel; for a triangulation law the sensor's optical
    centre r0 lies k half-travels beyond the centre, on either side."""
    half = d.travel_mm / 2
    r0 = d.centre_mm + _sign(rng) * k * half if kind == "triangulation" else d.centre_mm
    slope = rng.uniform(-0.6, 0.6)
    return ReferenceRipple(
        law=kind,
        period_c_mm=p_c,
        centre_mm=d.centre_mm,
        r0_mm=r0,
        half_travel_mm=half,
        amplitude_c_um=amp / (1 + abs(slope)),
        amplitude_slope=slope,
        phase=rng.uniform(0, 2 * np.pi),
        h2=h2,
        phase2=rng.uniform(0, 2 * np.pi),
    )


def _periodic_draft(variant: str, rng: np.random.Generator, sigma: float, kind: str) -> Draft:
    machine = kind == "periodic"
    p_c, rev = _ripple_period_and_reversal(rng, variant, machine)
    rev *= _sign(rng, 0.8)
    k = rng.uniform(2.5, 10.0)  # triangulation: sensor distance / half travel
    p_min = p_c * (1 - 1 / k) ** 2 if kind == "triangulation" else p_c
    travel = (max(1.0, 10 * p_c), min(80.0, max(1.0, 60 * p_c)))
    c = Constraints(mode=mode_of(variant), travel_mm=travel, ds_max_mm=p_min / 6, max_cycles=3)
    amp = size_um(rng, 0.8 if machine else 1.0, 8.0 if machine else 12.0, 2.5 * sigma)
    h2 = rng.uniform(0.0, 0.1)

    def build(d: SessionDesign, rng: np.random.Generator) -> list[Effect]:
        effects: list[Effect] = [Reversal(rev)] if rev else []
        if machine:
            phase = rng.uniform(0, 2 * np.pi)
            effects.append(PeriodicError(p_c, amp, phase, h2, rng.uniform(0, 2 * np.pi)))
            return effects
        ripple = _ripple(kind, p_c, k, amp, h2, d, rng)
        return [*effects, ripple]

    return Draft(c, build)


# ------------------------------------------------------------------- motion-related families


def _motion_constraints(variant: str) -> Constraints:
    mode = mode_of(variant)
    if variant.endswith("-rest"):
        return Constraints(mode=mode, rest=True, speeds=1)
    if variant.endswith("two-speeds"):
        return Constraints(mode=mode, rest=False, speeds=2)
    if variant.endswith("one-speed"):
        return Constraints(mode=mode, rest=False, speeds=1)
    return Constraints(mode=mode)


def _reversal_draft(variant: str, rng: np.random.Generator, sigma: float) -> Draft:
    rev = size_um(rng, 4.0, 40.0, 5 * sigma) * _sign(rng, 0.8)
    return Draft(_motion_constraints(variant), lambda d, rng: [Reversal(rev)])


def _latency_for(d: SessionDesign, size: float, rng: np.random.Generator) -> Latency:
    vmax = max(d.plan.speeds)
    tau = float(np.clip(size / 1000.0 / vmax, 0.005, 0.15))
    if vmax * tau * 1000.0 < 0.8 * size:
        raise Redraw(f"latency: {size:.1f} µm needs > 150 ms at {vmax:.3f} mm/s")
    return Latency(tau * _sign(rng, 0.15))


def _latency_draft(variant: str, rng: np.random.Generator, sigma: float) -> Draft:
    size = size_um(rng, 2.0, 15.0, 4 * sigma)
    return Draft(_motion_constraints(variant), lambda d, rng: [_latency_for(d, size, rng)])


# --------------------------------------------------------------------- smooth and slow families


def _smooth_draft(variant: str, rng: np.random.Generator, sigma: float, reference: bool) -> Draft:
    ptv = size_um(rng, 4.0, 40.0, 8 * sigma)

    def build(d: SessionDesign, rng: np.random.Generator) -> list[Effect]:
        curve = draw_smooth(rng, *_span(d), ptv)
        return [ReferenceNonlinearity(curve) if reference else PositioningCurve(curve)]

    return Draft(Constraints(mode=mode_of(variant)), build)


def _thermal_for(d: SessionDesign, size: float, rng: np.random.Generator) -> ThermalExpansion:
    lo, hi = d.plan.lo, d.plan.hi
    pick = rng.random()
    fixed = lo if pick < 0.15 else hi if pick < 0.3 else rng.uniform(lo, hi)
    reach = max(abs(lo - d.plan.overrun - fixed), abs(hi + d.plan.overrun - fixed))
    minutes = (d.profile.t_end - d.plan.t_start) / 60.0
    rise = rng.uniform(2.0, min(30.0, max(2.5, minutes)))  # at most ~1 °C per minute
    alpha = size * 1000.0 / (rise * reach)
    if alpha > 60.0:  # beyond any scale/structure mismatch: heat more, or give up
        rise = size * 1000.0 / (60.0 * reach)
        if rise > min(30.0, max(2.5, minutes)):
            raise Redraw(f"thermal: {size:.1f} µm over {reach:.1f} mm needs > 60 µm/(m·°C)")
        alpha = 60.0
    curve = draw_time_curve(rng, d.plan.t_start, d.profile.t_end, ("linear", "warmup", "sigmoid"))
    return ThermalExpansion(alpha * _sign(rng, 0.3), float(fixed), float(rise), curve)


def _thermal_draft(variant: str, rng: np.random.Generator, sigma: float) -> Draft:
    size = size_um(rng, 3.0, 20.0, 6 * sigma)
    c = Constraints(mode=mode_of(variant), travel_mm=(15.0, 80.0), min_duration_s=600.0)
    return Draft(c, lambda d, rng: [_thermal_for(d, size, rng)])


def _scale_for(d: SessionDesign, size: float, rng: np.random.Generator) -> ReferenceScale:
    s = size / d.travel_mm * 1000.0  # µm/m
    pivot = float(rng.uniform(d.plan.lo, d.plan.hi))
    angle = float(np.arccos(1.0 - s / 1e6) * 1e3)
    if rng.random() < 0.5 and angle <= 60.0:
        return ReferenceScale("cosine", cosine_scale_um_per_m(angle), pivot, angle)
    return ReferenceScale("gain", s * _sign(rng), pivot, None)


def _scale_draft(variant: str, rng: np.random.Generator, sigma: float) -> Draft:
    size = size_um(rng, 3.0, 30.0, 6 * sigma)
    return Draft(Constraints(mode=mode_of(variant)), lambda d, rng: [_scale_for(d, size, rng)])


def _ref_drift_for(d: SessionDesign, size: float, rng: np.random.Generator) -> ReferenceDrift:
    kinds = ("linear", "warmup", "sigmoid", "wander")
    curve = draw_time_curve(rng, d.plan.t_start, d.profile.t_end, kinds)
    return ReferenceDrift(size * _sign(rng), curve)


def _ref_drift_draft(variant: str, rng: np.random.Generator, sigma: float) -> Draft:
    size = size_um(rng, 3.0, 15.0, 6 * sigma)
    c = Constraints(mode=mode_of(variant), min_duration_s=300.0)
    return Draft(c, lambda d, rng: [_ref_drift_for(d, size, rng)])


def _clean_draft(variant: str, rng: np.random.Generator, sigma: float) -> Draft:
    return Draft(Constraints(mode=mode_of(variant)), lambda d, rng: [])


def _mixed_draft(variant: str, rng: np.random.Generator, sigma: float) -> Draft:
    """The ESS record's situation: ISO 230-2 cycles with stops, a reversal, a smooth curve, a
    thermal (or reference) drift, one ripple (reference, chirped or not, or the machine's) and a
    latency small against the ripple's period (2·v·τ ≤ 5 % of it, so that the reversal alone
    decides the ripple's source)."""
    kind = str(rng.choice(["triangulation", "constant", "periodic"], p=[0.5, 0.2, 0.3]))
    p_c = _logu(rng, 0.5, 5.0) if kind == "periodic" else _logu(rng, 0.12, 0.8)
    k = rng.uniform(2.5, 10.0)
    p_min = p_c * (1 - 1 / k) ** 2 if kind == "triangulation" else p_c
    rev = rng.uniform(10.0, 40.0) * _sign(rng, 0.8)
    travel = (max(8.0, 15 * p_c), min(60.0, max(8.0, 120 * p_c)))
    c = Constraints(
        mode=mode_of(variant),
        layout="iso",
        rest=True,
        speeds=1,
        travel_mm=travel,
        ds_max_mm=p_min / 6,
        max_cycles=2,
        min_duration_s=600.0,
    )
    amp = size_um(rng, 1.5, 12.0, 3 * sigma)
    sizes = {
        "smooth": size_um(rng, 4.0, 40.0, 8 * sigma),
        "drift": size_um(rng, 3.0, 20.0, 6 * sigma),
        "latency": size_um(rng, 2.0, 15.0, 4 * sigma),
    }
    reference_smooth, thermal, with_latency = rng.random(3) < (0.3, 0.7, 0.7)

    def build(d: SessionDesign, rng: np.random.Generator) -> list[Effect]:
        curve = draw_smooth(rng, *_span(d), sizes["smooth"])
        effects: list[Effect] = [
            Reversal(rev),
            ReferenceNonlinearity(curve) if reference_smooth else PositioningCurve(curve),
            _thermal_for(d, sizes["drift"], rng)
            if thermal
            else _ref_drift_for(d, sizes["drift"], rng),
        ]
        if kind == "periodic":
            phase = rng.uniform(0, 2 * np.pi)
            effects.append(PeriodicError(p_c, amp, phase, 0.0, 0.0))
        else:
            effects.append(_ripple(kind, p_c, k, amp, 0.0, d, rng))
        vmax = max(d.plan.speeds)
        tau = min(sizes["latency"] / 1000.0 / vmax, 0.15, 0.025 * p_min / vmax)
        if with_latency and vmax * tau * 1000.0 >= 4 * sigma and tau >= 0.005:
            effects.append(Latency(tau))
        return effects

    return Draft(c, build)


DRAFTS: dict[str, Callable[[str, np.random.Generator, float], Draft]] = {
    "smooth": lambda v, r, s: _smooth_draft(v, r, s, reference=False),
    "smooth_reference": lambda v, r, s: _smooth_draft(v, r, s, reference=True),
    "periodic": lambda v, r, s: _periodic_draft(v, r, s, "periodic"),
    "ripple_triangulation": lambda v, r, s: _periodic_draft(v, r, s, "triangulation"),
    "ripple_constant": lambda v, r, s: _periodic_draft(v, r, s, "constant"),
    "reversal": _reversal_draft,
    "latency": _latency_draft,
    "thermal_drift": _thermal_draft,
    "reference_scale": _scale_draft,
    "reference_drift": _ref_drift_draft,
    "mixed": _mixed_draft,
    "clean": _clean_draft,
}
