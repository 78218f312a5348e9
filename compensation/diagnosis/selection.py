"""Greedy, out-of-sample model selection: which causes explain the residuals.

Each round, every remaining candidate is fitted jointly with the effects accepted so far
(nonlinear parameter profiled). A candidate is *eligible* when its nested-model F-test p-value,
Bonferroni-corrected for the number of candidates and for the look-elsewhere effect of its scanned
parameter, is below ``alpha``, and its grouped cross-validated MSE improves on the current model's
by at least ``min_cv_gain`` (relative). The eligible candidate with the best CV MSE is accepted
(among CV scores within 0.5 % of the best, the one with fewest parameters: the simpler
explanation). Rounds stop when no candidate is eligible. Then a generic smooth model (position,
time, temperatures, directions) tests whether structure remains that no cause explains
(``unexplained``). Verdict ``none`` when nothing is eligible.
"""

from __future__ import annotations

import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field, replace
from typing import Any

import numpy as np
from numpy.typing import NDArray

from ..formats.measurements import Measurements
from ..machine import Machine
from .candidates import Candidate, all_candidates, all_twins, is_finite_design
from .consistency import spatial_consistency
from .fitting import (
    Problem,
    Term,
    best_theta,
    cv_mse,
    cv_predictions,
    f_test_p,
    fit,
    make_problem,
    one_blas_thread,
    predictions,
)
from .leftover import UNEXPLAINED_SOURCE, leftover_entry
from .merge import one_for_several
from .outcome import Diagnosis, Finding, describe_terms, public_refusal, session_summary
from .periods import CYCLIC, check_period
from .reading import denoised_reading
from .residuals import Residuals, compute_residuals
from .sources import decide_sources
from .steps import (
    Slot,
    backward,
    choose_variants,
    model_cv,
    other_gain,
    reprofile,
    slow_noise,
    terms_of,
)
from .unexplained import is_local, local_candidates

__all__ = ["Diagnosis", "diagnose"]

#: Candidates whose CV MSE is within this fraction of the best are equally good: the one with
#: fewer parameters (the simpler explanation) is taken. 0.5 % is below what separates two
#: explanations on a few hundred points (paired CV differences of that size come and go with
#: the fold assignment).
SIMPLER_WITHIN = 0.005


