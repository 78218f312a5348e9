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
* it predicts held-out points as well: grouped CV MSE within ``SIMPLER_WITHIN`` of the group's.

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
    cv_full = cv_mse(problem, full)
    cv_full_time = (
        None if problem.time_folds is None else cv_mse(problem, full, folds=problem.time_folds)
    )
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
                ratio = cv_mse(problem, [*others, term]) / cv_full if cv_full > 0 else 1.0
                if (cand.hold_time or cand.start_state) and cv_full_time:
                    # a drift or a start-up transient may instead predict as well between
                    # neighbours in time (as when it is added: :func:`.selection._time_gain`)
                    cv_t = cv_mse(problem, [*others, term], folds=problem.time_folds)
                    ratio = min(ratio, cv_t / cv_full_time)
                if ratio > 1.0 + simpler_within:
                    continue
                if best is None or (len(group), -ratio) > (len(best.indices), -best.cv_ratio):
                    best = Merge(group, term, ratio)
    return best
