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

import functools
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from numpy.typing import NDArray

from ..effects import Effect
from ..formats.measurements import Measurements
from ..machine import Machine
from .alternatives import find_alternatives
from .candidates import Candidate, all_candidates, contract_keys, is_finite_design
from .consistency import spatial_consistency
from .fitting import (
    Problem,
    Term,
    best_theta,
    cv_gain,
    cv_mse,
    cv_predictions,
    f_test_p,
    fit,
    make_problem,
    predictions,
    split_coefficients,
)
from .merge import one_for_several
from .residuals import Residuals, compute_residuals, length_error_e0_um, rms3d
from .unexplained import (
    is_local,
    local_candidates,
    local_entry,
    local_unexplained,
    locate,
    unexplained_candidate,
)

__all__ = ["Diagnosis", "diagnose"]

#: Candidates whose CV MSE is within this fraction of the best are equally good: the one with
#: fewer parameters (the simpler explanation) is taken. 0.5 % is below what separates two
#: explanations on a few hundred points (paired CV differences of that size come and go with
#: the fold assignment).
SIMPLER_WITHIN = 0.005


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

    def to_json(self) -> dict[str, Any]:
        return {"verdict": self.verdict, "effects": self.entries, **self.summary}

    def extended_machine(self) -> Machine:
        """The machine with the compensable effects found (a ``drift`` describes the session
        but cannot be predicted at run time: it is not added)."""
        return self.residuals.machine.with_effects([e for e in self.effects if e.compensable])


@dataclass
class _Slot:
    """An accepted cause: its family's default candidate and the term in use (default or rich
    variant, with its nonlinear parameter)."""

    root: Candidate
    term: Term

    @property
    def rich_term(self) -> Term:
        return Term(self.root.rich or self.root, self.term.theta)


def _terms(slots: list[_Slot], rich: bool = False) -> list[Term]:
    return [s.rich_term if rich else s.term for s in slots]


def _round(
    problem: Problem,
    slots: list[_Slot],
    pool: list[Candidate],
    n_tried: int,
    alpha: float,
    min_cv_gain: float,
    cv_base: float,
    local_hits: list[dict[str, Any]],
) -> tuple[Term | None, list[dict[str, Any]]]:
    """One forward step. New candidates are tested against the accepted causes at their *rich*
    shape, so what a mis-shaped accepted cause leaves behind (same signal, same axis, same Abbe
    arms) is absorbed by it and never named as a second cause. A pick that fails the volume
    consistency test (:mod:`.consistency`) is not taken; it is appended to ``local_hits`` and the
    next eligible candidate is considered."""
    base = _terms(slots, rich=True)
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
    current = _terms(slots)
    folds = problem.judged_folds(current)
    if folds is not None:
        cv_base = cv_mse(problem, current, folds=folds)
    for r in eligible:
        with_it = [*current, Term(r["candidate"], r["theta"])]
        r["cv_mse"] = cv_mse(problem, with_it, folds=folds)
        r["cv_gain"] = (cv_base - r["cv_mse"]) / cv_base if cv_base > 0 else 0.0
        timed = _other_gain(problem, current, with_it, folds) if r["candidate"].timed else None
        if timed is not None and timed > r["cv_gain"]:
            # a drift or a start-up transient may also be judged between neighbours in time
            r["cv_gain"] = timed
            r["cv_mse"] = cv_base * (1.0 - timed)
    eligible = [r for r in eligible if r["cv_gain"] >= min_cv_gain]
    while eligible:
        best_cv = min(r["cv_mse"] for r in eligible)
        close = [r for r in eligible if r["cv_mse"] <= best_cv * (1.0 + SIMPLER_WITHIN)]
        pick = min(close, key=lambda r: (r["candidate"].n_params, r["cv_mse"]))
        term = Term(pick["candidate"], pick["theta"])
        if is_local(term.candidate):
            family = _family_rather_than_bump(problem, current, eligible, pick["cv_mse"], folds)
            return family or term, rows
        check = spatial_consistency(problem, [*current, term], len(current))
        if not check.local:
            return term, rows
        # significant, but not the same law across the volume: a local defect soaked up by a
        # global shape — never named as that cause (reported as unexplained by the caller)
        pick["local"] = check.ratios
        local_hits.append(pick)
        eligible = [r for r in eligible if r is not pick]
    return None, rows