def _round(
    problem: Problem, slots: list[Slot], pool: list[Candidate], search: _Search
) -> tuple[Term | None, list[dict[str, Any]]]:
    """One forward step. New candidates are tested against the accepted causes at their *rich*
    shape, so what a mis-shaped accepted cause leaves behind (same signal, same axis, same Abbe
    arms) is absorbed by it and never named as a second cause. A pick that fails the volume
    consistency test (:mod:`.consistency`) is not taken; it is appended to ``local_hits`` and the
    next eligible candidate is considered."""
    n_tried, alpha, min_cv_gain = search.n_tried, search.alpha, search.min_cv_gain
    cv_base, local_hits, refused = search.cv_history[-1], search.local_hits, search.refused
    base = terms_of(slots, rich=True)
    n_obs = problem.y.size
    _, rss0, rank0 = fit(problem, base)
    rows: list[dict[str, Any]] = []
    for cand in pool:
        theta, rss1, extra = best_theta(problem, base, cand)
        p = f_test_p(rss0, rss1, extra, n_obs, rank0 + extra)
        static = cand.static(problem.res, theta)
        if static is not None and p < alpha:
            # a signal-driven cause must be seen in the signal's variation, not its mean
            base_s = [*base, Term(static)]
            _, rss0s, rank0s = fit(problem, base_s)
            _, rss1s, rank1s = fit(problem, [*base_s, Term(cand, theta)])
            p = max(p, f_test_p(rss0s, rss1s, rank1s - rank0s, n_obs, rank1s))
        p_adj = min(1.0, p * n_tried * cand.look_elsewhere)
        rows.append(
            {"candidate": cand, "theta": theta, "label": cand.label, "rss": rss1, "p_adj": p_adj}
        )
    eligible = [r for r in rows if r["p_adj"] < alpha]
    rows.sort(key=lambda r: r["rss"])
    if not eligible:
        return None, rows
    # out-of-sample gain against the model as it stands (the rich shapes only absorb leftovers
    # in the significance test: with few points they would overfit the comparison)
    current = terms_of(slots)
    folds = problem.judged_folds(current)
    if folds is not None:
        cv_base = cv_mse(problem, current, folds=folds)
    for r in eligible:
        with_it = [*current, Term(r["candidate"], r["theta"])]
        r["cv_mse"] = cv_mse(problem, with_it, folds=folds)
        r["cv_gain"] = (cv_base - r["cv_mse"]) / cv_base if cv_base > 0 else 0.0
        timed = other_gain(problem, current, with_it, folds) if r["candidate"].timed else None
        if timed is not None and timed > r["cv_gain"]:
            # a drift or a start-up transient may also be judged between neighbours in time
            r["cv_gain"] = timed
            r["cv_mse"] = cv_base * (1.0 - timed)
    eligible = [r for r in eligible if r["cv_gain"] >= min_cv_gain]
    while eligible:
        best_cv = min(r["cv_mse"] for r in eligible)
        close = [r for r in eligible if r["cv_mse"] <= best_cv * (1.0 + SIMPLER_WITHIN)]
        pick = min(close, key=lambda r: (r["candidate"].n_params, r["cv_mse"]))
        if not is_local(pick["candidate"]):
            pick = _leaner_family(problem, current, eligible, pick, folds) or pick
        term = Term(pick["candidate"], pick["theta"])
        if is_local(term.candidate):
            family = _family_rather_than_bump(problem, current, eligible, pick["cv_mse"], folds)
            return family or term, rows
        if term.candidate.cause in CYCLIC:
            period = check_period(problem, [*current, term], len(current), subsets=False)
            if not period.ok:
                # not a period (a flank of a smooth curve, or not the same in every subset):
                # never named; its shape is left to the smooth tables
                refused.append(_refusal(term, period.evidence()))
                eligible = [r for r in eligible if r is not pick]
                continue
        check = spatial_consistency(problem, [*current, term], len(current))
        if not check.local:
            return term, rows
        # significant, but not the same law across the volume: a local defect soaked up by a
        # global shape — never named as that cause (reported as unexplained by the caller)
        pick["local"] = check.ratios
        local_hits.append(pick)
        eligible = [r for r in eligible if r is not pick]
    return None, rows


def _refusal(term: Term, evidence: dict[str, Any]) -> dict[str, Any]:
    theta = term.theta
    return {
        "label": term.candidate.label,
        "axis": term.candidate.keys.get("axis"),
        "period_mm": float(theta[1] if isinstance(theta, tuple) else theta),
        "candidate": id(term.candidate),
        **evidence,
    }


#: How many of the best global families are tried at their rich shape against a local bump.
RICH_CHALLENGERS = 3


def _leaner_family(
    problem: Problem,
    current: list[Term],
    eligible: list[dict[str, Any]],
    pick: dict[str, Any],
    folds: Sequence[NDArray[np.intp]] | None,
) -> dict[str, Any] | None:
    """A pick wins by its shape, not by its number of parameters: the best few families leaner
    at their default shape than the pick whose rich shape has no more parameters than it (a
    table of order 8 against a bend with its slope, 14 parameters) are tried at that rich shape;
    where one predicts held-out points as well as the pick (within :data:`SIMPLER_WITHIN`), it
    is taken instead — the leanest such (its default candidate: the variant is chosen later with
    the others)."""
    n_pick = pick["candidate"].n_params
    leaner = sorted(
        (
            r
            for r in eligible
            if r is not pick
            and not is_local(r["candidate"])
            and r["candidate"].rich is not None
            and r["candidate"].n_params < n_pick
            and r["candidate"].rich.n_params <= n_pick
        ),
        key=lambda r: r["cv_mse"],
    )[:RICH_CHALLENGERS]
    good = [
        r
        for r in leaner
        if cv_mse(problem, [*current, Term(r["candidate"].rich, r["theta"])], folds=folds)
        <= pick["cv_mse"] * (1.0 + SIMPLER_WITHIN)
    ]
    # the leanest of them, as the pick itself is chosen among the close ones
    return min(good, key=lambda r: (r["candidate"].n_params, r["cv_mse"]), default=None)


