"""What the named causes leave: the entry for structure no cause explains.

A local bump that won a place in the search becomes a ``local`` entry; otherwise the residual
left by the named causes is tested for an ``unexplained`` structure (a smooth field or a local
hit still significant). Residuals in µm, positions in mm.
"""

from __future__ import annotations

from typing import Any

from .fitting import Problem, Term
from .residuals import FloatArray, Residuals
from .steps import Slot, still_significant, terms_of
from .unexplained import is_local, local_entry, local_unexplained, locate, unexplained_candidate

__all__ = ["UNEXPLAINED_SOURCE", "leftover_entry"]

#: What an ``unexplained`` entry says of its source: structure no cause of either instrument
#: explains.
UNEXPLAINED_SOURCE = {
    "source": "either",
    "locked_to": "undetermined",
    "evidence": {"summary": "structure no cause of the machine or of the reference explains"},
}


def leftover_entry(
    problem: Problem,
    res: Residuals,
    accepted: list[Term],
    slots: list[Slot],
    local_hits: list[Any],
    *,
    n_tried: int,
    alpha: float,
    min_cv_gain: float,
    cv_last: float,
    beta: Any,
    fitted: FloatArray,
    held_folds: Any,
) -> dict[str, Any] | None:
    """The ``local`` or ``unexplained`` entry of the diagnosis JSON, or None when the named
    causes leave nothing significant (``alpha`` family-wise over ``n_tried`` candidates, a CV
    gain of at least ``min_cv_gain`` over the last CV MSE ``cv_last``, µm²)."""
    local = [i for i, t in enumerate(accepted) if is_local(t.candidate)]
    if local:
        return local_entry(problem, accepted, local, beta)
    unexplained = unexplained_candidate(
        problem, accepted, alpha, min_cv_gain, cv_last, terms_of(slots, rich=True), held_folds
    )
    if unexplained is None and local_hits:
        hits = still_significant(problem, slots, local_hits, n_tried, alpha, min_cv_gain, cv_last)
        if hits:
            unexplained = local_unexplained(problem, accepted, hits)
    if unexplained is None:
        return None
    unexplained["parameters"].update(locate(res, res.residual_um - fitted))
    unexplained.update(UNEXPLAINED_SOURCE)
    return unexplained
