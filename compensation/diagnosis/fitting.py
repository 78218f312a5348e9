"""Least-squares fitting of candidate terms, profiles over nonlinear parameters, grouped CV, F-tests.

The residuals of all points and measured axes are stacked into one vector y (3N, or fewer when an
axis was never measured); a model is a list of :class:`Term` (candidate + nonlinear parameter),
its design the stacked columns of their designs, fitted jointly by linear least squares (columns
scaled for conditioning). A nonlinear parameter (period, time constant, lobes) is profiled: every
grid value is fitted (the accepted terms projected out by QR), and a continuous one is refined by
a bounded scalar search between the neighbouring grid values.
"""

from __future__ import annotations

import functools
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field, replace
from typing import Any, TypeVar

import numpy as np
from numpy.typing import NDArray
from scipy import linalg, optimize, stats

from .candidates import Candidate
from .residuals import FloatArray, Residuals

#: Designs of candidates scanning more grid values than this are not cached.
_CACHE_LIMIT = 64


@dataclass(frozen=True)
class Term:
    candidate: Candidate
    theta: Any = None


@dataclass
class Problem:
    """The stacked residual vector, which axes are measured, and the CV folds."""

    res: Residuals
    axes: tuple[int, ...]  # measured axes (residual not identically zero)
    folds: list[NDArray[np.intp]]  # index arrays of held-out points
    #: Fit a constant offset per measured axis in every model (a nuisance, not a cause): the
    #: reference instrument's zero is never exactly the machine's reference point.
    offsets: bool = True
    #: Folds for a cause that is a function of time alone (a drift): short blocks of time dealt
    #: out in turn, so a held-out block has training points just before and after it. The main
    #: folds (whole groups or fifths of the session) ask whether a *law* carries over to unseen
    #: artefact positions or times; a drift has no law beyond its session — what can be asked
    #: is whether it predicts the points between those it was fitted on. None without times.
    time_folds: list[NDArray[np.intp]] | None = None
    _q_cache: dict[Any, FloatArray | None] = field(default_factory=dict, repr=False)
    _train_cache: dict[Any, NDArray[np.intp]] = field(default_factory=dict, repr=False)

    def training_rows(self, test: NDArray[np.intp]) -> NDArray[np.intp]:
        """The sorted rows not in ``test`` (cached, read-only: every model's cross-validation
        holds out the same folds)."""
        key = (test.dtype.str, test.tobytes())
        if key not in self._train_cache:
            if len(self._train_cache) > 64:
                self._train_cache.clear()
            train = np.setdiff1d(np.arange(self.res.n), test)
            train.flags.writeable = False
            self._train_cache[key] = train
        return self._train_cache[key]

    def projector(self, base: Sequence[Term], rows: Any) -> FloatArray | None:
        """Orthonormal basis of the columns of ``base`` on ``rows`` (cached: every candidate of
        a round is profiled against the same base)."""
        key = (
            tuple((id(t.candidate), t.theta) for t in base),
            None if isinstance(rows, slice) else np.asarray(rows).tobytes(),
        )
        if key not in self._q_cache:
            if len(self._q_cache) > 64:
                self._q_cache.clear()
            self._q_cache[key] = _projector(self.stacked(base, rows))
        return self._q_cache[key]

    @property
    def y(self) -> FloatArray:
        return self.res.residual_um[:, self.axes]

    def judged_folds(self, terms: Sequence[Term]) -> list[NDArray[np.intp]] | None:
        """The folds a model is judged on held out: the time blocks once it holds a cause of
        time (``Candidate.timed``), else the main folds (None). The main folds would ask a
        drift to predict whole artefact lines measured in hours it never saw, which no drift
        can: on length lines a drift judged that way predicted 4× worse than no model at all,
        and every candidate after it was scored against that noise."""
        if self.time_folds is not None and any(t.candidate.timed for t in terms):
            return self.time_folds
        return None

    def design(self, term: Term, rows: Any = slice(None)) -> FloatArray:
        """(rows·axes, p) stacked design of ``term``."""
        cand = term.candidate
        if len(cand.thetas) > _CACHE_LIMIT and cand.design_fn is not None:
            x = cand.design_fn(self.res, term.theta)
        else:
            x = cand.design(self.res, term.theta)
        x = x[rows][:, self.axes, :]
        return x.reshape(-1, x.shape[2])

    @property
    def n_nuisance(self) -> int:
        """Leading columns of every stacked design that are nuisance offsets."""
        return len(self.axes) if self.offsets else 0

    def stacked(self, terms: Sequence[Term], rows: Any = slice(None)) -> FloatArray:
        """(rows·axes, n_nuisance + Σp) design: the offsets, then each term's columns."""
        n_rows = len(self.y[rows])
        cols = [np.tile(np.eye(len(self.axes)), (n_rows, 1))] if self.offsets else []
        cols += [self.design(t, rows) for t in terms]
        return np.hstack(cols) if cols else np.zeros((n_rows * len(self.axes), 0))


