"""Identities of causes, read from the contract (docs/formats.md §4) and nothing else.

An effect's identity is ``(cause, component, axis, varies_with)`` where only the keys the
contract gives that cause count; the others are None (``lobes``, ``period_mm``,
``time_constant_s`` are parameters, not identity).
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any

#: cause → the identity keys docs/formats.md §4 gives it.
IDENTITY_KEYS: dict[str, tuple[str, ...]] = {
    "coupling": ("component", "varies_with"),
    "thermal_gradient": ("axis",),
    "thermal_lag": (),
    "scale_expansion": ("axis",),
    "workpiece_expansion": (),
    "squareness_drift": ("component",),
    "reversal": ("axis",),
    "periodic": ("axis",),
    "parametric": ("component",),
    "probe_lobing": (),
    "drift": ("axis",),
    "unexplained": (),
}

CAUSES: tuple[str, ...] = tuple(IDENTITY_KEYS)


@dataclass(frozen=True, order=True)
class Identity:
    """What a diagnosis must name for one effect."""

    cause: str
    component: str | None = None
    axis: str | None = None
    varies_with: str | None = None

    def __post_init__(self) -> None:
        if self.cause not in IDENTITY_KEYS:
            raise ValueError(f"unknown cause {self.cause!r}; allowed: {', '.join(CAUSES)}")
        for key in ("component", "axis", "varies_with"):
            present = getattr(self, key) is not None
            if present != (key in IDENTITY_KEYS[self.cause]):
                raise ValueError(
                    f"{self.cause}: identity key {key!r} "
                    + ("is not part of this cause" if present else "is required")
                )

    def label(self) -> str:
        keys = [f"{k}={getattr(self, k)}" for k in IDENTITY_KEYS[self.cause]]
        return f"{self.cause}({', '.join(keys)})" if keys else self.cause

    def as_dict(self) -> dict[str, str]:
        out = {"cause": self.cause}
        for key in IDENTITY_KEYS[self.cause]:
            value = getattr(self, key)
            assert value is not None
            out[key] = value
        return out


def identity_from_entry(entry: Mapping[str, Any]) -> Identity | None:
    """The identity of one JSON effect or alternative; None when its cause is not in §4.

    Only the keys of the contract count; values are compared in lower case.
    """
    cause = entry.get("cause")
    if not isinstance(cause, str) or cause not in IDENTITY_KEYS:
        return None
    values: dict[str, str | None] = {}
    for key in IDENTITY_KEYS[cause]:
        value = entry.get(key)
        if value is None and isinstance(entry.get("parameters"), Mapping):
            value = entry["parameters"].get(key)
        values[key] = str(value).lower() if value is not None else "?"
    return Identity(cause=cause, **values)
