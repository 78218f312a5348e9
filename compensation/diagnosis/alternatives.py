"""Explanations a session cannot tell apart, and the measurement that would separate them.

After selection, each accepted cause is swapped in turn for every other candidate (the other
accepted causes kept, nonlinear parameters re-profiled). A candidate whose fit — at its default
shape or, for a cause of the named one's kind (tables and couplings are one kind), its rich
shape, each parameter beyond the named term's charged one noise variance and each one fewer
credited one — is worse by less
than the ``1 − alpha`` quantile of χ²(1) times the noise variance is an *alternative*: the data
do not prefer the named cause over it. Typical case: with one stylus straight down, an angular
error of Z and a straightness of Z have the same Abbe arm and act identically.

Which measurement separates them is decided by simulation, not by a rule table: the named
effect's displacement is evaluated on hypothetical variants of the same session (a longer stylus,
styli offset sideways, the artefact spread over the whole volume, a wider temperature range) and
the alternative is fitted to it; the variant where it fits worst is the advice.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import numpy as np
from scipy import stats

from ..effects import Effect
from ..kinematics import first_order_jacobian
from .candidates import Candidate, effect_displacement_um
from .fitting import Problem, Term, best_theta
from .residuals import FloatArray, Residuals

__all__ = ["find_alternatives", "separating_measurement"]

#: Causes of one kind: geometric shapes of the tables (a table of one carriage and a twist of
#: another act alike through the chain); any other cause is a kind of its own.
_GEOMETRIC = frozenset({"parametric", "coupling"})


def _kind(cause: str) -> str:
    return "geometric" if cause in _GEOMETRIC else cause


#: Above this relative misfit in a hypothetical session, the measurement separates the two.
SEPARATES = 0.3


def _hypothetical(
    res: Residuals,
    *,
    stylus_add_mm: FloatArray | None = None,
    positions_mm: FloatArray | None = None,
    temperature_scale: float | None = None,
) -> Residuals:
    """The session's points with a different stylus, positions or temperature swing (designs
    only: predicted and residual are zero)."""
    m = res.machine
    data = res.data.subset(slice(None))
    q = res.q_mm.copy() if positions_mm is None else np.asarray(positions_mm, dtype=float)
    stylus = res.stylus_mm.copy()
    if stylus_add_mm is not None:
        stylus = stylus + stylus_add_mm
    data.indicated_mm = q
    data.reference_mm = q.copy()
    data.stylus_mm = stylus
    signals = {k: v.copy() for k, v in res.signals.items()}
    if temperature_scale is not None:
        ref_c = m.thermal.reference_C
        for name in list(signals):
            if name.startswith("T_"):
                signals[name] = ref_c + (signals[name] - ref_c) * temperature_scale
    jac, sq = first_order_jacobian(m.chain, q - m.volume.reference_mm, stylus)
    zero = np.zeros((res.n, 3))
    return Residuals(
        machine=m,
        data=data,
        stylus_mm=stylus,
        signals=signals,
        predicted_um=zero,
        residual_um=zero.copy(),
        jacobian=jac,
        squareness_jacobian=sq,
    )


def _variants(res: Residuals) -> list[tuple[str, Residuals]]:
    n = res.n
    rng = np.random.default_rng(0)
    lo, hi = res.machine.volume.lower_mm, res.machine.volume.upper_mm
    sideways = np.zeros((n, 3))
    sideways[::2, 0] = 100.0
    sideways[1::2, 1] = 100.0
    longer = np.zeros((n, 3))
    longer[::2, 2] = -100.0  # half the points: a second stylus length beside the first
    out = [
        ("a second stylus length (e.g. 100 mm longer)", _hypothetical(res, stylus_add_mm=longer)),
        (
            "styli offset sideways (e.g. ±100 mm in x and y)",
            _hypothetical(res, stylus_add_mm=sideways),
        ),
        (
            "the artefact at other positions, spread over the whole volume",
            _hypothetical(res, positions_mm=lo + rng.random((n, 3)) * (hi - lo)),
        ),
    ]
    if any(k.startswith("T_") for k in res.data.temps_C):
        out.append(
            ("a session over a wider temperature range", _hypothetical(res, temperature_scale=3.0))
        )
    return out


def _misfit(target: FloatArray, x: FloatArray) -> float:
    """Relative misfit of the best combination of the columns of ``x`` (N, 3, p) to ``target``."""
    t = target.reshape(-1)
    norm = float(np.linalg.norm(t))
    if norm == 0.0:
        return 0.0
    a = x.reshape(-1, x.shape[2])
    coef, *_ = np.linalg.lstsq(a, t, rcond=1e-10)
    return float(np.linalg.norm(t - a @ coef)) / norm


def separating_measurement(
    res: Residuals, effect: Effect, alternative: Candidate, theta: Any
) -> tuple[str, float]:
    """(advice, relative misfit): the hypothetical measurement where ``alternative`` fails most
    to imitate ``effect``; advice says so when none of them separates the two."""
    best = ("", 0.0)
    for text, hyp in _variants(res):
        target = effect_displacement_um(hyp, effect)
        x = alternative.design_uncached(hyp, theta)
        miss = _misfit(target, x)
        if miss > best[1]:
            best = (text, miss)
    if best[1] < SEPARATES:
        return (
            "none of: another stylus length, styli offset sideways, other artefact positions, a "
            "wider temperature range — the two are the same term at first order",
            best[1],
        )
    return best


def find_alternatives(
    problem: Problem,
    others: Sequence[Term],
    term: Term,
    effect: Effect,
    pool: Sequence[Candidate],
    accepted_roots: Sequence[Candidate],
    rss_after: float,
    sigma2: float,
    alpha: float,
) -> dict[str, Any] | None:
    """``{"alternatives": [...], "separate_by": "..."}`` for the accepted ``term``, or None."""
    taken = {c.identity for c in accepted_roots} | {term.candidate.identity}
    threshold = float(stats.chi2.ppf(1.0 - alpha, 1)) * sigma2
    found: list[tuple[float, Candidate, Any]] = []
    n_named = term.candidate.n_params
    for root in pool:
        if root.identity in taken:
            continue
        # the family at its default and, for a cause of the named one's kind (a twist of
        # another carriage, a table of another component), its rich shape: a cause the session
        # cannot tell from the named one may need its richer shape to act alike (a twist that
        # sags along the other axis); each parameter beyond the named term's is charged the σ²
        # it gains from noise, and each one fewer credited it (the named term's extra
        # parameters gained it too: a leaner cause is judged on equal terms)
        rich = root.rich if _kind(root.cause) == _kind(term.candidate.cause) else None
        for cand in (root,) if rich is None else (root, rich):
            theta, rss, _ = best_theta(problem, others, cand)
            charged = rss + sigma2 * (cand.n_params - n_named)
            if charged - rss_after < threshold:
                found.append((charged, cand, theta))
    if not found:
        return None
    found.sort(key=lambda f: f[0])
    advice: list[str] = []
    alternatives: list[dict[str, Any]] = []
    listed: set[tuple[Any, ...]] = set()
    for _, cand, theta in found:
        if cand.identity in listed:  # one entry per identity: its best-fitting variant
            continue
        listed.add(cand.identity)
        keys = {
            k: v
            for k, v in zip(
                ("cause", "component", "axis", "varies_with"), cand.identity, strict=True
            )
            if v is not None
        }
        text, miss = separating_measurement(problem.res, effect, cand, theta)
        alternatives.append(
            {
                **keys,
                "source": cand.source,
                "locked_to": cand.locked_to,
                "separated_by": text,
                "misfit_there": round(miss, 3),
            }
        )
        advice.append(f"{cand.label}: {text}")
    return {"alternatives": alternatives, "separate_by": "; ".join(advice)}
