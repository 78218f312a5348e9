"""The diagnosis' outcome: each named term as a docs/formats.md §4 entry (its cause, fitted
parameters, share explained, source, coordinate, evidence, alternatives) and the session's
statistics before and after.

Sources and coordinates come from :mod:`.sources` (the twins' test), a cyclic error's figures
from :mod:`.periods` (peak and subsets) and :mod:`.locking` (shift between directions, phase
from pass to pass); explanations the session cannot tell apart from :mod:`.alternatives` and
from the twins within the band, each with its source.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from ..effects import Effect
from ..formats.measurements import Measurements
from ..machine import Machine
from .alternatives import find_alternatives
from .candidate import Candidate, contract_keys
from .fitting import Problem, Term, cv_predictions, fit, predictions, split_coefficients
from .locking import cyclic_locking
from .periods import CYCLIC, check_period, partial_residual
from .residuals import Residuals, length_error_e0_um, rms3d
from .sources import SourceCall, twins_of
from .unexplained import is_local

__all__ = [
    "SEPARATE_BY",
    "Diagnosis",
    "Finding",
    "describe_terms",
    "public_refusal",
    "session_summary",
]

#: How to tell the two instruments apart, per pair of twin causes.
SEPARATE_BY: dict[frozenset[str], str] = {
    frozenset({"periodic", "reference_ripple"}): (
        "passes in both directions with a reversal that moves the cyclic error's phase clearly "
        "(at least a fifth of its period), or the reference mounted at another distance"
    ),
    frozenset({"parametric", "reference_nonlinearity"}): (
        "a second reference instrument, or the same one at another distance: a positioning "
        "error stays with the axis, a sensor's nonlinearity moves with its reading"
    ),
    frozenset({"parametric", "reference_scale"}): (
        "the reference's alignment and environment checked (beam aligned to the axis, "
        "wavelength compensated), or a second reference"
    ),
    frozenset({"scale_expansion", "reference_scale"}): (
        "the reference's environment logged beside the scale's temperature"
    ),
    frozenset({"reversal", "latency"}): "points at rest, or passes at a second speed",
    frozenset({"drift", "reference_drift"}): (
        "a fixed point measured again during the session (a reference drift moves it "
        "everywhere alike), or the temperatures logged"
    ),
}


@dataclass
class Diagnosis:
    """The outcome: effects found (as model effects), statistics before/after, what was tried."""

    verdict: str
    effects: list[Effect]
    entries: list[dict[str, Any]]  # docs/formats.md §4 "effects" entries
    residuals: Residuals
    fitted_um: Any  # (N, 3) in-sample prediction of the effects found
    heldout_pred_um: Any  # (N, 3) out-of-fold prediction
    summary: dict[str, Any]
    rounds: list[list[dict[str, Any]]] = field(default_factory=list)
    terms: list[Term] = field(default_factory=list)  # the accepted terms, in ``effects`` order
    problem: Problem | None = None
    #: per effect: the entry's source (``machine``, ``reference``, ``either``)
    sources: list[str] = field(default_factory=list)
    #: for an ``either`` entry whose primary is the reference's: the machine's version, fitted
    either_machine: list[Effect] = field(default_factory=list)

    def to_json(self) -> dict[str, Any]:
        return {"verdict": self.verdict, "effects": self.entries, **self.summary}

    def machine_effects(self, include_either: bool = False) -> list[Effect]:
        """What ``extend`` adds: the compensable effects whose source is the machine, with
        ``include_either`` also those the session cannot assign (a reference-primary entry by
        its machine version); never the reference's."""
        sources = self.sources or ["machine"] * len(self.effects)
        out = [
            e
            for e, s in zip(self.effects, sources, strict=True)
            if e.compensable
            and e.source == "machine"
            and (s == "machine" or (include_either and s == "either"))
        ]
        if include_either:
            out += [e for e in self.either_machine if e.compensable]
        return out

    def extended_machine(self, include_either: bool = False) -> Machine:
        """The machine with :meth:`machine_effects` added (a ``drift`` describes the session but
        cannot be predicted at run time, a reference's effect is not the machine's: neither is
        added)."""
        return self.residuals.machine.with_effects(self.machine_effects(include_either))


@dataclass
class Finding:
    """What selection hands over: the named terms, their family candidates and source calls."""

    problem: Problem
    accepted: list[Term]
    roots: list[Candidate]
    calls: list[SourceCall]
    pool: list[Candidate]  # every global candidate and twin
    alpha: float
    refused_periods: list[dict[str, Any]] = field(default_factory=list)
    #: the candidates of the forward search (alternatives are sought among them; the twins
    #: only through :mod:`.sources`: a smooth function of the reading beside the machine's
    #: smooth tables would explain the observed error by itself)
    searched: list[Candidate] = field(default_factory=list)


