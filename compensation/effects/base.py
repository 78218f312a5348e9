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
(docs/formats.md §4 names) and are created from them by :func:`effect_from_table`. This module also
holds what every concrete effect shares: reading its table's parameters and adding its term to
the context. Units: positions mm, linear errors µm, angles µrad, temperatures °C, time s.
"""

from __future__ import annotations

import importlib
import math
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from typing import Any, ClassVar

import numpy as np
from numpy.typing import NDArray

from ..parametric_errors import AXES, AXIS_INDEX, SQUARENESS, parse_component

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
    #: False for effects that describe a session but cannot be predicted at run time (a drift
    #: with time): ``cmm-comp extend`` leaves them out of the extended machine.
    compensable: ClassVar[bool] = True
    #: Which instrument carries the effect: ``"machine"`` (what compensation corrects) or
    #: ``"reference"`` (the instrument that measured it: never added to a machine).
    source: ClassVar[str] = "machine"

    def signals(self) -> dict[str, float]:
        """Runtime signals this effect needs, with their reference (neutral) values."""
        return {}

    def transform_signals(self, ctx: EvalContext) -> None:
        """Hook 1: change ``ctx.signals`` in place."""

    def modify_errors(self, ctx: EvalContext) -> None:
        """Hook 2: add to ``ctx.errors`` / ``ctx.squareness_urad`` in place."""

    def add_direct(self, ctx: EvalContext) -> None:
        """Hook 3: add to ``ctx.direct_um`` in place."""

    def shortest_wavelength_mm(self) -> dict[str, float]:
        """Per axis, the shortest spatial wavelength (mm) of this effect's shape along it: what
        a correction grid's node spacing must resolve (empty for effects no finer than a few
        oscillations over the volume, which the default grid already follows)."""
        return {}

    def to_table(self) -> dict[str, Any]:
        """The ``[[effects]]`` table that recreates this effect (``cause`` included)."""
        raise NotImplementedError

    def describe(self) -> dict[str, Any]:
        """Diagnosis-contract keys (docs/formats.md §4): cause, component/axis…, parameters."""
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
    for key, wrap in _WRAPPERS.items():  # e.g. a thermal effect and its static image
        if key in table:
            return wrap(table, _REGISTRY[cause])
    return _REGISTRY[cause](table)


#: Table keys that wrap an effect in another (``static_image``): key → (table, plain factory)
#: → effect. Registered by the wrapping module (:mod:`.static_image`).
_WRAPPERS: dict[str, Callable[[Mapping[str, Any], EffectFactory], Effect]] = {}


def register_wrapper(
    key: str, factory: Callable[[Mapping[str, Any], EffectFactory], Effect]
) -> None:
    """Make ``[[effects]]`` tables with ``key`` load through ``factory``."""
    _WRAPPERS[key] = factory


#: Modules defining the built-in effects; each registers its causes when imported.
BUILTIN_EFFECT_MODULES: tuple[str, ...] = (
    "cmm_comp.compensation.effects.parametric",
    "cmm_comp.compensation.effects.periodic",
    "cmm_comp.compensation.effects.drift",
    "cmm_comp.compensation.effects.probe",
    "cmm_comp.compensation.effects.static_image",
    "cmm_comp.compensation.thermal.distortion",
    "cmm_comp.compensation.thermal.expansion",
    "cmm_comp.compensation.thermal.lag",
)


def _load_builtin_effects() -> None:
    # Imported on first use, not here: the thermal effects import this module.
    for name in BUILTIN_EFFECT_MODULES:
        importlib.import_module(name)


# ----------------------------------------------------------------------------- table parameters
def read_axis(value: Any, what: str = "axis") -> str:
    """``value`` as an axis name ``x``/``y``/``z``; ValueError naming ``what`` otherwise."""
    if value not in AXES:
        raise ValueError(f"{what} must be one of x, y, z, got {value!r}")
    return str(value)


def read_str(table: Mapping[str, Any], key: str) -> str:
    """``table[key]`` as a string; a missing (or null) key is a ValueError naming the key."""
    value = table.get(key)
    if value is None:
        raise ValueError(f"{key} is required")
    if not isinstance(value, str):
        raise ValueError(f"{key} must be a string, got {value!r}")
    return value


def read_span(value: Any, what: str) -> tuple[float, float]:
    """``[lo, hi]`` (mm) with ``hi > lo``."""
    try:
        lo, hi = (float(v) for v in value)
    except (TypeError, ValueError):
        raise ValueError(f"{what} must be [lo, hi] in mm, got {value!r}") from None
    if not hi > lo:
        raise ValueError(f"{what} must have hi > lo, got {value!r}")
    return lo, hi


def read_floats(value: Any, what: str, n: int | None = None) -> list[float]:
    """A list of finite numbers (exactly ``n`` when given)."""
    try:
        out = [float(v) for v in value]
    except (TypeError, ValueError):
        raise ValueError(f"{what} must be a list of numbers, got {value!r}") from None
    if n is not None and len(out) != n:
        raise ValueError(f"{what} must have {n} values, got {len(out)}")
    if not all(math.isfinite(v) for v in out):
        raise ValueError(f"{what} must be finite, got {value!r}")
    return out


def read_number(table: Mapping[str, Any], key: str, default: float | None = None) -> float:
    """``table[key]`` as a finite number (``default`` when absent; required without one)."""
    if key not in table:
        if default is None:
            raise ValueError(f"missing key {key!r}")
        return default
    try:
        v = float(table[key])
    except (TypeError, ValueError):
        raise ValueError(f"{key} must be a number, got {table[key]!r}") from None
    if not math.isfinite(v):
        raise ValueError(f"{key} must be finite, got {v}")
    return v


# ----------------------------------------------------------------------------- context helpers
def add_to_component(ctx: EvalContext, component: str, value: FloatArray) -> None:
    """Add ``value`` (N,) to a parametric error (µm, µrad) or a squareness (µrad) of ``ctx``."""
    if component in SQUARENESS:
        ctx.squareness_urad[:, SQUARENESS.index(component)] += value
    else:
        c = parse_component(component)
        ctx.errors[:, AXIS_INDEX[c.axis], c.slot] += value


def signal_or(ctx: EvalContext, name: str, default: float) -> FloatArray:
    """The runtime signal ``name`` as (N,) values, ``default`` everywhere when not given."""
    v = ctx.signals.get(name)
    return np.full(ctx.n, default) if v is None else np.asarray(v, dtype=float)
