"""One cause for several: the parsimony step after forward selection.

Forward selection adds one cause at a time, each the best single addition. A cause whose
signature is spread over several components can therefore enter as two or three smaller
causes that each match one part of it: an isotropic workpiece expansion with a nearly constant
temperature enters as three scale tables (each is as good a first step as the whole), a thermal
bow as a coupling and a straightness table, a drift on back-and-forth length lines as a cyclic
error plus a reversal. Each part passes its own tests, and backward elimination keeps them all
(none is redundant *given the others*).

Here every group of two or three accepted causes is replaced, in turn, by each single candidate
not yet named (nonlinear parameter re-profiled, the other accepted causes kept). The one cause
replaces the group when

* it fits as well: its residual sum of squares exceeds the group's by less than the
  ``1 − alpha`` quantile of χ²(1) times the noise variance, each parameter it has beyond the
  group's charged one noise variance (the test :mod:`.alternatives` uses for "the session
  cannot tell them apart"), and
* it predicts held-out points as well: CV MSE within ``SIMPLER_WITHIN`` of the group's, both
  on the folds either model is judged on (time blocks once a cause of time is in it).

One cause that does the work of several is the simpler explanation (Occam), so it is named and the
group's members are not. The step only ever removes named causes: it cannot raise a false alarm
on a session where nothing was found.
"""

from __future__ import annotations

import itertools
from collections.abc import Sequence
from dataclasses import dataclass

from scipy import stats

from .candidates import Candidate
from .fitting import Problem, Term, best_theta, cv_mse, fit

__all__ = ["Merge", "one_for_several"]

#: Largest group of accepted causes one candidate may replace.
MAX_GROUP = 3


@dataclass(frozen=True)
class Merge:
    """Replace the accepted terms at ``indices`` by ``term``; ``cv_ratio``: its held-out MSE over
    the group's (on the time folds for a drift or a transient, where that is lower)."""

    indices: tuple[int, ...]
    term: Term
    cv_ratio: float


def one_for_several(
    problem: Problem,
    accepted: Sequence[Term],
    pool: Sequence[Candidate],
    alpha: float,
    simpler_within: float,
    keep: Sequence[Term] = (),
) -> Merge | None:
    """The best single candidate of ``pool`` that replaces a group of ``accepted`` (module
    docstring), or None. ``accepted`` are the causes that may be grouped, ``keep`` terms fitted
    beside them but never grouped (local bumps); ``pool`` the global candidates whose identity
    is not already named. Among several merges the largest group wins, then the lowest ratio."""
    if len(accepted) < 2 or not pool:
        return None
    n_obs = problem.y.size
    full = [*accepted, *keep]
    _, rss_full, rank_full = fit(problem, full)
    sigma2 = rss_full / max(n_obs - rank_full, 1)
    threshold = float(stats.chi2.ppf(1.0 - alpha, 1)) * sigma2
    cv_full: dict[bool, float] = {}  # the full model's CV MSE, on time blocks or not

    def ratio_on(on_time: bool, new: list[Term]) -> float:
        folds = problem.time_folds if on_time else None
        if on_time not in cv_full:
            cv_full[on_time] = cv_mse(problem, full, folds=folds)
        ref = cv_full[on_time]
        return cv_mse(problem, new, folds=folds) / ref if ref > 0 else 1.0

    best: Merge | None = None
    for size in range(2, min(MAX_GROUP, len(accepted)) + 1):
        for group in itertools.combinations(range(len(accepted)), size):
            others = [*(t for i, t in enumerate(accepted) if i not in group), *keep]
            n_group = sum(accepted[i].candidate.n_params for i in group)
            for cand in pool:
                # screened on the scan's grid first (the refinement between two grid values
                # moves the RSS by far less than the threshold again): most candidates fit a
                # group's work nowhere near, and refining each would double the diagnosis time
                _, rss, _ = best_theta(problem, others, cand, refine=False)
                if rss + sigma2 * max(cand.n_params - n_group, 0) - rss_full >= 2.0 * threshold:
                    continue
                theta, rss, _ = best_theta(problem, others, cand)
                charged = rss + sigma2 * max(cand.n_params - n_group, 0)
                if charged - rss_full >= threshold:
                    continue
                term = Term(cand, theta)
                # both models on the folds either is judged on (``Problem.judged_folds``); a
                # cause of time also on the other kind, kept on either, as when it is added
                on_time = problem.judged_folds([*full, term]) is not None
                kinds = [on_time]
                if cand.timed and problem.time_folds is not None:
                    kinds.append(not on_time)
                ratio = min(ratio_on(k, [*others, term]) for k in kinds)
                if ratio > 1.0 + simpler_within:
                    continue
                if best is None or (len(group), -ratio) > (len(best.indices), -best.cv_ratio):
                    best = Merge(group, term, ratio)
    return best