#: Blocks of time per fold in :attr:`Problem.time_folds` (5 folds → 25 blocks, dealt to the
#: folds in a seeded shuffled order).
TIME_BLOCKS_PER_FOLD = 5


def _time_blocks(t_s: FloatArray, n_folds: int, seed: int) -> list[NDArray[np.intp]]:
    """Folds of :data:`TIME_BLOCKS_PER_FOLD` blocks of time each, dealt in a shuffled order."""
    n = len(t_s)
    rank = np.argsort(np.argsort(t_s, kind="stable"), kind="stable")
    n_blocks = n_folds * TIME_BLOCKS_PER_FOLD
    block = rank * n_blocks // max(n, 1)
    # blocks dealt to the folds in a shuffled order, not in turn: a session that repeats a
    # cycle of positions (ISO 230-2 runs: 5 blocks per cycle) would otherwise give each fold
    # the same positions of every cycle, never seen in training
    deal = np.random.default_rng(seed + 1).permutation(n_blocks) % n_folds
    return [f for f in (np.flatnonzero(deal[block] == j) for j in range(n_folds)) if len(f)]


def make_problem(res: Residuals, n_folds: int = 5, seed: int = 0) -> Problem:
    """Folds by ``group`` (groups shuffled into ``n_folds`` folds), else by blocks of time dealt
    in a shuffled order (:func:`_time_blocks`), else by blocks of consecutive rows: held-out
    points are never neighbours of training points in the same artefact position / time.

    Not five consecutive fifths of the time: a session of one back-and-forth cycle (one group)
    then holds out the far end of the travel in both directions at once (the middle fifth of the
    time), which no positional table fitted on the rest can predict — a 35 µm sensor linearity,
    a thermal drift and a ripple of a one-cycle session went unnamed, their tables' held-out
    error 2.6× that of no table (``mixed/bidirectional/s4000`` of the reference generator)."""
    r = res.residual_um
    axes = tuple(k for k in range(3) if np.any(r[:, k] != 0.0))
    data = res.data
    n = data.n
    timed = data.t_s is not None and float(np.ptp(data.t_s)) > 0
    if data.group is not None and len(np.unique(data.group)) >= 2:
        labels = np.unique(data.group)
        rng = np.random.default_rng(seed)
        order = rng.permutation(len(labels))
        k = min(n_folds, len(labels))
        fold_of = {labels[i]: j % k for j, i in enumerate(order)}
        which = np.array([fold_of[g] for g in data.group])
        folds = [np.flatnonzero(which == j) for j in range(k)]
    elif timed:
        assert data.t_s is not None
        folds = _time_blocks(data.t_s, n_folds, seed)
    else:
        which = np.arange(n) * n_folds // max(n, 1)
        folds = [np.flatnonzero(which == j) for j in range(n_folds)]
    time_folds = _time_blocks(data.t_s, n_folds, seed) if timed and data.t_s is not None else None
    return Problem(
        res=res, axes=axes or (0,), folds=[f for f in folds if len(f)], time_folds=time_folds
    )


def lstsq(x: FloatArray, y: FloatArray) -> tuple[FloatArray, float, int]:
    """Least squares with column scaling: (coefficients, residual sum of squares, rank)."""
    if x.shape[1] == 0:
        return np.zeros(0), float(np.sum(y**2)), 0
    scale = np.sqrt(np.sum(x**2, axis=0))
    scale[scale == 0] = 1.0
    # QR with column pivoting (LAPACK gelsy): as robust as the SVD for these well-scaled
    # designs and several times faster on the wide generic ones
    beta, _, rank, _ = linalg.lstsq(x / scale, y, cond=1e-10, lapack_driver="gelsy")
    beta = beta / scale
    rss = float(np.sum((y - x @ beta) ** 2))
    return beta, rss, int(rank)


def _rows_index(rows: Any) -> Any:
    return slice(None) if rows is None else rows


