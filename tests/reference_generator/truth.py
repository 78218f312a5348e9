"""Truth labels: what a correct diagnosis names for each hidden effect, and with which source.

Computed here from the drawn session and the effects' own parameters, by the physics rules of
the lead's contract (/work/issues/24-contract.md, "The right source"); never from a diagnosis.

* ripple / periodic: a bidirectional session with a reversal r separates a reference-locked
  ripple from a position-locked one when the phase shift 2π·r/p is clearly non-zero modulo 2π:
  the distance of r/p to the nearest integer ≥ 0.2 at the period at the centre of the travel,
  and |r| ≥ 5 µm. Then ``reference_ripple`` → ``reference``, ``periodic`` → ``machine``;
  otherwise (one direction, no reversal, r/p near an integer) → ``either``;
* a smooth curve (positioning table or sensor linearity) → ``either``;
* latency: rows at rest or ≥ 2 cruise speeds → ``reference``; else bidirectional → ``either``
  (it is a reversal there); one direction at one speed → a constant offset: naming nothing is
  right;
* reversal: bidirectional with rows at rest or ≥ 2 speeds → ``machine``; bidirectional, one
  speed, no rest → ``either`` (it is a latency there); one direction → invisible: nothing;
* reference scale → ``either``; reference drift (the same at every position) → ``either``;
  thermal expansion about a point (a drift that depends on position) → ``drift``, ``machine``.

Identities: ``parametric`` by ``component`` (dx_x, dy_y, dz_z of the measured axis), every other
cause by ``axis``; ``periodic`` also by ``period_mm`` and ``reference_ripple`` by ``law`` and
``period_mm`` (the period at the centre of the travel the reference saw: the middle of its
readings' range, the constant offset between the instruments removed).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field

import numpy as np

from .machine_effects import PeriodicError, PositioningCurve, Reversal, ThermalExpansion
from .reference_effects import (
    Latency,
    ReferenceDrift,
    ReferenceNonlinearity,
    ReferenceRipple,
    ReferenceScale,
)

MIN_REVERSAL_UM = 5.0
MIN_PHASE_FRACTION = 0.2
MIN_REST_ROWS = 3


@dataclass(frozen=True)
class SessionFacts:
    """What the rules need to know of the session, measured on the rows written."""

    axis: str
    bidirectional: bool
    rest_rows: int
    n_speeds: int
    reversal_um: float  # |reversal| of the machine, 0 without one
    ref_centre_mm: float = 0.0  # centre of the travel the reference saw (its reading − offset)

    @property
    def has_rest(self) -> bool:
        return self.rest_rows >= MIN_REST_ROWS


@dataclass(frozen=True)
class Hidden:
    """One effect a correct diagnosis names: ``cause`` with ``keys``, from ``source``."""

    family: str
    cause: str
    keys: dict[str, object]
    source: str
    rule: str
    extra: dict[str, object] = field(default_factory=dict)

    @property
    def label(self) -> str:
        keys = ",".join(f"{k}={_short(v)}" for k, v in self.keys.items())
        return f"{self.cause}({keys})/{self.source}"

    def as_dict(self) -> dict[str, object]:
        return {
            "label": self.label,
            "family": self.family,
            "cause": self.cause,
            "keys": self.keys,
            "source": self.source,
            "rule": self.rule,
            **({"extra": self.extra} if self.extra else {}),
        }


def _short(v: object) -> str:
    return f"{v:.4g}" if isinstance(v, float) else str(v)


def separation(reversal_um: float, period_mm: float) -> tuple[bool, float]:
    """(separable, distance of r/p to the nearest integer) for a reversal r (µm), period p (mm)."""
    ratio = abs(reversal_um) / 1000.0 / period_mm
    frac = ratio - np.floor(ratio)
    dist = float(abs(frac - round(frac)))
    return abs(reversal_um) >= MIN_REVERSAL_UM and dist >= MIN_PHASE_FRACTION, dist


def _periodic_source(facts: SessionFacts, period_mm: float, locked: str) -> tuple[str, str]:
    sep, dist = separation(facts.reversal_um, period_mm)
    why = f"reversal {facts.reversal_um:.2f} µm, period {period_mm:.5g} mm: r/p {dist:.3f} from an integer"
    if not facts.bidirectional:
        return "either", "one direction: nothing moves the ripple between passes"
    if sep:
        return locked, f"bidirectional, {why} (≥ {MIN_PHASE_FRACTION}): separable"
    return "either", f"bidirectional, {why}: not separable"


def _motion_evidence(facts: SessionFacts) -> bool:
    """Rows at rest or at two speeds: a velocity-proportional error shows as one."""
    return facts.has_rest or facts.n_speeds >= 2


def _truth_of(effect: object, facts: SessionFacts) -> Hidden | str:
    axis = facts.axis
    motion = f"{facts.rest_rows} rows at rest, {facts.n_speeds} speed(s)"
    if isinstance(effect, PositioningCurve):
        return Hidden(
            "smooth",
            "parametric",
            {"component": f"d{axis}_{axis}"},
            "either",
            "a smooth curve barely moves with a reversal: table or sensor linearity",
        )
    if isinstance(effect, ReferenceNonlinearity):
        return Hidden(
            "smooth_reference",
            "reference_nonlinearity",
            {"axis": axis},
            "either",
            "a smooth curve barely moves with a reversal: sensor linearity or table",
        )
    if isinstance(effect, PeriodicError):
        source, why = _periodic_source(facts, effect.period_mm, "machine")
        keys = {"axis": axis, "period_mm": effect.period_mm}
        return Hidden("periodic", "periodic", keys, source, why)
    if isinstance(effect, ReferenceRipple):
        # the contract's period_mm: the period at the centre of the measured travel
        p_c = float(effect.local_period_mm(np.array([facts.ref_centre_mm]))[0])
        source, why = _periodic_source(facts, p_c, "reference")
        keys = {"axis": axis, "law": effect.law, "period_mm": p_c}
        family = f"ripple_{effect.law}"
        return Hidden(family, "reference_ripple", keys, source, why, effect.describe())
    if isinstance(effect, Reversal):
        if not facts.bidirectional:
            return "reversal in a one-directional session: a constant offset, invisible"
        source = "machine" if _motion_evidence(facts) else "either"
        return Hidden("reversal", "reversal", {"axis": axis}, source, f"bidirectional, {motion}")
    if isinstance(effect, Latency):
        if _motion_evidence(facts):
            return Hidden("latency", "latency", {"axis": axis}, "reference", motion)
        if facts.bidirectional:
            why = f"bidirectional, {motion}: a reversal"
            return Hidden("latency", "latency", {"axis": axis}, "either", why)
        return (
            f"latency in a one-directional session at one speed without rest ({motion}): an offset"
        )
    if isinstance(effect, ReferenceScale):
        return Hidden(
            "reference_scale",
            "reference_scale",
            {"axis": axis},
            "either",
            "a scale term of the reference is a scale error of the axis",
        )
    if isinstance(effect, ReferenceDrift):
        why = "the same at every position: the reference's or a uniform drift of the machine"
        return Hidden("reference_drift", "reference_drift", {"axis": axis}, "either", why)
    if isinstance(effect, ThermalExpansion):
        why = f"expansion about {effect.fixed_point_mm:.2f} mm: a drift that depends on position"
        return Hidden("thermal_drift", "drift", {"axis": axis}, "machine", why)
    raise TypeError(f"no truth rule for {type(effect).__name__}")


def truth_labels(effects: Sequence[object], facts: SessionFacts) -> tuple[list[Hidden], list[str]]:
    """Hidden identities to be named, and notes on effects for which naming nothing is right."""
    hidden: list[Hidden] = []
    nothing: list[str] = []
    for effect in effects:
        t = _truth_of(effect, facts)
        if isinstance(t, str):
            nothing.append(t)
        else:
            hidden.append(t)
    return hidden, nothing
