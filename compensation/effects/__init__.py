"""effects: model terms beyond the rigid-body parametric model, and their registry.

* :mod:`.base` — :class:`Effect`, :class:`EvalContext`, the cause registry and the helpers every
  effect shares;
* :mod:`.parametric` — corrections of the parametric errors (``parametric``, ``coupling``,
  ``reversal``); :mod:`.periodic` — cyclic errors (``periodic``), their period laws in
  :mod:`.period_law`;
* :mod:`.probe` — probe lobing;
* :mod:`.drift` — an axis' error drifting with time (``drift``: diagnosis only).

The temperature-driven effects (``thermal_gradient``, ``thermal_lag``, ``scale_expansion``,
``workpiece_expansion``, ``squareness_drift``) live with the other thermal terms in
:mod:`cmm_comp.compensation.thermal`; the registry knows every cause.
"""

from __future__ import annotations

from .base import Effect, EvalContext, effect_from_table, known_causes, register_effect
from .drift import DriftEffect
from .parametric import (
    CouplingEffect,
    ParametricEffect,
    ReversalEffect,
    default_orders,
    legendre_shape,
    normalised,
)
from .period_law import PeriodLaw
from .periodic import PeriodicEffect, ripple_columns, ripple_terms
from .probe import ProbeLobingEffect, lobing_signals
from .static_image import StaticImageEffect

__all__ = [
    "CouplingEffect",
    "DriftEffect",
    "Effect",
    "EvalContext",
    "ParametricEffect",
    "PeriodLaw",
    "PeriodicEffect",
    "ProbeLobingEffect",
    "ReversalEffect",
    "StaticImageEffect",
    "default_orders",
    "effect_from_table",
    "known_causes",
    "legendre_shape",
    "lobing_signals",
    "normalised",
    "register_effect",
    "ripple_columns",
    "ripple_terms",
]