def _other_gain(
    problem: Problem,
    base: list[Term],
    with_term: list[Term],
    folds: Sequence[NDArray[np.intp]] | None,
) -> float | None:
    """A cause of time is judged on both kinds of folds and kept on either: its gain on the
    kind ``folds`` is not (time blocks when ``folds`` is None, else the main folds); None when
    the session has no time blocks."""
    if folds is None:
        return (
            None
            if problem.time_folds is None
            else cv_gain(problem, base, with_term, problem.time_folds)
        )
    return cv_gain(problem, base, with_term)


def _model_cv(problem: Problem, terms: Sequence[Term]) -> float:
    """The model's held-out MSE on the folds it is judged on (``Problem.judged_folds``)."""
    return cv_mse(problem, terms, folds=problem.judged_folds(terms))


#: How many of the best global families are tried at their rich shape against a local bump.
RICH_CHALLENGERS = 3


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


def _reprofile(problem: Problem, slots: list[_Slot]) -> None:
    """Re-profile every accepted term's nonlinear parameter given the others."""
    for i, s in enumerate(slots):
        if len(s.term.candidate.thetas) > 1:
            others = _terms(slots[:i] + slots[i + 1 :])
            theta, _, _ = best_theta(problem, others, s.term.candidate)
            s.term = Term(s.term.candidate, theta)


def _choose_variants(
    problem: Problem, slots: list[_Slot], alpha: float, min_cv_gain: float
) -> None:
    """Each accepted cause takes its rich shape only when the data need it (F-test and CV)."""
    n_obs = problem.y.size
    for i, s in enumerate(slots):
        if s.root.rich is None:
            continue
        others = _terms(slots[:i] + slots[i + 1 :])
        plain, rich = Term(s.root, s.term.theta), s.rich_term
        _, rss0, rank0 = fit(problem, [*others, plain])
        _, rss1, rank1 = fit(problem, [*others, rich])
        p = f_test_p(rss0, rss1, rank1 - rank0, n_obs, rank1)
        use_rich = p * len(slots) < alpha
        if use_rich:
            # a drift's shape is judged between neighbours in time, any other on the grouped
            # folds (the shape of a table is a question of where, not when)
            folds = problem.judged_folds([plain])
            cv0 = cv_mse(problem, [*others, plain], folds=folds)
            cv1 = cv_mse(problem, [*others, rich], folds=folds)
            use_rich = cv0 > 0 and (cv0 - cv1) / cv0 >= min_cv_gain
        s.term = rich if use_rich else plain


def _backward(
    problem: Problem, slots: list[_Slot], n_tried: int, alpha: float, min_cv_gain: float
) -> list[_Slot]:
    """Backward elimination: drop, one at a time, the weakest accepted cause that is no longer
    needed given the others (F-test at ``alpha`` with the same corrections as when it was added,
    or a CV gain below ``min_cv_gain``). Returns the dropped slots."""
    dropped: list[_Slot] = []
    n_obs = problem.y.size
    while len(slots) > 1:
        worst: tuple[float, int] | None = None
        full = _terms(slots)
        folds = problem.judged_folds(full)
        cv_full = cv_mse(problem, full, folds=folds)
        for i, s in enumerate(slots):
            # significance against the others at their rich shapes, as when a cause is added:
            # a cause taken early that is only the leftover of a later one's richer shape (a
            # stale squareness that is a thermal cause's static image) is not needed. (The
            # held-out gain stays with the shapes in use: rich shapes fitted on a few folds
            # predict wildly between them.)
            rich_others = [t.rich_term for t in slots[:i] + slots[i + 1 :]]
            _, rss1, rank1 = fit(problem, [*rich_others, s.term])
            _, rss0, rank0 = fit(problem, rich_others)
            others = full[:i] + full[i + 1 :]
            p = f_test_p(rss0, rss1, rank1 - rank0, n_obs, rank1)
            p_adj = min(1.0, p * n_tried * s.root.look_elsewhere)
            cv0 = cv_mse(problem, others, folds=folds)
            # (a drift in the model: both on the time blocks, ``Problem.judged_folds``)
            gain = (cv0 - cv_full) / cv0 if cv0 > 0 else 0.0
            other = _other_gain(problem, others, full, folds) if s.root.timed else None
            if other is not None:  # a cause of time is kept on either test, as it was added
                gain = max(gain, other)
            if (p_adj >= alpha or gain < min_cv_gain) and (worst is None or -gain > worst[0]):
                worst = (-gain, i)
        if worst is None:
            break
        dropped.append(slots.pop(worst[1]))
        _reprofile(problem, slots)
    return dropped


