"""Is a cause the same everywhere in the volume? The test that tells a cause from a local defect.

A cause of the model is *global*: a table of an axis is one function of that axis' position, the
same at every position of the other axes; a drift or an expansion is the same law everywhere. A
local defect (a dent in a guideway, a loose cover, a blob of error in one corner) is none of them,
yet a flexible global term (a coupling, a table) fitted to the whole session soaks it up and
reaches significance. The difference shows when the volume is cut in two across a coordinate the
cause does *not* depend on: a global cause fitted on one half predicts the other half; a term that
only soaked up a local defect fitted on the half without it predicts nothing there, and fitted on
the half with it predicts structure where there is none.

For each accepted term, the others held at their joint full-data fit, the term is refitted on each
half of every *split coordinate* (x, y, z with a median split; not the axes the cause is a
function of — its table must not be extrapolated) and scored on the other half, on the points
that lie within the range of the cause's own axes the fitted half covers (artefact lines along a
diagonal cover other ranges of y and z in each half of x: no table is judged where it would be
extrapolated). The held-out gain (decrease of the sum of squares on the points scored) is compared
with the full-data fit's in-sample gain on the same points. A cause is
*local* when every split that can be tested gives a held-out gain below ``MIN_RATIO`` of its
in-sample gain.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from .fitting import Problem, Term, fit, lstsq, predictions
from .residuals import FloatArray

__all__ = ["MIN_RATIO", "Consistency", "own_axes", "spatial_consistency"]

#: A global cause keeps at least this share of its in-sample gain when each half of the volume
#: predicts the other; a term that soaked up a local defect keeps none (or loses).
MIN_RATIO = 0.2

#: A half must hold this many observations per parameter of the term to be fitted on.
_MIN_OBS_PER_PARAM = 4


@dataclass(frozen=True)
class Consistency:
    """The outcome for one term: held-out/in-sample gain per split coordinate."""

    label: str
    in_sample_gain_um2: float
    ratios: dict[str, float]  # split coordinate → held-out gain / in-sample gain

    @property
    def tested(self) -> bool:
        return bool(self.ratios)

    @property
    def local(self) -> bool:
        """True when every tested split says the term does not carry across the volume."""
        return self.tested and max(self.ratios.values()) < MIN_RATIO


def own_axes(term: Term) -> set[int]:
    """The axes (0, 1, 2) a candidate's shape is a free function of: its axis, the axis of its
    component (``ey_x`` → x), the axis it varies with."""
    keys = term.candidate.keys
    out: set[int] = set()
    for name in ("axis", "varies_with"):
        v = keys.get(name)
        if isinstance(v, str) and v in "xyz" and len(v) == 1:
            out.add("xyz".index(v))
    comp = keys.get("component")
    if isinstance(comp, str) and "_" in comp and comp[-1] in "xyz":
        out.add("xyz".index(comp[-1]))
    return out


#: Combinations of a term's coefficients (columns scaled to the whole session's norms) that a
#: half determines worse than this fraction of its best-determined one (relative singular
#: value) are not fitted on that half.
_RCOND = 1e-2


def _fit_predict(
    x_train: FloatArray, y_train: FloatArray, x_test: FloatArray, scale: FloatArray
) -> FloatArray:
    """Fit on the training rows and predict the test rows, with the columns scaled to the whole
    session's norms and combinations the half cannot determine dropped (truncated SVD): a half
    that saw too few styli or directions to pin a coefficient must not extrapolate it."""
    xs = x_train / scale
    beta, *_ = np.linalg.lstsq(xs, y_train, rcond=_RCOND)
    return (x_test / scale) @ beta


def spatial_consistency(
    problem: Problem, terms: Sequence[Term], index: int, beta: FloatArray | None = None
) -> Consistency:
    """Split test of ``terms[index]`` given the others (docstring of the module). ``beta`` is the
    joint full-data fit of ``terms`` (computed when None)."""
    if beta is None:
        beta, _, _ = fit(problem, terms)
    term = terms[index]
    n_axes = len(problem.axes)
    # partial residual: everything but the term's own columns (nuisance offsets are refitted)
    start = problem.n_nuisance + sum(t.candidate.n_params for t in terms[:index])
    stop = start + term.candidate.n_params
    beta_others = beta.copy()
    beta_others[: problem.n_nuisance] = 0.0
    beta_others[start:stop] = 0.0
    partial = problem.y - predictions(problem, terms, beta_others)[:, problem.axes]
    x_term = problem.design(term)  # (N·axes, p)
    x_off = problem.stacked([])  # (N·axes, offsets)
    x_full = np.hstack([x_off, x_term])
    y = partial.reshape(-1)
    beta0, rss0, _ = lstsq(x_off, y)
    beta1, rss1, _ = lstsq(x_full, y)
    gain_in = rss0 - rss1
    # the full-data gain per observation: the in-sample reference for any subset scored below
    gain_rows = (y - x_off @ beta0) ** 2 - (y - x_full @ beta1) ** 2
    norms = np.linalg.norm(x_full, axis=0)
    scale = np.where(norms > 0, norms, 1.0)
    ratios: dict[str, float] = {}
    q = problem.res.q_mm
    own = sorted(own_axes(term))
    # a drift is a function of time alone: its own coordinate is time, never extrapolated
    # (artefact lines measured one after another put each half of the volume in other hours)
    t = problem.res.signals.get("t") if term.candidate.hold_time else None
    p = x_full.shape[1]
    for k in range(3):
        if k in own or float(np.ptp(q[:, k])) <= 1e-6:
            continue
        low = q[:, k] <= np.median(q[:, k])
        if low.all() or not low.any():
            continue
        halves = [np.flatnonzero(low), np.flatnonzero(~low)]
        if min(len(h) for h in halves) * n_axes < _MIN_OBS_PER_PARAM * p:
            continue
        gain_out = 0.0
        gain_ref = 0.0
        for train, test in ((halves[0], halves[1]), (halves[1], halves[0])):
            # scored only where the half fitted on covers the term's own axes: a table is not
            # extrapolated (artefact lines along a diagonal cover other ranges in each half)
            inside = np.ones(len(test), dtype=bool)
            for a in own:
                lo, hi = float(np.min(q[train, a])), float(np.max(q[train, a]))
                inside &= (q[test, a] >= lo) & (q[test, a] <= hi)
            if t is not None:
                inside &= (t[test] >= np.min(t[train])) & (t[test] <= np.max(t[train]))
            test = test[inside]
            if len(test) * n_axes < p:
                continue
            rows_tr = (train[:, None] * n_axes + np.arange(n_axes)).reshape(-1)
            rows_te = (test[:, None] * n_axes + np.arange(n_axes)).reshape(-1)
            p0 = _fit_predict(x_off[rows_tr], y[rows_tr], x_off[rows_te], scale[: x_off.shape[1]])
            p1 = _fit_predict(x_full[rows_tr], y[rows_tr], x_full[rows_te], scale)
            gain_out += float(np.sum((y[rows_te] - p0) ** 2) - np.sum((y[rows_te] - p1) ** 2))
            gain_ref += float(np.sum(gain_rows[rows_te]))
        if gain_ref <= 0.0:  # nothing scored within the range fitted on: not testable this way
            continue
        ratios["xyz"[k]] = gain_out / gain_ref
    return Consistency(term.candidate.label, float(gain_in), ratios)