def _keys(cand: Candidate) -> dict[str, Any]:
    keys = {
        k: v
        for k, v in zip(("cause", "component", "axis", "varies_with"), cand.identity, strict=True)
        if v is not None
    }
    return {**keys, "source": cand.source, "locked_to": cand.locked_to}


def _twin_alternatives(
    f: Finding, call: SourceCall, cause: str, coefs_of: Callable[[Term], Effect]
) -> tuple[list[dict[str, Any]], Effect | None]:
    """The twins within the band as alternatives, each with its identifying keys and fitted
    parameters (a period, a ripple's law: what names it); the machine's version of a
    reference term."""
    out: list[dict[str, Any]] = []
    machine: Effect | None = None
    for t, delta in call.alternatives:
        advice = SEPARATE_BY.get(frozenset({cause, t.candidate.cause}), "")
        twin = coefs_of(t)
        described = twin.describe()
        out.append(
            {
                **described,
                **_keys(t.candidate),
                "parameters": described.get("parameters", {}),
                "delta_chi2": delta,
                "separated_by": advice,
            }
        )
        if t.candidate.source == "machine" and machine is None:
            machine = twin
    return out, machine


def _unique(alts: list[dict[str, Any]]) -> list[dict[str, Any]]:
    """One alternative per identity (the first: a twin's, with its source test)."""
    seen: set[tuple[Any, ...]] = set()
    out = []
    for a in alts:
        key = tuple(a.get(k) for k in ("cause", "component", "axis", "varies_with"))
        if key not in seen:
            seen.add(key)
            out.append(a)
    return out


def _evidence(f: Finding, index: int, beta: Any, call: SourceCall, label: str) -> dict[str, Any]:
    term, root = f.accepted[index], f.roots[index]
    ev: dict[str, Any] = {"summary": call.summary(label), "twins": call.twins}
    if root.cause in CYCLIC:
        check = check_period(f.problem, f.accepted, index, beta)
        ev.update(check.evidence())
        cyclic_twins = twins_of(root, f.pool, term.theta)
        twin = cyclic_twins[0] if cyclic_twins else None
        if twin is not None and term.candidate is not root and twin.rich is not None:
            twin = twin.rich
        ev["locking"] = cyclic_locking(f.problem, f.accepted, index, beta, twin)
    axis = root.keys.get("axis") or str(root.keys.get("component", ""))[-1:]
    if root.cause == "reversal":
        ev.update(_reversal_by_state(f, index, beta, axis))
    if root.cause in ("parametric", "reference_nonlinearity"):
        refused = [public_refusal(r) for r in f.refused_periods if r.get("axis") == axis]
        if refused:
            ev["refused_periods"] = refused
    return ev


def _reversal_by_state(f: Finding, index: int, beta: Any, axis: str) -> dict[str, Any]:
    """The reversal (µm, error after − minus after + approach) seen at rest and while moving,
    from the residual with the reversal term added back: at rest it is the drive's alone; while
    moving a latency between the streams adds to it."""
    res = f.problem.res
    k = "xyz".index(axis)
    d = res.signals.get(f"dir_{axis}")
    v = res.signals.get(f"v_{axis}")
    if d is None or v is None:
        return {}
    y = partial_residual(f.problem, f.accepted, beta, {index})[:, k]
    out: dict[str, Any] = {}
    for name, state in (("at_rest_um", v == 0), ("moving_um", v != 0)):
        plus, minus = state & (d > 0), state & (d < 0)
        if plus.sum() >= 3 and minus.sum() >= 3:
            out[name] = float(np.mean(y[minus]) - np.mean(y[plus]))
    return {"reversal_by_state": out} if out else {}