def _family_rather_than_bump(
    problem: Problem,
    current: list[Term],
    eligible: list[dict[str, Any]],
    bump_cv: float,
    folds: Sequence[NDArray[np.intp]] | None = None,
) -> Term | None:
    """A local bump beat every cause at its default shape. Before structure is called
    ``unexplained``, the best few causes get their rich shape (a table of order 8 rather than 4,
    harmonics, …): where one of them predicts held-out points as well as the bump (within
    :data:`SIMPLER_WITHIN`), the structure *is* that cause, only shaped beyond its default, and
    the cause is returned (its default candidate: the variant is chosen later with the others).
    A bump that sits in one corner stays unexplained: no global shape follows it there."""
    globals_ = sorted(
        (r for r in eligible if not is_local(r["candidate"]) and r["candidate"].rich is not None),
        key=lambda r: r["cv_mse"],
    )[:RICH_CHALLENGERS]
    best: tuple[float, dict[str, Any]] | None = None
    for r in globals_:
        cand = r["candidate"]
        cv = cv_mse(problem, [*current, Term(cand.rich, r["theta"])], folds=folds)
        if cv <= bump_cv * (1.0 + SIMPLER_WITHIN) and (best is None or cv < best[0]):
            best = (cv, r)
    return None if best is None else Term(best[1]["candidate"], best[1]["theta"])


def _merge_causes(
    problem: Problem,
    slots: list[Slot],
    pool: list[Candidate],
    alpha: float,
    min_cv_gain: float,
    say: Callable[[str], None],
) -> bool:
    """Replace groups of accepted causes by one cause that does their work (:mod:`.merge`),
    as long as one does; True when anything changed. The new cause must pass the volume
    consistency test like any accepted cause."""
    changed = False
    while True:  # each merge names fewer causes: this ends
        causes = [i for i, s in enumerate(slots) if not is_local(s.root)]
        named = {slots[i].root.identity for i in causes}
        free = [c for c in pool if not is_local(c) and c.identity not in named]
        keep = [slots[i].term for i in range(len(slots)) if i not in causes]
        merge = one_for_several(
            problem, [slots[i].term for i in causes], free, alpha, SIMPLER_WITHIN, keep
        )
        if merge is None:
            return changed
        group = [causes[i] for i in merge.indices]
        kept = [s for i, s in enumerate(slots) if i not in group]
        new = [*terms_of(kept), merge.term]
        if spatial_consistency(problem, new, len(kept)).local:
            return changed
        if merge.term.candidate.cause in CYCLIC and not check_period(problem, new, len(kept)).ok:
            return changed
        say(
            f"  one cause for several: {merge.term.candidate.label} replaces "
            + ", ".join(slots[i].root.label for i in group)
        )
        slots[:] = [*kept, Slot(merge.term.candidate, merge.term)]
        reprofile(problem, slots)
        choose_variants(problem, slots, alpha, min_cv_gain)
        changed = True


@dataclass
class _Search:
    """The state of the forward search: causes named, excluded, rounds, refusals."""

    cv_history: list[float]
    n_tried: int
    alpha: float
    min_cv_gain: float
    slots: list[Slot] = field(default_factory=list)
    excluded: set[int] = field(default_factory=set)
    rounds: list[list[dict[str, Any]]] = field(default_factory=list)
    local_hits: list[dict[str, Any]] = field(default_factory=list)
    refused: list[dict[str, Any]] = field(default_factory=list)


#: Passes of forward search: a cyclic error refused by the final period test is removed and the
#: search resumed without it.
MAX_PASSES = 3


def _rounds(
    problem: Problem,
    pool: list[Candidate],
    search: _Search,
    max_effects: int,
    say: Callable[[str], None],
) -> None:
    """Forward steps with backward elimination until nothing is eligible."""
    slots = search.slots
    while len(slots) < max_effects:
        taken = {id(s.root) for s in slots} | search.excluded
        taken |= {r["candidate"] for r in search.refused}
        # one entry per identity (the shapes of one family compete, never both named); two
        # cyclic errors of one axis with different periods are two causes, and a local bump
        # is fitted per error component (one `unexplained` entry for all of them); a chirped
        # cyclic error is one object, whichever coordinate it was named in
        named = {
            s.root.identity for s in slots if s.root.cause not in CYCLIC and not is_local(s.root)
        }
        chirped = {s.root.keys.get("axis") for s in slots if s.root.theta_step is not None}
        remaining = [
            c
            for c in pool
            if id(c) not in taken
            and c.identity not in named
            and not (c.theta_step is not None and c.keys.get("axis") in chirped)
        ]
        say(f"round {len(search.rounds) + 1}: {len(remaining)} candidates")
        term, rows = _round(problem, slots, remaining, search)
        search.rounds.append(_public_rows(rows))
        if term is None:
            break
        slots.append(Slot(term.candidate, term))
        say(f"  accepted {term.candidate.label}")
        _after_change(problem, search, say)


