"""Truth labels: what a correct diagnosis names for each hidden effect, and with which source.

Computed here from the drawn session and the effects' own parameters, by the physics rules of
the lead's contract (/work/issues/24-contract.md, "The right source"); never from a diagnosis.

* ripple / periodic: a bidirectional session with a reversal r separates a reference-locked
  ripple from a position-locked one when the data can tell them apart: the noncentrality λ (the
  expected Δχ² between the true lock and the best imitation by the other lock, computed from the
  effect's own noise-free signal at the session's sample points and the generator's noise σ,
  :mod:`.separability`) is ≥ 25 (a 5σ separation). Then ``reference_ripple`` → ``reference``,
  ``periodic`` → ``machine``; otherwise (one direction, no reversal, a shift the noise hides)
  → ``either``. This replaces the fixed rule of the first version (r/p ≥ 0.2 of a period from an
  integer and |r| ≥ 5 µm), which called the issue's ESS ripple (27 µm against 0.22–0.47 mm,
  0.06–0.12 of a period, thousands of points, 4–35 µm of ripple against < 1 µm of noise)
  unseparable while the issue's own analysis separates it: separability is not a fraction of a
  period but signal lost by the imitation × points / noise;
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

from collections.abc import Callable, Sequence
from dataclasses import dataclass, field, replace

import numpy as np
from numpy.typing import NDArray

from .machine_effects import PeriodicError, PositioningCurve, Reversal, ThermalExpansion
from .reference_effects import (
    Latency,
    ReferenceDrift,
    ReferenceNonlinearity,
    ReferenceRipple,
    ReferenceScale,
)
from .separability import LAMBDA_MIN, drift_lambda, lock_lambda, uniform_drift_lambda

MIN_REST_ROWS = 3
FloatArray = NDArray[np.float64]


@dataclass(frozen=True)
class SessionFacts:
    """What the rules need to know of the session, measured on the rows written."""

    axis: str
    bidirectional: bool
    rest_rows: int
    n_speeds: int
    reversal_um: float  # |reversal| of the machine, 0 without one
    ref_centre_mm: float = 0.0  # centre of the travel the reference saw (its reading − offset)
    has_table: bool = False  # a smooth curve (the axis' table or the sensor's linearity) is hidden

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
    #: False: the session cannot show it as itself (a drift a table and a reversal imitate):
    #: naming it is right, naming nothing for it too (scored neither as named nor as missed)
    required: bool = True

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
            "required": self.required,
            **({"extra": self.extra} if self.extra else {}),
        }


def _short(v: object) -> str:
    return f"{v:.4g}" if isinstance(v, float) else str(v)


@dataclass(frozen=True)
class SamplePoints:
    """The session's rows as the separability rule needs them: the axis' position q at each
    sample instant (mm; the latency's own shift left out), the carriage position x there moved by
    the reversal alone (mm; q + d·r/2, r signed — the direction-dependent part of the machine's
    errors; what does not depend on the direction is a function of q, which a position-locked
    imitation may follow, and the drift's shift between passes in time is left out: conservative),
    the direction of the last motion there (±1) and the total noise σ of the observed error (µm)."""

    q_mm: FloatArray
    carriage_mm: FloatArray
    direction: FloatArray
    sigma_um: float
    t_s: FloatArray | None = None  # the sample instants (s): a drift's truth needs them


def _drift_hidden(
    family: str,
    cause: str,
    keys: dict[str, object],
    source: str,
    why: str,
    points: SamplePoints | None,
    signal_of: Callable[[FloatArray, FloatArray], FloatArray],
) -> Hidden:
    """A drift's truth: required only when the session can show it as a drift (λ ≥ 25 against
    a table and a reversal, :func:`.separability.drift_lambda`)."""
    if points is None or points.t_s is None:
        return Hidden(family, cause, keys, source, why)
    s = signal_of(points.q_mm, points.t_s)
    lam = drift_lambda(points.q_mm, points.direction, s, points.sigma_um)
    if lam >= LAMBDA_MIN:
        why = f"{why}; λ = {lam:.4g} against a table and a reversal"
        return Hidden(family, cause, keys, source, why, {"lambda": round(lam, 3)})
    why = f"{why}; λ = {lam:.4g} (< {LAMBDA_MIN:g}): a table and a reversal imitate it"
    return Hidden(family, cause, keys, source, why, {"lambda": round(lam, 3)}, required=False)


def _periodic_source(
    facts: SessionFacts,
    points: SamplePoints | None,
    signal_of: Callable[[FloatArray], FloatArray],
    phase_of: Callable[[FloatArray], FloatArray],
    locked: str,
) -> tuple[str, str, float]:
    """(source, why, λ) of a ripple locked to ``locked`` (``reference`` or ``machine``)."""
    if not facts.bidirectional:
        return "either", "one direction: nothing moves the ripple between passes", 0.0
    if points is None:
        raise ValueError("a bidirectional ripple's truth needs the session's sample points")
    lam = lock_lambda(
        points.q_mm,
        points.carriage_mm,
        points.direction,
        points.sigma_um,
        signal_of,
        phase_of,
        locked,
    )
    why = (
        f"bidirectional, reversal {facts.reversal_um:.2f} µm, σ {points.sigma_um:.3g} µm, "
        f"{points.q_mm.size} rows: λ = {lam:.4g}"
    )
    if lam >= LAMBDA_MIN:
        return locked, f"{why} (≥ {LAMBDA_MIN:g}): separable", lam
    return "either", f"{why} (< {LAMBDA_MIN:g}): not separable", lam


def _motion_evidence(facts: SessionFacts) -> bool:
    """Rows at rest or at two speeds: a velocity-proportional error shows as one."""
    return facts.has_rest or facts.n_speeds >= 2


def _truth_of(effect: object, facts: SessionFacts, points: SamplePoints | None) -> Hidden | str:
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
        p = effect.period_mm
        source, why, lam = _periodic_source(
            facts,
            points,
            lambda c: effect.error_um(c, np.ones_like(c), np.zeros_like(c)),
            lambda c: 2 * np.pi * c / p,
            "machine",
        )
        keys = {"axis": axis, "period_mm": effect.period_mm}
        return Hidden("periodic", "periodic", keys, source, why, {"lambda": round(lam, 3)})
    if isinstance(effect, ReferenceRipple):
        # the contract's period_mm: the period at the centre of the measured travel
        p_c = float(effect.local_period_mm(np.array([facts.ref_centre_mm]))[0])
        source, why, lam = _periodic_source(
            facts,
            points,
            lambda c: effect.error_um(c, np.zeros_like(c)),
            effect.phase_at,
            "reference",
        )
        keys = {"axis": axis, "law": effect.law, "period_mm": p_c}
        family = f"ripple_{effect.law}"
        extra = {**effect.describe(), "lambda": round(lam, 3)}
        return Hidden(family, "reference_ripple", keys, source, why, extra)
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
        keys = {"axis": axis}
        ref = effect
        return _drift_hidden(
            "reference_drift", "reference_drift", keys, "either", why, points, ref.error_um
        )
    if isinstance(effect, ThermalExpansion):
        why = f"expansion about {effect.fixed_point_mm:.2f} mm: a drift that depends on position"
        th = effect
        source = "machine"
        if points is not None and points.t_s is not None:
            s = th.error_um(points.q_mm, np.zeros_like(points.q_mm), points.t_s)
            lam = uniform_drift_lambda(
                points.q_mm,
                points.direction,
                points.t_s,
                s,
                points.sigma_um,
                facts.has_table,
                facts.bidirectional and facts.reversal_um > 0,
            )
            if lam < LAMBDA_MIN:
                source = "either"
                why = (
                    f"{why}, but a drift the same everywhere and what the session holds imitate "
                    f"it: λ = {lam:.4g} (< {LAMBDA_MIN:g}); the machine's or the reference's"
                )
        return _drift_hidden(
            "thermal_drift",
            "drift",
            {"axis": axis},
            source,
            why,
            points,
            lambda q, t: th.error_um(q, np.zeros_like(q), t),
        )
    raise TypeError(f"no truth rule for {type(effect).__name__}")


def truth_labels(
    effects: Sequence[object], facts: SessionFacts, points: SamplePoints | None = None
) -> tuple[list[Hidden], list[str]]:
    """Hidden identities to be named, and notes on effects for which naming nothing is right;
    ``points`` (the session's rows) are needed for a ripple in a bidirectional session."""
    hidden: list[Hidden] = []
    nothing: list[str] = []
    if any(isinstance(e, PositioningCurve | ReferenceNonlinearity) for e in effects):
        facts = replace(facts, has_table=True)
    for effect in effects:
        t = _truth_of(effect, facts, points)
        if isinstance(t, str):
            nothing.append(t)
        else:
            hidden.append(t)
    return hidden, nothing
