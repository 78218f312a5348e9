"""What follows the fit (:mod:`.solver`): the covariance marginalised over the estimated
smoothness (docs/calibration.md §5) — the smoothness is an estimate, not a known constant, and a
U conditional on it is too small where the data end. Units: µm, µrad.
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np
from numpy.typing import NDArray

from .normal import Normal
from .solver import CLASS_WEIGHT, LAMBDA_RANGE, Problem, Solution

__all__ = ["smoothness_spread", "with_smoothness_spread"]

FloatArray = NDArray[np.float64]


def with_smoothness_spread(problem: Problem, sol: Solution) -> Solution:
    """``sol`` with :attr:`Solution.covariance_theta` widened by what the smoothness' own
    uncertainty adds (:func:`smoothness_spread`); unchanged when the smoothness was fixed."""
    if problem.fixed_smoothness is not None or not problem.classes:
        return sol
    x_abs = problem.absolute(sol.theta_internal, sol.states)
    normal = Normal(problem, sol.stats, x_abs, sol.lam, pinned=False)
    cov = normal.kept_inverse()
    cov = cov + smoothness_spread(problem, sol.stats, x_abs, sol.lam, cov, normal.step())
    return replace(sol, covariance_theta=problem.theta_covariance(cov[: problem.p, : problem.p]))


def smoothness_spread(
    problem: Problem,
    stats: list[tuple[FloatArray, FloatArray, float]],
    x_abs: FloatArray,
    lam: dict[str, float],
    cov: FloatArray,
    step: FloatArray,
) -> FloatArray:
    """(K, K) what the smoothness' own uncertainty adds to the posterior covariance ``cov`` of
    the kept parameters (:attr:`.solver.Problem.kept`: θ first, the local nuisance eliminated).

    Each class' λ_f is an estimate: its evidence gives log λ_f a posterior of standard deviation
    ``√(2/ν_f)`` (MacKay), ν_f the degrees of freedom behind it (γ_f of the data plus the
    :data:`CLASS_WEIGHT` the class lends). The covariance marginalised over λ is
    ``E[H(λ)⁻¹] + Var[θ̂(λ)]``; both are integrated by 3-point Gauss–Hermite in log λ_f, one class
    at a time (nodes ±√3·s, weight 1/6 each): a rougher λ widens what the data leave to the
    prior (where the data end: the volume's corners), and a solution that moves with λ adds its
    move. Additive over classes (first order in the cross terms)."""
    out = np.zeros_like(cov)
    for f in problem.classes:
        dof = max(problem.gamma.get(f, 0.0), 0.0) + CLASS_WEIGHT
        s = float(np.sqrt(2.0 / dof))
        for sign in (-1.0, 1.0):
            moved = dict(lam)
            moved[f] = float(np.clip(lam[f] * np.exp(sign * np.sqrt(3.0) * s), *LAMBDA_RANGE))
            normal = Normal(problem, stats, x_abs, moved, pinned=False)
            shift = (normal.step() - step)[problem.kept]  # θ̂(λ') − θ̂(λ), linearised
            out += (normal.kept_inverse() - cov + np.outer(shift, shift)) / 6.0
    return out