def _after_change(problem: Problem, search: _Search, say: Callable[[str], None]) -> None:
    """Re-profile, choose shapes, drop what is no longer needed, score the model."""
    slots = search.slots
    n_tried, alpha, min_cv_gain = search.n_tried, search.alpha, search.min_cv_gain
    reprofile(problem, slots)
    choose_variants(problem, slots, alpha, min_cv_gain)
    dropped = backward(problem, slots, n_tried, alpha, min_cv_gain)
    for s in dropped:
        search.excluded.add(id(s.root))
        say(f"  dropped {s.root.label}: not needed given the others")
    if dropped:  # what a dropped cause carried may need the others' rich shapes now
        choose_variants(problem, slots, alpha, min_cv_gain)
    search.cv_history.append(model_cv(problem, terms_of(slots)))


def _final_periods(problem: Problem, search: _Search, say: Callable[[str], None]) -> bool:
    """The full period test (peak and subsets) of every cyclic error named, with the other
    causes now named beside it; those refused are removed (True when any was)."""
    removed = False
    for i in reversed(range(len(search.slots))):
        terms = terms_of(search.slots)
        if terms[i].candidate.cause not in CYCLIC:
            continue
        check = check_period(problem, terms, i)
        if not check.ok:
            slot = search.slots.pop(i)
            search.refused.append(_refusal(slot.term, check.evidence()))
            say(f"  refused {slot.root.label}: " + "; ".join(check.disagreements))
            removed = True
    if removed:
        _after_change(problem, search, say)
    return removed


def _carried_reading(problem: Problem, terms: Sequence[Term]) -> Problem:
    """The problem with the reading's coordinate (:func:`.reading.denoised_reading`) carrying
    the machine's named cyclic errors (a screw's, a scale's: the carriage, and the sensor's
    target with it, is where they put it; a smooth curve per pass cannot follow them) and
    without the sensor's own named cyclic error (``reference_ripple``: an error of the reading,
    not of where the sensor looked — left in, a stop's smooth part carries the ripple's value
    there, up to its amplitude). The problem itself when no cyclic error is named or the
    reading is raw."""
    res = problem.res
    causes = {t.candidate.cause for t in terms}
    if res.reading_mm is None or not causes & {"periodic", "reference_ripple"}:
        return problem
    beta, _, _ = fit(problem, terms)
    carried = np.zeros((res.n, 3))
    sensor = np.zeros((res.n, 3))
    col = problem.n_nuisance
    for t in terms:
        p = t.candidate.n_params
        if t.candidate.cause == "periodic":
            carried += t.candidate.design(res, t.theta) @ beta[col : col + p]
        elif t.candidate.cause == "reference_ripple":
            sensor += t.candidate.design(res, t.theta) @ beta[col : col + p]
        col += p
    reading = denoised_reading(res.data, carried, sensor)
    return replace(problem, res=replace(res, reading_mm=reading), _q_cache={})


def _cyclic_beside_ripple(problem: Problem, search: _Search, say: Callable[[str], None]) -> bool:
    """With the sensor's own ripple named and the reading's coordinate now without it
    (:func:`_carried_reading`), the machine's cyclic errors named beside it judged again, as
    backward elimination judges a cause: with the coordinate that carried the ripple's value at
    the stops, the ripple misfit there by up to its phase 2π·A/p, and small cyclic terms took
    that misfit up (0.15–0.19 µm beside an 8.6 µm triangulation ripple). True when any was
    dropped."""
    slots = search.slots
    if not any(s.root.cause == "reference_ripple" for s in slots):
        return False
    if not any(s.root.cause == "periodic" for s in slots):
        return False
    reprofile(problem, slots)
    dropped = backward(
        problem,
        slots,
        search.n_tried,
        search.alpha,
        search.min_cv_gain,
        causes=frozenset({"periodic"}),
    )
    for s in dropped:
        search.excluded.add(id(s.root))
        say(f"  dropped {s.root.label}: the sensor's ripple at the distance it looked at")
    if dropped:
        _after_change(problem, search, say)
    return bool(dropped)