def fit(
    problem: Problem, terms: Sequence[Term], rows: Any = None, ridge: bool = False
) -> tuple[FloatArray, float, int]:
    """Joint least-squares fit of ``terms`` on ``rows`` (all when None). With ``ridge``, terms
    that declare a ridge penalty are shrunk (predictions: cross-validation, the final fit); the
    significance tests use plain least squares throughout."""
    r = _rows_index(rows)
    x, y = problem.stacked(terms, r), problem.y[r].reshape(-1)
    if not ridge or not any(t.candidate.ridge or t.candidate.prior_sd for t in terms):
        return lstsq(x, y)
    # a ridge prior (coefficients shrink to 0 where the term's columns see no data): penalty
    # rows appended; the returned RSS is that of the data rows only
    s2 = float(np.mean(y**2)) if y.size else 0.0
    weights = np.concatenate(
        [np.zeros(problem.n_nuisance)] + [_penalty(t.candidate, s2) for t in terms]
    )
    keep = weights > 0
    pen = np.diag(weights)[keep]
    beta, _, rank = lstsq(np.vstack([x, pen]), np.concatenate([y, np.zeros(pen.shape[0])]))
    return beta, float(np.sum((y - x @ beta) ** 2)), rank


def _penalty(cand: Candidate, s2: float) -> FloatArray:
    """Per coefficient of ``cand``, the weight of its penalty row: √ridge, or σ/prior for a
    coefficient with a prior (``s2`` the mean square of the residual fitted)."""
    w = np.full(cand.n_params, np.sqrt(cand.ridge))
    for j, sd in enumerate(cand.prior_sd or ()):
        if sd is not None and sd > 0 and j < cand.n_params:
            w[j] = max(w[j], np.sqrt(s2) / sd)
    return w


def _projector(x: FloatArray) -> FloatArray | None:
    if x.shape[1] == 0:
        return None
    q, rdiag = np.linalg.qr(x)
    keep = np.abs(np.diag(rdiag)) > 1e-10 * max(1.0, float(np.max(np.abs(np.diag(rdiag)))))
    return q[:, keep]


def _profile_rss(
    problem: Problem, cand: Candidate, theta: Any, r: Any, q: FloatArray | None, y: FloatArray
) -> tuple[float, int]:
    xc = problem.design(Term(cand, theta), r)
    if q is not None:
        xc = xc - q @ (q.T @ xc)
        y = y - q @ (q.T @ y)
    _, rss, rank = lstsq(xc, y)
    return rss, rank


#: Budget (float64 values) of one block of designs profiled at once.
_PROFILE_BLOCK = 4_000_000


def _designs_for(problem: Problem, cand: Candidate, thetas: Sequence[Any], r: Any) -> FloatArray:
    """(rows·axes, T, p) stacked designs of ``cand`` at each theta."""
    if cand.design_many is not None and cand.design_component is None:
        x = cand.design_many(problem.res, thetas)[r][:, problem.axes]
        return x.reshape(-1, x.shape[2], x.shape[3])
    return np.stack([problem.design(Term(cand, th), r) for th in thetas], axis=1)


#: Eigenvalues of a candidate's projected Gram matrix below this fraction of its columns'
#: unprojected squared norms are directions the accepted terms already span (the Gram matrix is
#: formed as XᵀX − CᵀC, whose cancellation error is ~1e-15 of the unprojected norms).
_GRAM_KEEP = 1e-9


def _gain_from_gram(g: FloatArray, b: FloatArray) -> tuple[FloatArray, NDArray[np.intp]]:
    """Per theta: the RSS reduction bᵀG⁺b and the rank of G ((T, p, p) Gram matrices of columns
    scaled to unit unprojected norm, (T, p) right-hand sides)."""
    w, v = np.linalg.eigh(g)
    keep = w > _GRAM_KEEP
    vb = np.einsum("tpq,tp->tq", v, b)
    gain = np.sum(np.where(keep, vb**2 / np.where(keep, w, 1.0), 0.0), axis=1)
    return gain, np.sum(keep, axis=1)