def describe_terms(
    f: Finding, say: Callable[[str], None]
) -> tuple[list[dict[str, Any]], list[Effect], list[str], list[Effect], list[Term], Any]:
    """Entries, effects, sources, machine versions of reference-primary ``either`` entries and
    terms (all ordered by importance), and the joint fit's coefficients."""
    problem, accepted = f.problem, f.accepted
    beta, rss_after, rank_after = fit(problem, accepted, ridge=True)
    coefs = split_coefficients(problem, accepted, beta)
    causes = [i for i, t in enumerate(accepted) if not is_local(t.candidate)]
    rss_before = float(np.sum(problem.y**2))
    sigma2 = rss_after / max(problem.y.size - rank_after, 1)
    causes_pool = [c for c in (f.searched or f.pool) if not is_local(c)]
    rows: list[tuple[dict[str, Any], Effect, str, Effect | None, Term]] = []
    if causes:
        say("sources, evidence and alternatives")
    for i in causes:
        t, call = accepted[i], f.calls[i]
        eff = t.candidate.build(coefs[i], t.theta)
        others = accepted[:i] + accepted[i + 1 :]

        def coefs_of(twin: Term, others: list[Term] = others) -> Effect:
            b, _, _ = fit(problem, [*others, twin], ridge=True)
            return twin.candidate.build(
                split_coefficients(problem, [*others, twin], b)[-1], twin.theta
            )

        _, rss_without, _ = fit(problem, others)
        entry: dict[str, Any] = {
            **contract_keys(eff),
            "parameters": eff.describe().get("parameters", {}),
        }
        entry["explained_fraction"] = (rss_without - rss_after) / rss_before if rss_before else 0.0
        entry["label"] = t.candidate.label
        entry["source"] = call.source
        entry["locked_to"] = call.locked_to
        entry["evidence"] = _evidence(f, i, beta, call, t.candidate.label)
        twin_alts, machine = _twin_alternatives(f, call, t.candidate.cause, coefs_of)
        alt = find_alternatives(
            problem, others, t, eff, causes_pool, f.roots, rss_after, sigma2, f.alpha
        )
        alts = _unique(twin_alts + (alt["alternatives"] if alt is not None else []))
        if alts:
            entry["alternatives"] = alts
            advice = [f"{a['cause']}: {a['separated_by']}" for a in alts if a["separated_by"]]
            entry["separate_by"] = "; ".join(advice)
        if not eff.compensable:
            entry["compensable"] = False
        either_machine = machine if call.source == "either" and eff.source != "machine" else None
        rows.append((entry, eff, call.source, either_machine, t))
    rows.sort(key=lambda r: -r[0]["explained_fraction"])
    return (
        [r[0] for r in rows],
        [r[1] for r in rows],
        [r[2] for r in rows],
        [r[3] for r in rows if r[3] is not None],
        [r[4] for r in rows],
        beta,
    )


def session_summary(
    problem: Problem,
    data: Measurements,
    n_given: int,
    accepted: Sequence[Term],
    fitted: Any,
    heldout_pred: Any,
    held_folds: Any,
    extra: dict[str, Any],
) -> dict[str, Any]:
    """The statistics before and after (docs/formats.md §4)."""
    r_before = problem.res.residual_um
    r_after = r_before - fitted
    r_heldout = r_before - heldout_pred
    beta, rss_after, rank_after = fit(problem, list(accepted), ridge=True)
    sigma2 = rss_after / max(problem.y.size - rank_after, 1)
    # "before" is the model as described with the same nuisance offsets removed (in-sample and
    # held out), so before/after differ by the effects found and nothing else
    beta0, _, _ = fit(problem, [])
    r_before_in = r_before - predictions(problem, [], beta0)
    r_before_out = r_before - cv_predictions(problem, [], folds=held_folds)
    return {
        "residual_rms_um": {"before": rms3d(r_before_in), "after": rms3d(r_after)},
        "heldout_rms_um": {"before": rms3d(r_before_out), "after": rms3d(r_heldout)},
        "e0_um": {
            "before": length_error_e0_um(data.reference_mm, r_before_out, data.group),
            "after": length_error_e0_um(data.reference_mm, r_heldout, data.group),
            "definition": "max |length error| over point pairs of one group (artefact "
            "position); 'after' uses out-of-fold predictions",
        },
        "noise_sigma_um": float(np.sqrt(sigma2)),
        "offset_um": {
            "xyz"[k]: float(v)
            for k, v in zip(problem.axes, beta[: problem.n_nuisance], strict=False)
        },
        "n_points": int(data.n),
        "n_points_given": int(n_given),
        "measured_axes": ["xyz"[k] for k in problem.axes],
        "folds": len(problem.folds),
        "heldout_method": (
            "grouped cross-validation: each fold predicted by the effects fitted on the other "
            "folds (nonlinear parameters re-profiled near the full-data value)"
            if held_folds is None
            else "cross-validation on short blocks of time dealt out to the folds (a drift or a "
            "start-up transient is named: no cause of time predicts hours it never saw); each "
            "fold predicted by the effects fitted on the others"
        ),
        **extra,
    }


def public_refusal(refusal: dict[str, Any]) -> dict[str, Any]:
    """A refused period as the diagnosis JSON shows it: without ``candidate``, the search's
    in-process identity of the refused candidate (an object id, different on every run)."""
    return {k: v for k, v in refusal.items() if k != "candidate"}