def _resume_after_replacement(
    problem: Problem,
    pool: list[Candidate],
    search: _Search,
    roots: list[Candidate],
    accepted: list[Term],
    max_effects: int,
    say: Callable[[str], None],
) -> bool:
    """Where a named term was replaced by its twin (:func:`.sources.decide_sources`), the model
    changed shape: what the first term's rich shape absorbed (a drift that changes along the
    axis soaks up part of a smooth curve; a reference drift the same everywhere does not) may now
    be a cause of its own. The replacement is put in place, the first term's family excluded,
    and the forward search resumed; True when it named anything more (then the sources are to be
    decided again)."""
    slots = search.slots
    replaced = [i for i, s in enumerate(slots) if s.root is not roots[i]]
    if not replaced:
        return False
    for i in replaced:
        old = slots[i].root
        search.excluded |= {id(c) for c in pool if c.cause == old.cause and c.keys == old.keys}
        slots[i] = Slot(roots[i], accepted[i])
    before = [id(s.root) for s in slots]
    say("a term replaced by its twin: the search resumed")
    _after_change(problem, search, say)
    _rounds(problem, pool, search, max_effects, say)
    _final_periods(problem, search, say)  # a cyclic error named now is tested like the others
    slow_noise(problem, search.slots, search.n_tried, search.alpha, say)
    return [id(s.root) for s in slots] != before


def _search_all(
    problem: Problem,
    pool: list[Candidate],
    search: _Search,
    max_effects: int,
    alpha: float,
    min_cv_gain: float,
    say: Callable[[str], None],
) -> Problem:
    """The forward search's passes (a cyclic error refused by the final period test is removed
    and the search runs again), then the problem at the distance the sensor looked at."""
    for _ in range(MAX_PASSES):
        _rounds(problem, pool, search, max_effects, say)
        refused_ids = {r["candidate"] for r in search.refused}
        usable = [c for c in pool if id(c) not in refused_ids]
        if _merge_causes(problem, search.slots, usable, alpha, min_cv_gain, say):
            search.cv_history.append(model_cv(problem, terms_of(search.slots)))
        if not _final_periods(problem, search, say):
            break
    slow_noise(problem, search.slots, search.n_tried, search.alpha, say)
    # the distance the sensor looked at includes the machine's named cyclic errors, not the
    # sensor's own; with the sensor's ripple named, a cyclic error of the machine named beside
    # it is judged again there (:func:`_cyclic_beside_ripple`)
    refined = _carried_reading(problem, terms_of(search.slots))
    if refined is not problem and _cyclic_beside_ripple(refined, search, say):
        refined = _carried_reading(problem, terms_of(search.slots))
    return refined


def _sources(
    problem: Problem,
    res: Residuals,
    pool: list[Candidate],
    search: _Search,
    max_effects: int,
    alpha: float,
    say: Callable[[str], None],
) -> tuple[list[Term], list[Candidate], Any, list[Candidate]]:
    """Which instrument carries each named term, and which coordinate it is locked to:
    ``(accepted terms, their roots, the source calls, the twins)``; the search resumes once when
    a term was replaced by its twin."""
    slots = search.slots
    accepted = terms_of(slots)
    roots = [s.root for s in slots]
    twins = all_twins(res)
    say("sources: each term against its twins")
    calls = decide_sources(problem, accepted, roots, [*pool, *twins], alpha)
    if _resume_after_replacement(problem, pool, search, roots, accepted, max_effects, say):
        accepted, roots = terms_of(slots), [s.root for s in slots]
        say("sources: each term against its twins, again")
        calls = decide_sources(problem, accepted, roots, [*pool, *twins], alpha)
    for s, t, root in zip(slots, accepted, roots, strict=True):
        s.root, s.term = root, t
    return accepted, roots, calls, twins


