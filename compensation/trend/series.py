"""Effect series: what the diagnoses of one machine's sessions said about each named effect.

An effect is recognised across sessions by its *identity*: its ``label`` when the entry has one
(the diagnosis' short name, e.g. ``reversal(axis=x)``), else its ``cause`` and the string- or
integer-valued keys that name it (``axis``, ``component``, ``varies_with``, ``lobes`` …). Nothing
here knows the causes: any entry of the ``effects`` list of a ``cmm-comp diagnose --json`` object
(docs/formats.md §4) is taken as it comes, and its numeric ``parameters`` (numbers, lists of
numbers as ``name[i]``, nested tables as ``name.key``) become one series each.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from datetime import date
from typing import Any

import numpy as np

__all__ = [
    "EffectSeries",
    "SessionEffects",
    "effect_identity",
    "effect_series",
    "numeric_parameters",
]

#: Keys of an effect entry that describe the result, not which effect it is.
NOT_IDENTITY = frozenset(
    {
        "cause",
        "parameters",
        "explained_fraction",
        "label",
        "alternatives",
        "separate_by",
        "compensable",
        "source",
        "locked_to",
        "evidence",
    }
)


@dataclass(frozen=True)
class SessionEffects:
    """One diagnosed session of a machine: its date, where it came from (``path``) and the
    ``effects`` list of its diagnosis."""

    day: date
    path: str
    effects: Sequence[Mapping[str, Any]]


def effect_identity(entry: Mapping[str, Any]) -> tuple[str, str, dict[str, Any]]:
    """``(name, cause, keys)`` of one effect entry (module docstring)."""
    cause = str(entry.get("cause", "?"))
    keys = {
        k: v
        for k, v in entry.items()
        if k not in NOT_IDENTITY and isinstance(v, str | int) and not isinstance(v, bool)
    }
    label = entry.get("label")
    if isinstance(label, str) and label:
        return label, cause, keys
    inner = ",".join(f"{k}={v}" for k, v in sorted(keys.items()))
    return f"{cause}({inner})", cause, keys


def numeric_parameters(parameters: Any, prefix: str = "") -> dict[str, float]:
    """The finite numbers of a ``parameters`` table, flattened (``name``, ``name[i]``,
    ``name.key``); strings, booleans and non-finite values are left out."""
    out: dict[str, float] = {}
    if isinstance(parameters, Mapping):
        for k, v in parameters.items():
            out.update(numeric_parameters(v, f"{prefix}.{k}" if prefix else str(k)))
    elif isinstance(parameters, list | tuple):
        for i, v in enumerate(parameters):
            out.update(numeric_parameters(v, f"{prefix}[{i}]"))
    elif (
        isinstance(parameters, int | float)
        and not isinstance(parameters, bool)
        and math.isfinite(parameters)
    ):
        out[prefix] = float(parameters)
    return out


@dataclass
class EffectSeries:
    """One effect over a machine's sessions: ``named[i]`` whether session ``i`` named it, and per
    parameter an array over the sessions (NaN where the session did not name it)."""

    name: str
    cause: str
    keys: dict[str, Any]
    named: np.ndarray
    parameters: dict[str, np.ndarray] = field(default_factory=dict)


def effect_series(sessions: Sequence[SessionEffects]) -> dict[str, EffectSeries]:
    """Every effect named in any of ``sessions`` (in date order: sort them first), by name.

    Two entries of one identity in a session (two cyclic errors of one axis) become ``name``
    and ``name #2`` (by ``explained_fraction``, the larger first)."""
    n = len(sessions)
    out: dict[str, EffectSeries] = {}
    for i, session in enumerate(sessions):
        ranked = sorted(
            session.effects, key=lambda e: -float(e.get("explained_fraction", 0.0) or 0.0)
        )
        seen: dict[str, int] = {}
        for entry in ranked:
            name, cause, keys = effect_identity(entry)
            seen[name] = seen.get(name, 0) + 1
            if seen[name] > 1:
                name = f"{name} #{seen[name]}"
            series = out.get(name)
            if series is None:
                series = out[name] = EffectSeries(name, cause, keys, np.zeros(n, dtype=bool))
            series.named[i] = True
            for pname, value in numeric_parameters(entry.get("parameters", {})).items():
                column = series.parameters.get(pname)
                if column is None:
                    column = series.parameters[pname] = np.full(n, np.nan)
                column[i] = value
    return dict(sorted(out.items()))
