"""Steps on the set of causes named so far: their shapes, their nonlinear parameters and
backward elimination (used by :mod:`.selection`)."""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import NDArray

from .candidate import Candidate
from .fitting import Problem, Term, best_theta, cv_gain, cv_mse, f_test_p, fit
from .sources import contribution, direction_factor, residual_in_time

__all__ = [
    "Slot",
    "backward",
    "choose_variants",
    "model_cv",
    "other_gain",
    "reprofile",
    "slow_noise",
    "still_significant",
    "terms_of",
    "timed_p",
]


@dataclass
class Slot:
    """An accepted cause: its family's default candidate and the term in use (default or rich
    variant, with its nonlinear parameter)."""

    root: Candidate
    term: Term

    @property
    def rich_term(self) -> Term:
        return Term(self.root.rich or self.root, self.term.theta)


def terms_of(slots: list[Slot], rich: bool = False) -> list[Term]:
    return [s.rich_term if rich else s.term for s in slots]


def other_gain(
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


def model_cv(problem: Problem, terms: Sequence[Term]) -> float:
    """The model's held-out MSE on the folds it is judged on (``Problem.judged_folds``)."""
    return cv_mse(problem, terms, folds=problem.judged_folds(terms))


def reprofile(problem: Problem, slots: list[Slot]) -> None:
    """Re-profile every accepted term's nonlinear parameter given the others."""
    for i, s in enumerate(slots):
        if len(s.term.candidate.thetas) > 1:
            others = terms_of(slots[:i] + slots[i + 1 :])
            theta, _, _ = best_theta(problem, others, s.term.candidate)
            s.term = Term(s.term.candidate, theta)


def choose_variants(problem: Problem, slots: list[Slot], alpha: float, min_cv_gain: float) -> None:
    """Each accepted cause takes its rich shape only when the data need it (F-test and CV)."""
    n_obs = problem.y.size
    for i, s in enumerate(slots):
        if s.root.rich is None:
            continue
        others = terms_of(slots[:i] + slots[i + 1 :])
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


def backward(
    problem: Problem,
    slots: list[Slot],
    n_tried: int,
    alpha: float,
    min_cv_gain: float,
    causes: frozenset[str] | None = None,
) -> list[Slot]:
    """Backward elimination: drop, one at a time, the weakest accepted cause that is no longer
    needed given the others (F-test at ``alpha`` with the same corrections as when it was added,
    or a CV gain below ``min_cv_gain``); only causes in ``causes`` when given. Returns the
    dropped slots."""
    dropped: list[Slot] = []
    n_obs = problem.y.size
    while len(slots) > 1:
        worst: tuple[float, int] | None = None
        full = terms_of(slots)
        folds = problem.judged_folds(full)
        cv_full = cv_mse(problem, full, folds=folds)
        for i, s in enumerate(slots):
            if causes is not None and s.root.cause not in causes:
                continue
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
            other = other_gain(problem, others, full, folds) if s.root.timed else None
            if other is not None:  # a cause of time is kept on either test, as it was added
                gain = max(gain, other)
            if p_adj >= alpha and gain >= min_cv_gain:
                # not significant beside the others' rich shapes, but needed at the shapes in
                # use: dropped only where those rich shapes do its work held out as well
                gain = min(gain, _gain_over(problem, rich_others, full, folds, cv_full))
            if gain < min_cv_gain and (worst is None or -gain > worst[0]):
                worst = (-gain, i)
        if worst is None:
            break
        dropped.append(slots.pop(worst[1]))
        reprofile(problem, slots)
    return dropped


def _gain_over(
    problem: Problem,
    rich_others: list[Term],
    full: list[Term],
    folds: Sequence[NDArray[np.intp]] | None,
    cv_full: float,
) -> float:
    """The held-out gain of the model in use over the others at their rich shapes (on the
    model's folds): a table beside a drift that changes along the axis is not significant
    against the drift's rich shape (which holds a table), yet that shape alone predicted 5.8×
    worse on the time blocks than the table and the drift at their shapes (9.75 against
    1.68 µm², ``mixed/one-directional/s4000`` of the reference generator) — the table was
    dropped, and the ripple and the latency that the drift's rich shape then hid never named."""
    cv0 = cv_mse(problem, rich_others, folds=folds)
    return (cv0 - cv_full) / cv0 if cv0 > 0 else 0.0


def still_significant(
    problem: Problem,
    slots: list[Slot],
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
    base = terms_of(slots, rich=True)
    current = terms_of(slots)
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


def timed_p(problem: Problem, base: list[Term], term: Term, rss0: float, n_obs: int) -> float:
    """The F-test p-value of a cause of time (a drift) with the noise variance inflated along
    its own contribution by the residual's correlation in time
    (:func:`.sources.direction_factor`): a slow term fitted to noise correlated over seconds
    gains as many σ² as that noise's correlation time holds points, not one per parameter —
    a drift of 4 parameters took 1.9 % of a 126-s session's noise (an Ornstein–Uhlenbeck part
    of 2.1 s) beside a latency and was named (latency/bidirectional-rest/s5001)."""
    terms = [*base, term]
    beta, rss1, rank1 = fit(problem, terms)
    resid_t = residual_in_time(problem, terms, beta)
    factor = direction_factor(problem, resid_t, contribution(problem, terms, beta, len(base)), 1.0)
    rss1_eff = rss0 - (rss0 - rss1) / factor
    return f_test_p(rss0, rss1_eff, term.candidate.n_params, n_obs, rank1)


def slow_noise(
    problem: Problem, slots: list[Slot], n_tried: int, alpha: float, say: Callable[[str], None]
) -> None:
    """Drop, one at a time, a named cause of time (a drift) whose F-test beside the others fails
    once σ² is inflated along its contribution by the residual's correlation in time
    (:func:`timed_p`), at the final model, whose residual is the noise: judged while other
    causes were still in the residual, that correlation would be theirs, not the noise's."""
    n_obs = problem.y.size
    while True:
        weakest: tuple[float, int] | None = None
        for i, s in enumerate(slots):
            if not s.root.timed:
                continue
            others = terms_of(slots[:i] + slots[i + 1 :])
            _, rss0, _ = fit(problem, others)
            p = timed_p(problem, others, s.term, rss0, n_obs)
            p_adj = p * n_tried * s.root.look_elsewhere
            if p_adj >= alpha and (weakest is None or p_adj > weakest[0]):
                weakest = (p_adj, i)
        if weakest is None:
            return
        gone = slots.pop(weakest[1])
        say(f"  dropped {gone.root.label}: not beyond the noise's correlation in time")
        reprofile(problem, slots)
