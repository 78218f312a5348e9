"""Scoring a diagnosis JSON (docs/formats.md §4) against a case's truth, as a user would read it.

A hidden effect is **named** when an entry of ``effects`` states its identity, as the entry's own
``cause`` and keys or as one of its ``alternatives``; it is **named exactly** when, in addition,
that entry's ``source`` is the truth's (for an ``either`` entry the entry's ``source`` is judged,
not the alternative's — the lead's contract). Identities:

==========================  =========================================================
cause                       keys compared
==========================  =========================================================
``parametric``              ``component`` (``dx_x``/``dy_y``/``dz_z`` of the axis)
``reference_nonlinearity``  ``axis``
``periodic``                ``axis``, ``period_mm`` (within ±10 %)
``reference_ripple``        ``axis``, ``law``, ``period_mm`` (period at the centre, ±10 %)
``reversal``, ``latency``,  ``axis``
``reference_scale``,
``reference_drift``,
``drift``
==========================  =========================================================

A key is read at the entry's (or alternative's) top level, else in its ``parameters``; a key the
truth needs that the entry lacks is a mismatch. Entries and hidden effects are paired one to one
(an optimal assignment: exact pairs first, then named ones); an entry left unpaired is
**spurious** (also a second entry for one hidden effect: one physical cause must be one entry).
A session whose truth names nothing (clean, or only effects for which naming nothing is right)
is a **false alarm** when the verdict is not ``none`` or any effect is listed. A hidden effect
that is not ``required`` (a drift the session cannot show as one, truth.py) takes part in the
pairing — an entry naming it is not spurious — but is neither named nor missed in the rates.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from scipy.optimize import linear_sum_assignment

from .truth import Hidden

PERIOD_TOLERANCE = 0.10
SOURCES = ("machine", "reference", "either")


def _value(ident: Mapping[str, Any], key: str) -> Any:
    if key in ident:
        return ident[key]
    params = ident.get("parameters")
    if isinstance(params, Mapping) and key in params:
        return params[key]
    return None


def identity_mismatch(hidden: Hidden, ident: Mapping[str, Any]) -> str | None:
    """None when ``ident`` (an entry or an alternative) states the hidden identity; else why not."""
    if ident.get("cause") != hidden.cause:
        return f"cause {ident.get('cause')!r}"
    for key, want in hidden.keys.items():
        got = _value(ident, key)
        if got is None:
            return f"no {key}"
        if key == "period_mm":
            try:
                ratio = float(got) / float(want)  # type: ignore[arg-type]
            except (TypeError, ValueError, ZeroDivisionError):
                return f"period_mm {got!r}"
            if not abs(ratio - 1.0) <= PERIOD_TOLERANCE:
                return f"period_mm {float(got):.5g} (hidden {float(want):.5g})"  # type: ignore[arg-type]
        elif str(got).lower() != str(want).lower():
            return f"{key} {got!r}"
    return None


def entry_label(entry: Mapping[str, Any]) -> str:
    keys = [
        f"{k}={_fmt(_value(entry, k))}"
        for k in ("axis", "component", "varies_with", "law", "period_mm")
        if _value(entry, k) is not None
    ]
    return f"{entry.get('cause')}({','.join(keys)})/{entry.get('source', '?')}"


def _fmt(v: Any) -> str:
    return f"{v:.4g}" if isinstance(v, float) else str(v)


@dataclass
class HiddenScore:
    hidden: Hidden
    named: bool = False
    exact: bool = False
    via: str = ""  # primary | alternative
    entry: str = ""
    entry_source: str | None = None
    locked_to: str | None = None
    why_not: str = ""

    def as_dict(self) -> dict[str, Any]:
        return {
            "hidden": self.hidden.label,
            "family": self.hidden.family,
            "source": self.hidden.source,
            "named": self.named,
            "exact": self.exact,
            "via": self.via,
            "entry": self.entry,
            "entry_source": self.entry_source,
            "locked_to": self.locked_to,
            "why_not": self.why_not,
        }


@dataclass
class Score:
    per_hidden: list[HiddenScore]
    spurious: list[str]
    verdict: str
    expects_nothing: bool
    bad_sources: list[str] = field(default_factory=list)
    optional: list[str] = field(default_factory=list)  # hidden, not required (truth.Hidden)

    @property
    def false_alarm(self) -> bool:
        return self.expects_nothing and (self.verdict != "none" or bool(self.spurious))

    @property
    def all_exact(self) -> bool:
        return all(h.exact for h in self.per_hidden) and not self.spurious

    def as_dict(self) -> dict[str, Any]:
        return {
            "verdict": self.verdict,
            "per_hidden": [h.as_dict() for h in self.per_hidden],
            "spurious": self.spurious,
            "false_alarm": self.false_alarm,
            "all_exact": self.all_exact,
            "bad_sources": self.bad_sources,
            "optional": self.optional,
        }


def _pair_quality(hidden: Hidden, entry: Mapping[str, Any]) -> tuple[int, str, str]:
    """(0 none, 1 named via alternative, 2 named as the primary; +2 when the source is right),
    how, and why not."""
    why = identity_mismatch(hidden, entry)
    via = "primary" if why is None else ""
    if not via:
        for alt in entry.get("alternatives") or []:
            if isinstance(alt, Mapping) and identity_mismatch(hidden, alt) is None:
                via = "alternative"
                break
    if not via:
        return 0, "", why or ""
    q = 2 if via == "primary" else 1
    return q + (2 if entry.get("source") == hidden.source else 0), via, ""


def score_diagnosis(
    hidden: Sequence[Hidden], output: Mapping[str, Any], expects_nothing: bool | None = None
) -> Score:
    """Pair the diagnosis' entries with the hidden effects (see the module's docstring)."""
    entries = [e for e in output.get("effects") or [] if isinstance(e, Mapping)]
    n_h, n_e = len(hidden), len(entries)
    quality = np.zeros((n_h, n_e))
    how: dict[tuple[int, int], str] = {}
    for i, h in enumerate(hidden):
        for j, e in enumerate(entries):
            q, via, _ = _pair_quality(h, e)
            quality[i, j] = q
            how[i, j] = via
    rows, cols = linear_sum_assignment(-quality) if n_h and n_e else ([], [])
    paired = {int(i): int(j) for i, j in zip(rows, cols, strict=True) if quality[i, j] > 0}
    scores: list[HiddenScore] = []
    optional: list[str] = []
    for i, h in enumerate(hidden):
        if not h.required:  # an entry naming it is not spurious; naming nothing is no miss
            optional.append(h.label + (" (named)" if i in paired else ""))
            continue
        s = HiddenScore(h)
        if i in paired:
            e = entries[paired[i]]
            s.named, s.via, s.entry = True, how[i, paired[i]], entry_label(e)
            s.entry_source = e.get("source")
            s.locked_to = e.get("locked_to")
            s.exact = s.entry_source == h.source
            if not s.exact:
                s.why_not = f"source {s.entry_source!r}, want {h.source!r}"
        else:
            reasons = [_pair_quality(h, e)[2] for e in entries]
            reasons.sort(key=lambda r: r.startswith("cause"))  # same cause, wrong key first
            s.why_not = "not named" + (f" (closest: {'; '.join(reasons[:3])})" if reasons else "")
        scores.append(s)
    used = set(paired.values())
    spurious = [entry_label(e) for j, e in enumerate(entries) if j not in used]
    bad = [entry_label(e) for e in entries if e.get("source") not in SOURCES]
    nothing = (n_h == 0) if expects_nothing is None else expects_nothing
    return Score(scores, spurious, str(output.get("verdict")), nothing, bad, optional)
