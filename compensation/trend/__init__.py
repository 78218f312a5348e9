"""Trends over a machine's diagnosed sessions: effect series, change tests, a plain summary.

Modules: :mod:`.series` (effects recognised across sessions, their numeric parameters),
:mod:`.changepoint` (presence, line and step tests with valid p-values), :mod:`.machine` (one
machine's trend, changes at a stated false-alarm rate, and what to recalibrate). Pure
numpy/scipy on the JSON of ``cmm-comp diagnose`` (docs/formats.md §4); used by
``cmm-comp fleet diagnose`` (docs/fleet.md).
"""

from .changepoint import line_fit, presence_change, smallest_presence_p, step_change, trend_change
from .machine import PERSISTENT_SHARE, TrendSettings, machine_trend
from .series import EffectSeries, SessionEffects, effect_identity, effect_series, numeric_parameters

__all__ = [
    "PERSISTENT_SHARE",
    "EffectSeries",
    "SessionEffects",
    "TrendSettings",
    "effect_identity",
    "effect_series",
    "line_fit",
    "machine_trend",
    "numeric_parameters",
    "presence_change",
    "smallest_presence_p",
    "step_change",
    "trend_change",
]
