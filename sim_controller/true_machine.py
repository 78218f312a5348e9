"""The simulated true machine: the user's model plus hidden causes (docs/formats.md §4) plus noise.

:func:`random_effect` draws one cause with random shape/parameters (component, axis, period,
time constant …); :func:`scale_effect` scales its amplitude parameters so that the effect's 3-D
RMS displacement over a session equals a requested size. :class:`TrueMachine` holds the model the
user has, the hidden effects and the noise, and measures sessions.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from cmm_comp.compensation.effects import (
    CouplingEffect,
    Effect,
    ParametricEffect,
    PeriodicEffect,
    ProbeLobingEffect,
    ReversalEffect,
    default_orders,
    effect_from_table,
)
from cmm_comp.compensation.formats.measurements import Measurements
from cmm_comp.compensation.machine import Machine
from cmm_comp.compensation.parametric_errors import ANGULAR, AXES, SQUARENESS, TABLE_COMPONENTS
from cmm_comp.compensation.thermal import (
    ScaleExpansionEffect,
    SquarenessDriftEffect,
    ThermalGradientEffect,
    ThermalLagEffect,
    WorkpieceExpansionEffect,
)

from .sessions import SessionPlan, measure_session, plan_session, true_error_um

__all__ = [
    "HIDDEN_CAUSES",
    "TrueMachine",
    "effect_rms_um",
    "random_effect",
    "scale_effect",
]

HIDDEN_CAUSES: tuple[str, ...] = (
    "coupling",
    "thermal_gradient",
    "thermal_lag",
    "scale_expansion",
    "workpiece_expansion",
    "squareness_drift",
    "reversal",
    "periodic",
    "parametric",
    "probe_lobing",
)

#: Amplitude (linear) parameters of each cause's table: scaling them scales the effect.
_AMPLITUDE_KEYS: dict[str, tuple[str, ...]] = {
    "parametric": ("coefficients",),
    "coupling": ("coefficients",),
    "thermal_gradient": ("curvature_urad_per_m_C",),
    "thermal_lag": ("fraction",),
    "scale_expansion": ("delta_expansion",),
    "workpiece_expansion": ("delta_expansion",),
    "squareness_drift": ("urad_per_C",),
    "reversal": ("half_step_um",),
    "periodic": ("a_cos_um", "b_sin_um"),
    "probe_lobing": ("a_cos_um", "b_sin_um"),
}


def _span(machine: Machine, axis: str) -> tuple[float, float]:
    k = AXES.index(axis)
    return float(machine.volume.lower_mm[k]), float(machine.volume.upper_mm[k])


def random_effect(cause: str, machine: Machine, rng: np.random.Generator) -> Effect:
    """One effect of ``cause`` with random discrete choices and shape, unit-ish amplitude."""
    axis = str(rng.choice(AXES))
    ref_c = machine.thermal.reference_C
    if cause == "parametric":
        comp = str(rng.choice([*TABLE_COMPONENTS, *SQUARENESS]))
        orders = default_orders(comp)
        coef = [rng.normal() / max(k, 1) for k in orders]
        span = _span(machine, comp[-1]) if comp not in SQUARENESS else (0.0, 1.0)
        return ParametricEffect(comp, coef, span, orders)
    if cause == "coupling":
        comp = str(rng.choice(ANGULAR))
        other = str(rng.choice([a for a in AXES if a != comp[-1]]))
        return CouplingEffect(
            comp,
            other,
            [rng.normal(), 0.5 * rng.normal()],
            _span(machine, comp[-1]),
            _span(machine, other),
        )
    if cause == "thermal_gradient":
        eff: Any = ThermalGradientEffect(axis, rng.choice([-1.0, 1.0]))
    elif cause == "thermal_lag":
        eff = ThermalLagEffect(float(rng.uniform(900.0, 3600.0)), 1.0)
        return eff
    elif cause == "scale_expansion":
        eff = ScaleExpansionEffect(axis, rng.choice([-1.0, 1.0]))
    elif cause == "workpiece_expansion":
        fixture = (
            machine.thermal.workpiece_fixture_mm
            if machine.thermal.workpiece_fixture_mm is not None
            else (machine.volume.lower_mm + machine.volume.upper_mm) / 2
        )
        eff = WorkpieceExpansionEffect(rng.choice([-1.0, 1.0]), list(map(float, fixture)))
    elif cause == "squareness_drift":
        eff = SquarenessDriftEffect(str(rng.choice(SQUARENESS)), rng.choice([-1.0, 1.0]))
    elif cause == "reversal":
        return ReversalEffect(
            axis, [rng.choice([-1.0, 1.0]), 0.3 * rng.normal()], _span(machine, axis)
        )
    elif cause == "periodic":
        lo, hi = _span(machine, axis)
        period = (hi - lo) / float(np.exp(rng.uniform(np.log(4.0), np.log(30.0))))
        phase = rng.uniform(0, 2 * np.pi)
        return PeriodicEffect(axis, period, float(np.cos(phase)), float(np.sin(phase)))
    elif cause == "probe_lobing":
        phase = rng.uniform(0, 2 * np.pi)
        return ProbeLobingEffect(3, float(np.cos(phase)), float(np.sin(phase)))
    else:
        raise ValueError(f"unknown cause {cause!r}; known: {', '.join(HIDDEN_CAUSES)}")
    eff.reference_C = ref_c
    return eff


def scale_effect(effect: Effect, factor: float) -> Effect:
    """A copy of ``effect`` with its amplitude parameters multiplied by ``factor``."""
    table = effect.to_table()
    for key in _AMPLITUDE_KEYS[effect.cause]:
        v = table[key]
        table[key] = [factor * x for x in v] if isinstance(v, list) else factor * v
    return effect_from_table(table)


def effect_rms_um(machine: Machine, effect: Effect, data: Measurements) -> float:
    """3-D RMS (µm) of the displacement ``effect`` adds to ``machine`` over the points of ``data``."""
    d = true_error_um(machine.with_effects([effect]), data) - true_error_um(machine, data)
    return float(np.sqrt(np.mean(np.sum(d**2, axis=1))))


@dataclass
class TrueMachine:
    """The truth: ``model`` (what the user's machine.toml says) plus ``hidden`` effects, noise."""

    model: Machine
    hidden: list[Effect] = field(default_factory=list)
    noise_um: float = 0.5  # Gaussian, per axis (1σ)

    @property
    def machine(self) -> Machine:
        return self.model.with_effects(self.hidden) if self.hidden else self.model

    @property
    def noise_rms_3d_um(self) -> float:
        """3-D RMS of the noise: √3·σ."""
        return float(np.sqrt(3.0) * self.noise_um)

    def measure(self, plan: SessionPlan, rng: np.random.Generator) -> Measurements:
        return measure_session(self.machine, plan, self.noise_um, rng)

    @classmethod
    def random(
        cls,
        model: Machine,
        causes: Sequence[str],
        sizes: Sequence[float],
        rng: np.random.Generator,
        plan: SessionPlan,
        noise_um: float = 0.5,
    ) -> TrueMachine:
        """Hidden effects of ``causes`` whose 3-D RMS over ``plan`` is ``size × noise RMS`` each."""
        hidden: list[Effect] = []
        noise_rms = float(np.sqrt(3.0) * noise_um)
        for cause, size in zip(causes, sizes, strict=True):
            eff = random_effect(cause, model, rng)
            rms = effect_rms_um(model, eff, plan.data)
            hidden.append(scale_effect(eff, size * noise_rms / rms))
        return cls(model=model, hidden=hidden, noise_um=noise_um)


def simulate(
    model: Machine,
    causes: Sequence[str],
    sizes: Sequence[float],
    seed: int,
    *,
    noise_um: float = 0.5,
    n_points: int = 700,
) -> tuple[TrueMachine, Measurements]:
    """One simulated case: a session planned on ``model``, hidden ``causes`` at ``sizes`` (×
    noise RMS), measured. Deterministic for a ``seed``."""
    rng = np.random.default_rng(seed)
    plan = plan_session(model, rng, n_points=n_points)
    truth = TrueMachine.random(model, causes, sizes, rng, plan, noise_um)
    return truth, truth.measure(plan, rng)