def _still_significant(
    problem: Problem,
    slots: list[_Slot],
    hits: list[dict[str, Any]],
    n_tried: int,
    alpha: float,
    min_cv_gain: float,
    cv_now: float,
) -> list[dict[str, Any]]:
    """The local hits (candidates refused by the volume consistency test in some round) that are
    still significant and still predict held-out points better given the causes finally named:
    a hit from an early round is often what a cause accepted later explains (a squareness
    drift first fitted by a coupling in one half of the volume) and is then no structure left."""
    base = _terms(slots, rich=True)
    current = _terms(slots)
    folds = problem.judged_folds(current)
    n_obs = problem.y.size
    _, rss0, rank0 = fit(problem, base)
    out: list[dict[str, Any]] = []
    for h in hits:
        cand = h["candidate"]
        theta, rss1, extra = best_theta(problem, base, cand)
        p = f_test_p(rss0, rss1, extra, n_obs, rank0 + extra)
        p_adj = min(1.0, p * n_tried * cand.look_elsewhere)
        if p_adj >= alpha:
            continue
        cv = cv_mse(problem, [*current, Term(cand, theta)], folds=folds)
        gain = (cv_now - cv) / cv_now if cv_now > 0 else 0.0
        if gain >= min_cv_gain:
            out.append({**h, "theta": theta, "p_adj": p_adj, "cv_gain": gain})
    return out


