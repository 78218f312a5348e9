"""Extra model terms ("effects") beyond the rigid-body parametric model, and their registry.

An effect is a physically meaningful term with its own parameters (a parametric error that also
varies with another axis, bending with a temperature difference, a reversal step …). It plugs into
:meth:`compensation.Machine.volumetric_error` through three hooks, called in this order:

1. ``transform_signals(ctx)`` — change runtime signals before anything uses them (e.g. a thermal
   lag filters the temperatures along time);
2. ``modify_errors(ctx)`` — add to the parametric errors ``ctx.errors`` (N, 3 axes, 6) or the
   squareness ``ctx.squareness_urad`` (N, 3) before the kinematic chain: the term then gets its
   Abbe arms from the chain like any parametric error;
3. ``add_direct(ctx)`` — add a displacement (µm) to ``ctx.direct_um`` (N, 3) that does not go
   through the chain (thermal scale terms, probe lobing).

Effects are stored in the machine description as ``[[effects]]`` tables with a ``cause`` key
(FORMATS.md §4 names) and are created from them by :func:`effect_from_table`.
"""

from __future__ import annotations

import importlib
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from typing import Any, ClassVar

import numpy as np
from numpy.typing import NDArray

FloatArray = NDArray[np.float64]


@dataclass
class EvalContext:
    """Everything one evaluation of the model works on, for N points.

    ``q_mm`` indicated positions, ``u_mm = q − reference``, ``signals`` every runtime input as an
    (N,) array (temperatures °C, directions ±1, probing direction components, time s),
    ``errors`` (N, 3, 6) parametric errors per axis (µm, µrad), ``squareness_urad`` (N, 3),
    ``direct_um`` (N, 3) displacements added after the chain, ``reference_C`` the thermal reference.
    """

    q_mm: FloatArray
    u_mm: FloatArray
    signals: dict[str, FloatArray]
    errors: FloatArray
    squareness_urad: FloatArray
    direct_um: FloatArray
    reference_C: float
    reference_mm: FloatArray
    extras: dict[str, Any] = field(default_factory=dict)

    @property
    def n(self) -> int:
        return int(self.q_mm.shape[0])


class Effect:
    """Base class: subclasses set ``cause`` and override the hooks they need."""

    cause: ClassVar[str] = ""

    def signals(self) -> dict[str, float]:
        """Runtime signals this effect needs, with their reference (neutral) values."""
        return {}

    def transform_signals(self, ctx: EvalContext) -> None:
        """Hook 1: change ``ctx.signals`` in place."""

    def modify_errors(self, ctx: EvalContext) -> None:
        """Hook 2: add to ``ctx.errors`` / ``ctx.squareness_urad`` in place."""

    def add_direct(self, ctx: EvalContext) -> None:
        """Hook 3: add to ``ctx.direct_um`` in place."""

    def to_table(self) -> dict[str, Any]:
        """The ``[[effects]]`` table that recreates this effect (``cause`` included)."""
        raise NotImplementedError

    def describe(self) -> dict[str, Any]:
        """Diagnosis-contract keys (FORMATS.md §4): cause, component/axis…, parameters."""
        return self.to_table()


EffectFactory = Callable[[Mapping[str, Any]], Effect]
_REGISTRY: dict[str, EffectFactory] = {}


def register_effect(cause: str, factory: EffectFactory) -> None:
    """Make ``[[effects]] cause = <cause>`` tables loadable."""
    _REGISTRY[cause] = factory


def known_causes() -> list[str]:
    _load_builtin_effects()
    return sorted(_REGISTRY)


def effect_from_table(table: Mapping[str, Any]) -> Effect:
    """Create an effect from its TOML table; ValueError naming the cause and the known ones."""
    _load_builtin_effects()
    cause = table.get("cause")
    if not isinstance(cause, str) or cause not in _REGISTRY:
        raise ValueError(f"unknown effect cause {cause!r}; known: {', '.join(sorted(_REGISTRY))}")
    return _REGISTRY[cause](table)


def _load_builtin_effects() -> None:
    # The concrete effects live in compensation.effects, which registers them on import.
    try:
        importlib.import_module(f"{__package__}.effects")
    except ModuleNotFoundError as exc:  # optional module: only its own absence is tolerated
        if exc.name != f"{__package__}.effects":
            raise