def _thinned(
    data: Measurements, max_points: int | None, say: Callable[[str], None]
) -> Measurements:
    """Every k-th point of a dense record (in file order), at most ``max_points``: thousands of
    samples a minute apart by millimetres say nothing more about a cause than every k-th of
    them; thinned openly (said here, and ``n_points_given`` in the summary)."""
    if max_points is None or data.n <= max_points:
        return data
    stride = int(np.ceil(data.n / max_points))
    thinned = data.subset(np.arange(0, data.n, stride))
    say(f"dense record: every {stride}th of {data.n} points used ({thinned.n})")
    return thinned


@one_blas_thread
def diagnose(
    machine: Machine,
    data: Measurements,
    *,
    alpha: float = 1e-3,
    min_cv_gain: float = 0.01,
    max_effects: int = 5,
    n_folds: int = 5,
    progress: Callable[[str], None] | None = None,
    max_points: int | None = 6000,
) -> Diagnosis:
    """Compare ``machine`` with ``data``, find the causes of what it gets wrong (module docstring).

    ``progress`` (optional) receives one line per step (rounds, alternatives, held-out check).
    More than ``max_points`` points (a dense record) are thinned to every k-th point (in file
    order) before anything is fitted; ``n_points_given`` in the summary says so.

    BLAS runs on one thread meanwhile (:func:`.fitting.one_blas_thread`)."""
    t0 = time.perf_counter()
    say = progress or (lambda _msg: None)
    n_given = data.n
    data = _thinned(data, max_points, say)
    res = compute_residuals(machine, data)
    problem = make_problem(res, n_folds)
    pool = [c for c in all_candidates(res) if is_finite_design(c.design(res, c.thetas[0]))]
    # the null "a bump somewhere in the volume": every cause must explain more than it
    pool += local_candidates(res)
    n_tried = max(len(pool), 1)
    search = _Search([cv_mse(problem, [])], n_tried, alpha, min_cv_gain)
    problem = _search_all(problem, pool, search, max_effects, alpha, min_cv_gain, say)
    slots, rounds, cv_history = search.slots, search.rounds, search.cv_history
    local_hits, refused = search.local_hits, search.refused

    accepted, roots, calls, twins = _sources(problem, res, pool, search, max_effects, alpha, say)
    finding = Finding(problem, accepted, roots, calls, [*pool, *twins], alpha, refused, pool)
    entries, effects, sources, either_machine, terms, _ = describe_terms(finding, say)
    beta, _, _ = fit(problem, accepted, ridge=True)
    fitted = predictions(problem, accepted, beta)
    say("held-out predictions")
    held_folds = problem.judged_folds(accepted)
    heldout_pred = cv_predictions(problem, accepted, folds=held_folds)
    left = leftover_entry(
        problem, res, accepted, slots, local_hits, n_tried=n_tried, alpha=alpha,
        min_cv_gain=min_cv_gain, cv_last=cv_history[-1], beta=beta, fitted=fitted,
        held_folds=held_folds,
    )  # fmt: skip
    if left is not None:
        entries.append(left)
    for e in entries:
        if e["cause"] == "unexplained":
            e.update({k: v for k, v in UNEXPLAINED_SOURCE.items() if k not in e})
    extra = {
        "cv_mse_um2": cv_history,
        "alpha": alpha,
        "min_cv_gain": min_cv_gain,
        "candidates_tried": len(pool),
        "refused_periods": [public_refusal(r) for r in refused],
    }
    summary = session_summary(
        problem, data, n_given, accepted, fitted, heldout_pred, held_folds, extra
    )
    summary["elapsed_s"] = time.perf_counter() - t0
    return Diagnosis(
        verdict="found" if entries else "none",
        effects=effects,
        entries=entries,
        residuals=res,
        fitted_um=fitted,
        heldout_pred_um=heldout_pred,
        summary=summary,
        rounds=rounds,
        terms=terms,
        problem=problem,
        sources=sources,
        either_machine=either_machine,
    )


def _public_rows(rows: list[dict[str, Any]]) -> list[dict[str, Any]]:
    out: list[dict[str, Any]] = []
    for r in rows[:15]:
        row: dict[str, Any] = {k: r[k] for k in ("label", "rss", "p_adj") if k in r}
        for k in ("cv_mse", "cv_gain"):
            if k in r:
                row[k] = r[k]
        if r["theta"] is not None:
            row["theta"] = r["theta"]
        out.append(row)
    return out
