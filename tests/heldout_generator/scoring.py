"""Scoring a diagnosis JSON (docs/formats.md §4) against the hidden identities, as a user would.

* ``named``: the diagnosis names exactly as many effects as were hidden, and they can be paired
  one to one so that each hidden identity is the entry's own identity or one of its
  ``alternatives`` (explanations the session cannot tell apart, which the contract allows).
* ``strict``: the same, alternatives ignored.
* A clean session (nothing hidden) is right only with ``verdict == "none"`` and no effects.
* ``heldout_ok``: ``heldout_rms_um.after ≤ 1.5 ×`` the noise's 3-D RMS (σ·√3).
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from itertools import product
from typing import Any

from .identity import Identity, identity_from_entry

HELDOUT_LIMIT = 1.5


@dataclass
class Score:
    named: bool
    strict: bool
    heldout_ok: bool
    heldout_ratio: float | None
    verdict: str | None
    named_labels: list[str] = field(default_factory=list)
    missing: list[str] = field(default_factory=list)
    extra: list[str] = field(default_factory=list)
    error: str | None = None

    def as_dict(self) -> dict[str, Any]:
        return dict(self.__dict__)


def _entry_label(
    own: Identity | None, entry: Mapping[str, Any], alts: list[Identity | None]
) -> str:
    label = own.label() if own else f"?{entry.get('cause')!r}"
    names = [a.label() for a in alts if a is not None]
    return label + (f" [alt: {', '.join(names)}]" if names else "")


def _matches(hidden: Sequence[Identity], covers: list[set[Identity]]) -> bool:
    """Can each entry stand for one hidden identity from its cover so that all are stood for?"""
    wanted = set(hidden)
    options = [cover & wanted for cover in covers]
    if any(not o for o in options):
        return False
    return any(set(choice) == wanted for choice in product(*options))


def score_diagnosis(
    hidden: Sequence[Identity], result: Mapping[str, Any] | None, noise_rms_3d_um: float
) -> Score:
    """Score one diagnosis output; ``result`` None means the command produced no JSON."""
    if result is None or not isinstance(result.get("effects", []), list):
        return Score(False, False, False, None, None, error="no diagnosis JSON")
    verdict = result.get("verdict")
    entries = [e for e in result.get("effects", []) if isinstance(e, Mapping)]
    own = [identity_from_entry(e) for e in entries]
    alts = [
        [identity_from_entry(a) for a in e.get("alternatives", []) if isinstance(a, Mapping)]
        for e in entries
    ]
    strict_covers = [{o} if o else set() for o in own]
    covers = [
        ({o} if o else set()) | {a for a in alt if a is not None}
        for o, alt in zip(own, alts, strict=True)
    ]
    if hidden:
        named = verdict == "found" and _matches(hidden, covers)
        strict = verdict == "found" and _matches(hidden, strict_covers)
    else:
        named = strict = verdict == "none" and not entries
    heldout = result.get("heldout_rms_um")
    after = heldout.get("after") if isinstance(heldout, Mapping) else None
    ratio = float(after) / noise_rms_3d_um if isinstance(after, int | float) else None
    all_covered = set().union(*covers) if covers else set()
    return Score(
        named=named,
        strict=strict,
        heldout_ok=ratio is not None and ratio <= HELDOUT_LIMIT,
        heldout_ratio=ratio,
        verdict=verdict if isinstance(verdict, str) else None,
        named_labels=[_entry_label(o, e, a) for o, e, a in zip(own, entries, alts, strict=True)],
        missing=[h.label() for h in hidden if h not in all_covered],
        extra=[
            _entry_label(o, e, a)
            for o, e, a, cov in zip(own, entries, alts, covers, strict=True)
            if not (cov & set(hidden))
        ],
    )