def profile_rss(
    problem: Problem,
    cand: Candidate,
    thetas: Sequence[Any],
    r: Any,
    q: FloatArray | None,
    y: FloatArray,
) -> tuple[FloatArray, NDArray[np.intp]]:
    """RSS and rank of ``cand`` at every theta with the columns of ``q`` (orthonormal: the
    accepted terms) projected out — all thetas at once by normal equations on scaled columns:
    G = XᵀX − (QᵀX)ᵀ(QᵀX), b = (y − QQᵀy)ᵀX, never forming the projected design. A candidate
    whose design lies on one error component (``design_component``: a periodic error of an
    axis' scale) is profiled on that component's rows only."""
    if q is not None:
        y = y - q @ (q.T @ y)
    yy = float(y @ y)
    m = y.size
    p = cand.n_params
    rss = np.empty(len(thetas))
    rank = np.empty(len(thetas), dtype=np.intp)
    comp = cand.design_component
    if comp is not None and cand.design_many is not None:
        if comp not in problem.axes:  # the component is never measured: nothing to explain
            return np.full(len(thetas), yy), np.zeros(len(thetas), dtype=np.intp)
        pos, n_ax = problem.axes.index(comp), len(problem.axes)
        y_k = y[pos::n_ax]
        q_k = None if q is None else q[pos::n_ax]
        step = max(1, _PROFILE_BLOCK // max(y_k.size * p, 1))
        for i0 in range(0, len(thetas), step):
            xk = cand.design_many(problem.res, thetas[i0 : i0 + step])[r]  # (n, T, p)
            rss[i0 : i0 + xk.shape[1]], rank[i0 : i0 + xk.shape[1]] = _profile_block(
                xk, q_k, y_k, yy
            )
        return rss, rank
    step = max(1, _PROFILE_BLOCK // max(m * p, 1))
    for i0 in range(0, len(thetas), step):
        x3 = _designs_for(problem, cand, thetas[i0 : i0 + step], r)
        rss[i0 : i0 + x3.shape[1]], rank[i0 : i0 + x3.shape[1]] = _profile_block(x3, q, y, yy)
    return rss, rank


def _profile_block(
    x3: FloatArray, q: FloatArray | None, y: FloatArray, yy: float
) -> tuple[FloatArray, NDArray[np.intp]]:
    """RSS and rank for a block of designs ``x3`` (rows, T, p), ``y`` already projected."""
    n, t, p = x3.shape
    x = x3.reshape(n, t * p)
    g = np.empty((t, p, p))
    for a in range(p):
        for c in range(a, p):
            g[:, a, c] = g[:, c, a] = np.einsum("mt,mt->t", x3[:, :, a], x3[:, :, c])
    scale = np.sqrt(np.einsum("tpp->tp", g)).reshape(-1)
    scale[scale == 0] = 1.0
    b = (y @ x).reshape(t, p)
    if q is not None:
        cq = (q.T @ x).reshape(-1, t, p)  # (r, T, p)
        g -= np.einsum("rta,rtc->tac", cq, cq)
    s = scale.reshape(t, p)
    g /= s[:, :, None] * s[:, None, :]
    gain, rank = _gain_from_gram(g, b / s)
    return np.maximum(yy - gain, 0.0), rank


def _near(thetas: Sequence[Any], theta: Any, width: int) -> Sequence[Any]:
    """The grid values within ``width`` steps of the one closest to ``theta``."""
    if not isinstance(theta, float):
        return thetas
    i = int(np.argmin(np.abs(np.asarray(thetas, dtype=float) - theta)))
    return thetas[max(i - width, 0) : i + width + 1]


def best_theta(
    problem: Problem,
    base: Sequence[Term],
    cand: Candidate,
    rows: Any = None,
    near: Any = None,
    refine: bool = True,
) -> tuple[Any, float, int]:
    """Profile ``cand``'s nonlinear parameter with ``base`` fitted jointly: (theta, rss, rank).
    With ``near``, only the grid values within a few steps of it are scanned (a local re-profile,
    e.g. inside a cross-validation fold) before the continuous refinement; ``refine=False``
    stops at the best grid value (a quick screen: the refined RSS is never higher)."""
    r = _rows_index(rows)
    y = problem.y[r].reshape(-1)
    q = problem.projector(base, r)
    if len(cand.thetas) == 1:
        rss, rank = _profile_rss(problem, cand, cand.thetas[0], r, q, y)
        return cand.thetas[0], rss, rank
    thetas = cand.thetas if near is None else _near(cand.thetas, near, 3)
    rss_all, rank_all = profile_rss(problem, cand, thetas, r, q, y)
    i = int(np.argmin(rss_all))
    theta, rss, rank = thetas[i], float(rss_all[i]), int(rank_all[i])
    if refine and cand.theta_step is not None and isinstance(theta, tuple):
        theta, rss, rank = _refine_tuple(problem, cand, theta, r, q, y, rss, rank)
    elif refine and isinstance(theta, float):
        lo = thetas[max(i - 1, 0)]
        hi = thetas[min(i + 1, len(thetas) - 1)]
        lo, hi = min(lo, hi), max(lo, hi)
        if hi > lo:
            sol = optimize.minimize_scalar(
                lambda th: _profile_rss(problem, cand, float(th), r, q, y)[0],
                bounds=(lo, hi),
                method="bounded",
                options={"xatol": 1e-4 * (hi - lo)},
            )
            if sol.fun < rss:
                theta = float(sol.x)
                rss, rank = _profile_rss(problem, cand, theta, r, q, y)
    return theta, rss, rank


def _refine_tuple(
    problem: Problem,
    cand: Candidate,
    theta: tuple[Any, ...],
    r: Any,
    q: FloatArray | None,
    y: FloatArray,
    rss: float,
    rank: int,
) -> tuple[Any, float, int]:
    """Continuous refinement of a tuple parameter ``(kind, v1, v2, …)`` (a ripple's period law)
    by Nelder–Mead on its numbers, started at the grid's best with steps ``cand.theta_step``."""
    steps = np.asarray(cand.theta_step, dtype=float)
    x0 = np.asarray(theta[1:], dtype=float)

    def at(z: FloatArray) -> tuple[Any, ...]:
        return (theta[0], *(float(v) for v in x0 + z * steps))

    def cost(z: FloatArray) -> float:
        try:
            return _profile_rss(problem, cand, at(z), r, q, y)[0]
        except ValueError:  # a law outside its domain (r0 inside the travel …)
            return float("inf")

    simplex = np.vstack([np.zeros(len(x0)), np.eye(len(x0))])
    sol = optimize.minimize(
        cost,
        np.zeros(len(x0)),
        method="Nelder-Mead",
        options={"initial_simplex": simplex, "xatol": 1e-3, "fatol": 1e-6 * rss, "maxfev": 200},
    )
    if np.isfinite(sol.fun) and sol.fun < rss:
        best = at(sol.x)
        rss, rank = _profile_rss(problem, cand, best, r, q, y)
        return best, rss, rank
    return theta, rss, rank


def f_test_p(rss0: float, rss1: float, extra: int, n: int, p_total: int) -> float:
    """p-value of the nested-model F-test (``extra`` parameters added, ``p_total`` in the bigger
    model, ``n`` observations)."""
    dof = n - p_total
    if extra <= 0 or dof <= 0 or rss1 <= 0:
        return 1.0
    f = ((rss0 - rss1) / extra) / (rss1 / dof)
    return float(stats.f.sf(max(f, 0.0), extra, dof))


def cv_predictions(
    problem: Problem,
    terms: Sequence[Term],
    rescan: bool = True,
    folds: Sequence[NDArray[np.intp]] | None = None,
) -> FloatArray:
    """(N, 3) out-of-fold predictions: each fold predicted by the terms fitted on the others
    (nonlinear parameters re-profiled on the training folds when ``rescan``); ``folds``
    default: the problem's main folds."""
    res = problem.res
    pred = np.zeros((res.n, 3))
    if not terms and not problem.offsets:
        return pred
    for test in problem.folds if folds is None else folds:
        train = problem.training_rows(np.asarray(test))
        fold_terms: list[Term] = []
        for i, t in enumerate(terms):
            # (a ripple's period law is kept: its few numbers are pinned by thousands of points)
            if rescan and len(t.candidate.thetas) > 1 and t.candidate.theta_step is None:
                others = [*fold_terms, *terms[i + 1 :]]
                theta, _, _ = best_theta(problem, others, t.candidate, train, near=t.theta)
                fold_terms.append(Term(t.candidate, theta))
            else:
                fold_terms.append(t)
        beta, _, _ = fit(problem, fold_terms, train, ridge=True)
        x_test = _held_out_design(problem, fold_terms, train, test)
        p = (x_test @ beta).reshape(len(test), len(problem.axes))
        pred[np.ix_(test, np.asarray(problem.axes, dtype=np.intp))] = p
    return pred


#: How far back a start-up transient is extrapolated before a training span: at most this factor
#: of its value at the span's first training time (the transient's e-folding law, not a fit).
TRANSIENT_BACK = 2.0


def _held_out_design(
    problem: Problem, terms: Sequence[Term], train: NDArray[np.intp], test: NDArray[np.intp]
) -> FloatArray:
    """The stacked design of ``test`` rows, with the columns of terms that are not extrapolated
    in time (``Candidate.hold_time``) evaluated at the time clipped to the training span, and
    the start-up transient of a ``start_state`` term extrapolated back before the training span
    by at most :data:`TRANSIENT_BACK` (left out where its time constant is unknown)."""
    x = problem.stacked(terms, test)
    t = problem.res.signals.get("t")
    if t is None or not any(term.candidate.timed for term in terms):
        return x
    lo, hi = float(np.min(t[train])), float(np.max(t[train]))
    t_test = t[test]
    if float(np.min(t_test)) >= lo and float(np.max(t_test)) <= hi:
        return x
    before = t_test < lo
    if np.any(before):
        # a start-up transient (∝ e^{−(t−t₀)/τ}) is extrapolated back before the training span
        # by at most a factor TRANSIENT_BACK: what later blocks saw of it fixes its size only
        # where it had not yet decayed much (a structure hours from equilibrium: the decay is
        # the lag's physics), never the state at the start of a fast one they did not see
        col = problem.n_nuisance
        for term in terms:
            cols = [col + j for j in term.candidate.transient_columns]
            if cols:
                tau = float(term.theta) if isinstance(term.theta, float | int) else 0.0
                if tau > 0.0:
                    t_cap = lo - tau * np.log(TRANSIENT_BACK)
                    shrink = np.exp(-np.maximum(t_cap - t_test, 0.0) / tau)
                    factor = np.where(before, shrink, 1.0)
                else:
                    factor = np.where(before, 0.0, 1.0)
                f_rows = np.repeat(factor, len(problem.axes))
                x[:, np.asarray(cols)] *= f_rows[:, None]
            col += term.candidate.n_params
    if not any(term.candidate.hold_time for term in terms):
        return x
    sub = problem.res.subset(test)
    sub = replace(sub, signals={**sub.signals, "t": np.clip(t_test, lo, hi)})
    col = problem.n_nuisance
    for term in terms:
        n_p = term.candidate.n_params
        if term.candidate.hold_time:
            d = term.candidate.design_uncached(sub, term.theta)[:, problem.axes, :]
            x[:, col : col + n_p] = d.reshape(-1, n_p)
        col += n_p
    return x


def cv_mse(
    problem: Problem,
    terms: Sequence[Term],
    rescan: bool = True,
    folds: Sequence[NDArray[np.intp]] | None = None,
) -> float:
    """Mean squared out-of-fold residual per measured component (µm²)."""
    pred = cv_predictions(problem, terms, rescan, folds)
    r = problem.res.residual_um - pred
    return float(np.mean(r[:, problem.axes] ** 2))


def predictions(problem: Problem, terms: Sequence[Term], beta: FloatArray) -> FloatArray:
    """(N, 3) fitted displacement of ``terms`` with coefficients ``beta`` at all points."""
    out = np.zeros((problem.res.n, 3))
    if beta.size:
        out[:, problem.axes] = (problem.stacked(terms) @ beta).reshape(problem.res.n, -1)
    return out


def split_coefficients(
    problem: Problem, terms: Sequence[Term], beta: FloatArray
) -> list[list[float]]:
    """Each term's coefficients (the nuisance offsets first in ``beta`` are skipped)."""
    out, i = [], problem.n_nuisance
    for t in terms:
        out.append([float(v) for v in beta[i : i + t.candidate.n_params]])
        i += t.candidate.n_params
    return out


def cv_gain(
    problem: Problem,
    base: Sequence[Term],
    with_term: Sequence[Term],
    folds: Sequence[NDArray[np.intp]] | None = None,
) -> float:
    """Relative held-out gain of ``with_term`` over ``base``, both on ``folds`` (None: the main
    folds): (cv₀ − cv₁)/cv₀, 0 when cv₀ is 0."""
    cv0 = cv_mse(problem, base, folds=folds)
    return (cv0 - cv_mse(problem, with_term, folds=folds)) / cv0 if cv0 > 0 else 0.0


T = TypeVar("T")


def one_blas_thread(fn: Callable[..., T]) -> Callable[..., T]:
    """Run ``fn`` with BLAS on one thread: the matrices are a few thousand rows by tens of
    columns, where threads only cost (measured on a busy 2-core machine: an SVD of 2100 × 132
    took 2.6–4.1 s with two OpenBLAS threads, 0.02–0.05 s with one)."""

    @functools.wraps(fn)
    def run(*args: Any, **kwargs: Any) -> T:
        from threadpoolctl import threadpool_limits

        with threadpool_limits(limits=1, user_api="blas"):
            return fn(*args, **kwargs)

    return run
