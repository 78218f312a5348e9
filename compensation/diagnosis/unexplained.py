"""Structure no known cause explains: a generic smooth model of what remains.

Per measured axis, the remaining residual is fitted with Legendre products of total degree ≤ 3
in the normalised position, Legendre polynomials (1–4) of time, linear terms in every temperature
given and the travel directions. If that model passes the same F-test (at ``alpha``, Bonferroni
over its blocks) and CV-gain rule as a cause, the residual has structure the causes do not
explain: reported as ``unexplained`` with the block (position / time / temperature / direction)
that carries most of it, never as an effect of the model.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from itertools import product
from typing import Any

import numpy as np
from numpy.polynomial import legendre
from numpy.typing import NDArray
from scipy.spatial import cKDTree

from .candidates import Candidate
from .fitting import Problem, Term, cv_mse, f_test_p, fit
from .residuals import FloatArray, Residuals


def _leg(s: FloatArray, k: int) -> FloatArray:
    c = np.zeros(k + 1)
    c[k] = 1.0
    return np.asarray(legendre.legval(s, c), dtype=float)


def _norm(v: FloatArray) -> FloatArray:
    lo, hi = float(np.min(v)), float(np.max(v))
    return np.zeros_like(v) if hi <= lo else 2 * (v - lo) / (hi - lo) - 1


def generic_blocks(res: Residuals) -> dict[str, FloatArray]:
    """Scalar basis functions (N, k) per block name."""
    s = [_norm(res.q_mm[:, k]) for k in range(3)]
    moved = [float(np.ptp(res.q_mm[:, k])) > 1e-6 for k in range(3)]
    pos = []
    for i, j, k in product(range(4), repeat=3):
        if (
            0 < i + j + k <= 3
            and (i == 0 or moved[0])
            and (j == 0 or moved[1])
            and (k == 0 or moved[2])
        ):
            pos.append(_leg(s[0], i) * _leg(s[1], j) * _leg(s[2], k))
    blocks: dict[str, FloatArray] = {"position": np.column_stack([np.ones(res.n), *pos])}
    d = res.data
    if d.t_s is not None and np.ptp(d.t_s) > 0:
        ts = _norm(d.t_s)
        blocks["time"] = np.column_stack([_leg(ts, k) for k in range(1, 5)])
    temps = [v - np.mean(v) for v in d.temps_C.values() if np.ptp(v) > 0]
    if temps:
        blocks["temperature"] = np.column_stack(temps)
    dirs = [v for v in d.directions.values() if np.ptp(v) > 0]
    if dirs:
        blocks["direction"] = np.column_stack(dirs)
    return blocks


def _block_candidate(name: str, basis: FloatArray) -> Candidate:
    k = basis.shape[1]

    def design(_res: Residuals, _theta: Any) -> FloatArray:
        x = np.zeros((basis.shape[0], 3, 3 * k))
        for a in range(3):
            x[:, a, a * k : (a + 1) * k] = basis
        return x

    return Candidate("unexplained", {"block": name}, 3 * k, lambda _a, _t: None, design_fn=design)  # type: ignore[arg-type,return-value]


#: Centres of the local (radial) basis per moved coordinate, in the normalised range [-1, 1],
#: and the width of each Gaussian (same units): a defect a fifth of the travel wide or more.
LOCAL_CENTRES = (-1.0, -1.0 / 3.0, 1.0 / 3.0, 1.0)
LOCAL_WIDTH = 0.45
#: Ridge penalty of the local basis (one observation's worth per coefficient): a coefficient
#: whose Gaussian covers no training point shrinks to zero instead of extrapolating.
LOCAL_RIDGE = 3.0
#: The finer grid of the local basis' rich shape.
RICH_CENTRES = (-1.0, -0.5, 0.0, 0.5, 1.0)
RICH_WIDTH = 0.3


def local_basis(
    res: Residuals, centres: tuple[float, ...] = LOCAL_CENTRES, width: float = LOCAL_WIDTH
) -> FloatArray | None:
    """(N, k) Gaussian radial basis on a grid over the moved coordinates (None when fewer than
    two coordinates moved: along one axis a local defect is a table of that axis)."""
    moved = [k for k in range(3) if float(np.ptp(res.q_mm[:, k])) > 1e-6]
    if len(moved) < 2:
        return None
    s = [_norm(res.q_mm[:, k]) for k in moved]
    c = np.asarray(centres)
    per_axis = [np.exp(-0.5 * ((v[:, None] - c[None, :]) / width) ** 2) for v in s]
    basis = per_axis[0]
    for b in per_axis[1:]:
        basis = (basis[:, :, None] * b[:, None, :]).reshape(res.n, -1)
    return basis


def local_candidates(res: Residuals) -> list[Candidate]:
    """One generic local candidate per error component (``unexplained``, ``block: local``): the
    null model "a smooth bump somewhere in the volume" that every cause must beat. Accepted, it
    is reported as ``unexplained`` with where it sits, never as an effect."""
    basis = local_basis(res)
    rich = local_basis(res, RICH_CENTRES, RICH_WIDTH)
    if basis is None or rich is None:
        return []

    def design_of(b: FloatArray, a: int) -> Callable[[Residuals, Any], FloatArray]:
        def design(_res: Residuals, _theta: Any) -> FloatArray:
            x = np.zeros((b.shape[0], 3, b.shape[1]))
            x[:, a, :] = b
            return x

        return design

    out = []
    for a in range(3):
        cand = Candidate(
            "unexplained",
            {"block": "local", "error_axis": "xyz"[a]},
            basis.shape[1],
            lambda _a, _t: None,  # type: ignore[arg-type,return-value]
            design_fn=design_of(basis, a),
            ridge=LOCAL_RIDGE,
        )
        # its rich shape (a finer grid, in the significance tests only) absorbs what the
        # smooth bump leaves, so no table is named for the leftovers of a local defect
        out.append(cand.with_rich(n_params=rich.shape[1], design_fn=design_of(rich, a)))
    return out


def is_local(cand: Candidate) -> bool:
    return cand.cause == "unexplained"


def local_entry(
    problem: Problem, accepted: list[Term], indices: list[int], beta: FloatArray
) -> dict[str, Any]:
    """The one ``unexplained`` entry of the accepted local candidates at ``indices`` (a bump is
    fitted per error component; one entry says where their sum sits)."""
    contrib = np.zeros((problem.res.n, 3))
    for index in indices:
        term = accepted[index]
        start = problem.n_nuisance + sum(t.candidate.n_params for t in accepted[:index])
        coef = beta[start : start + term.candidate.n_params]
        contrib[:, problem.axes] += (problem.design(term) @ coef).reshape(problem.res.n, -1)
    _, rss0, _ = fit(problem, [t for i, t in enumerate(accepted) if i not in indices])
    _, rss1, _ = fit(problem, accepted)
    total = float(np.sum(problem.y**2))
    params: dict[str, Any] = {"varies_mostly_with": "position", "local": True}
    # located on the data (the residual with the bump added back), not on the fitted local
    # basis: its Gaussians sit on a fixed grid and are shrunk, which pulls a bump at an edge
    # towards the grid's interior
    others = np.zeros((problem.res.n, 3))
    others[:, problem.axes] = (problem.stacked(accepted) @ beta).reshape(problem.res.n, -1)
    partial = problem.res.residual_um - others + contrib
    causes = [t for i, t in enumerate(accepted) if i not in indices]
    extra = problem.stacked(causes)[:, problem.n_nuisance :] if causes else None
    params.update(locate(problem.res, partial, extra))
    return {
        "cause": "unexplained",
        "parameters": params,
        "explained_fraction": (rss0 - rss1) / total if total else 0.0,
    }


def unexplained_candidate(
    problem: Problem,
    accepted: list[Term],
    alpha: float,
    min_cv_gain: float,
    cv_current: float,
    accepted_rich: list[Term] | None = None,
    folds: Sequence[NDArray[np.intp]] | None = None,
) -> dict[str, Any] | None:
    """The ``unexplained`` entry (docs/formats.md §4) when a generic model still pays, else None.

    Significance is judged beside the accepted causes at their *rich* shapes
    (``accepted_rich``, default ``accepted``): what a cause's richer shape absorbs is that cause
    mis-shaped, not structure no cause explains."""
    blocks = generic_blocks(problem.res)
    terms = [Term(_block_candidate(n, b)) for n, b in blocks.items()]
    base = accepted if accepted_rich is None else accepted_rich
    _, rss0, rank0 = fit(problem, base)
    _, rss1, rank1 = fit(problem, [*base, *terms])
    p = f_test_p(rss0, rss1, rank1 - rank0, problem.y.size, rank1)
    if p * len(blocks) >= alpha:
        return None
    _, rss0, rank0 = fit(problem, accepted)
    _, rss1, rank1 = fit(problem, [*accepted, *terms])
    cv1 = cv_mse(problem, [*accepted, *terms], rescan=False, folds=folds)
    gain = (cv_current - cv1) / cv_current if cv_current > 0 else 0.0
    if gain < min_cv_gain:
        return None
    shares = {}
    for i, t in enumerate(terms):
        _, rss_wo, _ = fit(problem, [*accepted, *terms[:i], *terms[i + 1 :]])
        shares[t.candidate.keys["block"]] = max(rss_wo - rss1, 0.0)
    total = float(np.sum(problem.y**2))
    main = max(shares, key=lambda k: shares[k])
    return {
        "cause": "unexplained",
        "parameters": {
            "varies_mostly_with": main,
            "block_sum_of_squares_um2": shares,
            "cv_gain": gain,
            "p_value_adjusted": min(1.0, p * len(blocks)),
        },
        "explained_fraction": (rss0 - rss1) / total if total else 0.0,
    }


def locate(
    res: Residuals, remaining_um: FloatArray, extra: FloatArray | None = None
) -> dict[str, Any]:
    """Where and when the structure that remains sits: the axis carrying most of it, the centre
    and extent (mm) of a bump fitted to it, and the time span (s) of the points near it.

    A first guess is the mean position of the 10 % of points with the largest remaining
    residual on that axis (smoothed over each point's 10 nearest neighbours in position, so
    noise does not pick them). Near an edge of the volume those points all lie on the inner
    side of the bump, so their mean is pulled towards the centre of the volume (by a radius or
    more); the centre is therefore refined by fitting a Gaussian bump
    ``v·exp(−½|(q − c)/(w·span)|²)`` (plus offsets) to the remaining residual — centre c, width
    w, direction v — which may place it at the edge or just beyond the points measured
    (:func:`fit_bump`). ``located_by`` says which of the two was used."""
    r = np.asarray(remaining_um, dtype=float)
    axis = int(np.argmax(np.sum(r**2, axis=0)))
    q = res.q_mm
    span = np.ptp(q, axis=0)
    span[span == 0] = 1.0
    qn = q / span
    n = len(q)
    k = min(10, n)
    _, nn = cKDTree(qn).query(qn, k=k)
    smooth = np.mean(r[np.asarray(nn).reshape(n, k), axis], axis=1)
    top = np.argsort(-np.abs(smooth))[: max(1, n // 10)]
    where = np.mean(q[top], axis=0)
    extent = np.ptp(q[top], axis=0)
    located_by = "largest residuals"
    bump = fit_bump(q, r, where, extra)
    radius = None
    if bump is not None:
        where, radius = bump
        extent = 2.0 * radius
        located_by = "gaussian fit"
    near = np.linalg.norm((q - where) / span, axis=1)
    close = np.argsort(near)[: max(1, n // 10)]
    out: dict[str, Any] = {
        "axis": "xyz"[axis],
        "where_mm": [float(v) for v in where],
        "where_extent_mm": [float(v) for v in extent],
        "mean_there_um": float(np.mean(smooth[top])),
        "located_by": located_by,
    }
    if radius is not None:
        out["radius_mm"] = [float(v) for v in radius]
    t = res.data.t_s
    if t is not None:
        out["when_s"] = [float(np.min(t[close])), float(np.max(t[close]))]
    return out


#: The bump fit's width (fraction of the travel) is kept within these bounds.
BUMP_WIDTH = (0.03, 0.6)


def fit_bump(
    q_mm: FloatArray,
    r_um: FloatArray,
    start_mm: FloatArray,
    extra: FloatArray | None = None,
) -> tuple[FloatArray, FloatArray] | None:
    """(centre mm, radius mm per axis) of the Gaussian bump ``v·exp(−½Σ((q − c)/w)²)`` (a width
    per moved axis) that best fits ``r_um`` (N, 3), started at ``start_mm``. Its amplitudes
    per axis, offsets and the columns of ``extra`` (N·measured axes, p: the other causes named,
    refitted beside it so that what they took of the bump comes back) are linear and
    profiled. None when the fit does not improve on offsets alone or runs away (more than half
    a travel outside)."""
    from scipy import optimize

    moved = np.ptp(q_mm, axis=0) > 1e-6
    if not np.any(moved):
        return None
    lo, span = np.min(q_mm, axis=0), np.where(moved, np.ptp(q_mm, axis=0), 1.0)
    qn = ((q_mm - lo) / span)[:, moved]
    cols = np.flatnonzero(np.any(r_um != 0.0, axis=0))
    n, m = len(q_mm), len(cols)
    y = r_um[:, cols].reshape(-1)
    fixed = [np.kron(np.ones((n, 1)), np.eye(m))]
    if extra is not None and extra.shape[0] == n * m and extra.shape[1]:
        fixed.append(extra)
    base_x = np.hstack(fixed)
    base_coef, *_ = np.linalg.lstsq(base_x, y, rcond=None)
    base = float(np.sum((y - base_x @ base_coef) ** 2))
    k = int(np.sum(moved))

    def rss(p: FloatArray) -> float:
        c, w = p[:k], np.clip(p[k:], *BUMP_WIDTH)
        g = np.exp(-0.5 * np.sum(((qn - c) / w) ** 2, axis=1))
        a = np.hstack([base_x, np.kron(g[:, None], np.eye(m))])
        coef, *_ = np.linalg.lstsq(a, y, rcond=None)
        return float(np.sum((y - a @ coef) ** 2))

    c0 = ((start_mm - lo) / span)[moved]
    best = None
    for w0 in (0.1, 0.2, 0.35):
        x0 = np.concatenate([c0, np.full(k, w0)])
        sol = optimize.minimize(
            rss, x0, method="Nelder-Mead", options={"xatol": 1e-4, "maxfev": 300 * (2 * k)}
        )
        if best is None or sol.fun < best.fun:
            best = sol
    assert best is not None
    c = best.x[:k]
    if not best.fun < 0.9 * base or np.any(c < -0.5) or np.any(c > 1.5):
        return None
    centre = start_mm.astype(float).copy()
    centre[moved] = lo[moved] + c * span[moved]
    radius = np.zeros(3)
    radius[moved] = np.clip(best.x[k:], *BUMP_WIDTH) * span[moved]
    return centre, radius


def local_unexplained(
    problem: Problem, accepted: list[Term], local_hits: list[dict[str, Any]]
) -> dict[str, Any]:
    """The ``unexplained`` entry for significant structure that only global shapes of the wrong
    law could fit (candidates refused by the volume consistency test, :mod:`.consistency`)."""
    first = local_hits[0]
    _, rss0, _ = fit(problem, accepted)
    _, rss1, _ = fit(problem, [*accepted, Term(first["candidate"], first["theta"])])
    total = float(np.sum(problem.y**2))
    return {
        "cause": "unexplained",
        "parameters": {
            "varies_mostly_with": "position",
            "local": True,
            "fits_only_locally": [
                {"label": h["label"], "heldout_over_insample_gain": h["local"]} for h in local_hits
            ],
            "p_value_adjusted": float(first["p_adj"]),
            "cv_gain": float(first["cv_gain"]),
        },
        "explained_fraction": (rss0 - rss1) / total if total else 0.0,
    }
