"""Greedy, out-of-sample model selection: which causes explain the residuals.

Each round, every remaining candidate is fitted jointly with the effects accepted so far
(nonlinear parameter profiled). A candidate is *eligible* when its nested-model F-test p-value,
Bonferroni-corrected for the number of candidates and for the look-elsewhere effect of its scanned
parameter, is below ``alpha``, and its grouped cross-validated MSE improves on the current model's
by at least ``min_cv_gain`` (relative). The eligible candidate with the best CV MSE is accepted
(among CV scores within 0.2 % of the best, the one with fewest parameters: the simpler
explanation). Rounds stop when no candidate is eligible. Then a generic smooth model (position,
time, temperatures, directions) tests whether structure remains that no cause explains
(``unexplained``). Verdict ``none`` when nothing is eligible.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from ..effects import Effect
from ..formats.measurements import Measurements
from ..machine import Machine
from .candidates import Candidate, all_candidates, contract_keys, is_finite_design
from .fitting import (
    Problem,
    Term,
    best_theta,
    cv_mse,
    cv_predictions,
    f_test_p,
    fit,
    make_problem,
    predictions,
    split_coefficients,
)
from .residuals import Residuals, compute_residuals, length_error_e0_um, rms3d
from .unexplained import unexplained_candidate

__all__ = ["Diagnosis", "diagnose"]


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

    def to_json(self) -> dict[str, Any]:
        return {"verdict": self.verdict, "effects": self.entries, **self.summary}

    def extended_machine(self) -> Machine:
        return self.residuals.machine.with_effects(self.effects)


def _round(
    problem: Problem,
    accepted: list[Term],
    pool: list[Candidate],
    alpha: float,
    min_cv_gain: float,
    cv_base: float,
) -> tuple[Term | None, list[dict[str, Any]]]:
    n_obs = problem.y.size
    _, rss0, rank0 = fit(problem, accepted)
    rows: list[dict[str, Any]] = []
    m = max(len(pool), 1)
    for cand in pool:
        theta, rss1, extra = best_theta(problem, accepted, cand)
        p = f_test_p(rss0, rss1, extra, n_obs, rank0 + extra)
        p_adj = min(1.0, p * m * cand.look_elsewhere)
        rows.append(
            {"candidate": cand, "theta": theta, "label": cand.label, "rss": rss1, "p_adj": p_adj}
        )
    eligible = [r for r in rows if r["p_adj"] < alpha]
    for r in eligible:
        r["cv_mse"] = cv_mse(problem, [*accepted, Term(r["candidate"], r["theta"])])
        r["cv_gain"] = (cv_base - r["cv_mse"]) / cv_base if cv_base > 0 else 0.0
    eligible = [r for r in eligible if r["cv_gain"] >= min_cv_gain]
    rows.sort(key=lambda r: r["rss"])
    if not eligible:
        return None, rows
    best_cv = min(r["cv_mse"] for r in eligible)
    close = [r for r in eligible if r["cv_mse"] <= best_cv * 1.002]
    pick = min(close, key=lambda r: (r["candidate"].n_params, r["cv_mse"]))
    return Term(pick["candidate"], pick["theta"]), rows


def diagnose(
    machine: Machine,
    data: Measurements,
    *,
    alpha: float = 1e-3,
    min_cv_gain: float = 0.01,
    max_effects: int = 4,
    n_folds: int = 5,
) -> Diagnosis:
    """Compare ``machine`` with ``data``, find the causes of what it gets wrong (module docstring)."""
    t0 = time.perf_counter()
    res = compute_residuals(machine, data)
    problem = make_problem(res, n_folds)
    pool = [c for c in all_candidates(res) if is_finite_design(c.design(res, c.thetas[0]))]
    accepted: list[Term] = []
    rounds: list[list[dict[str, Any]]] = []
    cv_base = cv_mse(problem, [])
    cv_history = [cv_base]
    while len(accepted) < max_effects:
        remaining = [c for c in pool if all(c is not t.candidate for t in accepted)]
        term, rows = _round(problem, accepted, remaining, alpha, min_cv_gain, cv_history[-1])
        rounds.append(_public_rows(rows))
        if term is None:
            break
        accepted.append(term)
        # re-profile the earlier terms' nonlinear parameters given the new one
        for i, t in enumerate(accepted):
            if len(t.candidate.thetas) > 1:
                others = accepted[:i] + accepted[i + 1 :]
                theta, _, _ = best_theta(problem, others, t.candidate)
                accepted[i] = Term(t.candidate, theta)
        cv_history.append(cv_mse(problem, accepted))

    beta, rss_after, rank_after = fit(problem, accepted)
    fitted = predictions(problem, accepted, beta)
    heldout_pred = cv_predictions(problem, accepted)
    coefs = split_coefficients(accepted, beta)
    effects = [t.candidate.build(c, t.theta) for t, c in zip(accepted, coefs, strict=True)]
    rss_before = float(np.sum(problem.y**2))
    entries: list[dict[str, Any]] = []
    for i, (eff, t) in enumerate(zip(effects, accepted, strict=True)):
        _, rss_without, _ = fit(problem, accepted[:i] + accepted[i + 1 :])
        entry = {**contract_keys(eff), "parameters": eff.describe().get("parameters", {})}
        entry["explained_fraction"] = (rss_without - rss_after) / rss_before if rss_before else 0.0
        entry["label"] = t.candidate.label
        entries.append(entry)
    order = np.argsort([-e["explained_fraction"] for e in entries], kind="stable")
    entries = [entries[i] for i in order]
    effects = [effects[i] for i in order]

    # structure no cause explains?
    unexplained = unexplained_candidate(problem, accepted, alpha, min_cv_gain, cv_history[-1])
    if unexplained is not None:
        entries.append(unexplained)

    r_before = res.residual_um
    r_after = r_before - fitted
    r_heldout = r_before - heldout_pred
    n_obs = problem.y.size
    sigma = float(np.sqrt(rss_after / max(n_obs - rank_after, 1)))
    summary = {
        "residual_rms_um": {"before": rms3d(r_before), "after": rms3d(r_after)},
        "heldout_rms_um": {"before": rms3d(r_before), "after": rms3d(r_heldout)},
        "e0_um": {
            "before": length_error_e0_um(data.reference_mm, r_before, data.group),
            "after": length_error_e0_um(data.reference_mm, r_heldout, data.group),
            "definition": "max |length error| over point pairs of one group (artefact "
            "position); 'after' uses out-of-fold predictions",
        },
        "noise_sigma_um": sigma,
        "n_points": int(data.n),
        "measured_axes": ["xyz"[k] for k in problem.axes],
        "folds": len(problem.folds),
        "heldout_method": "grouped cross-validation: each fold predicted by the effects fitted "
        "on the other folds (nonlinear parameters re-profiled)",
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