def _merge_causes(
    problem: Problem,
    slots: list[_Slot],
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
        if spatial_consistency(problem, [*_terms(kept), merge.term], len(kept)).local:
            return changed
        say(
            f"  one cause for several: {merge.term.candidate.label} replaces "
            + ", ".join(slots[i].root.label for i in group)
        )
        slots[:] = [*kept, _Slot(merge.term.candidate, merge.term)]
        _reprofile(problem, slots)
        _choose_variants(problem, slots, alpha, min_cv_gain)
        changed = True


def _one_blas_thread(fn: Callable[..., Diagnosis]) -> Callable[..., Diagnosis]:
    """Run ``fn`` with BLAS on one thread: the matrices are a few thousand rows by tens of
    columns, where threads only cost (measured on a busy 2-core machine: an SVD of 2100 × 132
    took 2.6–4.1 s with two OpenBLAS threads, 0.02–0.05 s with one)."""

    @functools.wraps(fn)
    def run(*args: Any, **kwargs: Any) -> Diagnosis:
        from threadpoolctl import threadpool_limits

        with threadpool_limits(limits=1, user_api="blas"):
            return fn(*args, **kwargs)

    return run


@_one_blas_thread
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

    BLAS runs on one thread meanwhile (:func:`_one_blas_thread`)."""
    t0 = time.perf_counter()
    say = progress or (lambda _msg: None)
    n_given = data.n
    if max_points is not None and data.n > max_points:
        # a dense record (thousands of samples a minute apart by millimetres) says nothing more
        # about a cause than every k-th sample of it; thinned openly, reported in the summary
        stride = int(np.ceil(data.n / max_points))
        data = data.subset(np.arange(0, data.n, stride))
        say(f"dense record: every {stride}th of {n_given} points used ({data.n})")
    res = compute_residuals(machine, data)
    problem = make_problem(res, n_folds)
    pool = [c for c in all_candidates(res) if is_finite_design(c.design(res, c.thetas[0]))]
    # the null "a bump somewhere in the volume": every cause must explain more than it
    pool += local_candidates(res)
    n_tried = max(len(pool), 1)
    slots: list[_Slot] = []
    excluded: set[int] = set()
    rounds: list[list[dict[str, Any]]] = []
    cv_history = [cv_mse(problem, [])]
    local_hits: list[dict[str, Any]] = []
    while len(slots) < max_effects:
        taken = {id(s.root) for s in slots} | excluded
        # one entry per identity (the shapes of one family compete, never both named); two
        # cyclic errors of one axis with different periods are two causes, and a local bump
        # is fitted per error component (one `unexplained` entry for all of them)
        named = {
            s.root.identity for s in slots if s.root.cause != "periodic" and not is_local(s.root)
        }
        remaining = [c for c in pool if id(c) not in taken and c.identity not in named]
        say(f"round {len(rounds) + 1}: {len(remaining)} candidates")
        term, rows = _round(
            problem, slots, remaining, n_tried, alpha, min_cv_gain, cv_history[-1], local_hits
        )
        rounds.append(_public_rows(rows))
        if term is None:
            break
        slots.append(_Slot(term.candidate, term))
        say(f"  accepted {term.candidate.label}")
        _reprofile(problem, slots)
        _choose_variants(problem, slots, alpha, min_cv_gain)
        dropped = _backward(problem, slots, n_tried, alpha, min_cv_gain)
        for s in dropped:
            excluded.add(id(s.root))
            say(f"  dropped {s.root.label}: not needed given the others")
        if dropped:  # what a dropped cause carried may need the others' rich shapes now
            _choose_variants(problem, slots, alpha, min_cv_gain)
        cv_history.append(_model_cv(problem, _terms(slots)))
    if _merge_causes(problem, slots, pool, alpha, min_cv_gain, say):
        cv_history.append(_model_cv(problem, _terms(slots)))

    accepted = _terms(slots)
    beta, rss_after, rank_after = fit(problem, accepted, ridge=True)
    fitted = predictions(problem, accepted, beta)
    say("held-out predictions")
    held_folds = problem.judged_folds(accepted)
    heldout_pred = cv_predictions(problem, accepted, folds=held_folds)
    coefs = split_coefficients(problem, accepted, beta)
    local = [i for i, t in enumerate(accepted) if is_local(t.candidate)]
    local_entries = [local_entry(problem, accepted, local, beta)] if local else []
    causes = [i for i in range(len(accepted)) if i not in local]
    effects = [accepted[i].candidate.build(coefs[i], accepted[i].theta) for i in causes]
    rss_before = float(np.sum(problem.y**2))
    n_obs = problem.y.size
    sigma2 = rss_after / max(n_obs - rank_after, 1)
    entries: list[dict[str, Any]] = []
    causes_pool = [c for c in pool if not is_local(c)]
    if effects:
        say("alternatives")
    for i, eff in zip(causes, effects, strict=True):
        t = accepted[i]
        others = accepted[:i] + accepted[i + 1 :]
        _, rss_without, _ = fit(problem, others)
        entry = {**contract_keys(eff), "parameters": eff.describe().get("parameters", {})}
        entry["explained_fraction"] = (rss_without - rss_after) / rss_before if rss_before else 0.0
        entry["label"] = t.candidate.label
        alt = find_alternatives(
            problem, others, t, eff, causes_pool, [s.root for s in slots], rss_after, sigma2, alpha
        )
        if alt is not None:
            entry["alternatives"] = alt["alternatives"]
            entry["separate_by"] = alt["separate_by"]
        if not eff.compensable:
            entry["compensable"] = False
        entries.append(entry)
    order = np.argsort([-e["explained_fraction"] for e in entries], kind="stable")
    entries = [entries[i] for i in order]
    effects = [effects[i] for i in order]

    # structure no cause explains?
    r_before = res.residual_um
    r_after = r_before - fitted
    if local_entries:
        entries.extend(local_entries)
    else:
        unexplained = unexplained_candidate(
            problem,
            accepted,
            alpha,
            min_cv_gain,
            cv_history[-1],
            _terms(slots, rich=True),
            held_folds,
        )
        if unexplained is None and local_hits:
            hits = _still_significant(
                problem, slots, local_hits, n_tried, alpha, min_cv_gain, cv_history[-1]
            )
            if hits:
                unexplained = local_unexplained(problem, accepted, hits)
        if unexplained is not None:
            unexplained["parameters"].update(locate(res, r_after))
            entries.append(unexplained)
    r_heldout = r_before - heldout_pred
    # "before" is the model as described with the same nuisance offsets removed (in-sample and
    # held out), so before/after differ by the effects found and nothing else
    beta0, _, _ = fit(problem, [])
    r_before_in = r_before - predictions(problem, [], beta0)
    r_before_out = r_before - cv_predictions(problem, [], folds=held_folds)
    sigma = float(np.sqrt(sigma2))
    summary = {
        "residual_rms_um": {"before": rms3d(r_before_in), "after": rms3d(r_after)},
        "heldout_rms_um": {"before": rms3d(r_before_out), "after": rms3d(r_heldout)},
        "e0_um": {
            "before": length_error_e0_um(data.reference_mm, r_before_out, data.group),
            "after": length_error_e0_um(data.reference_mm, r_heldout, data.group),
            "definition": "max |length error| over point pairs of one group (artefact "
            "position); 'after' uses out-of-fold predictions",
        },
        "noise_sigma_um": sigma,
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
        "cv_mse_um2": cv_history,
        "alpha": alpha,
        "min_cv_gain": min_cv_gain,
        "candidates_tried": len(pool),
        "elapsed_s": time.perf_counter() - t0,
    }
    verdict = "found" if entries else "none"
    return Diagnosis(
        verdict=verdict,
        effects=effects,
        entries=entries,
        residuals=res,
        fitted_um=fitted,
        heldout_pred_um=heldout_pred,
        summary=summary,
        rounds=rounds,
        terms=[accepted[causes[i]] for i in order],
        problem=problem,
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
