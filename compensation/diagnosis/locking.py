"""The locking figures of a cyclic error: how far it moves between the directions of travel in
each coordinate, and whether its phase holds from pass to pass.

Between the passes of the two directions the axis' true position at the same indicated position
differs by the reversal ΔE = e(−) − e(+) (µm). A cyclic error locked to the reference's reading
then appears moved by −ΔE in axis coordinates and by nothing in the reading's; one locked to
the axis' position (a screw, a scale) the opposite: nothing in axis coordinates, +ΔE in the
reading's. The term (its period law fixed) is refitted on each direction alone in both
coordinates; the phase difference of its first harmonic at the centre of the travel, times the
period there, is the shift (µm). A disturbance locked to *time* keeps no phase in either: the
phase of each pass (a run of one direction) is fitted too, and their coherence
R = |mean(e^{iφ})| is ~1 for an error locked to a place, ~1/√passes for one that is not.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import numpy as np

from .candidate import Candidate
from .fitting import Problem, Term
from .periods import _first_harmonic, _harmonic_cov, cyclic_axis, partial_residual
from .residuals import FloatArray

__all__ = ["cyclic_locking", "passes_in_time", "shift_noncentrality"]

#: A pass must hold this many points to get a phase of its own.
MIN_PASS_POINTS = 30


def _phase(x: FloatArray, y: FloatArray, envelope: int) -> tuple[float, float]:
    a = np.column_stack([np.ones(len(y)), x])
    coef, *_ = np.linalg.lstsq(a, y, rcond=None)
    return _first_harmonic(np.asarray(coef[1:], float), envelope, 0.0)


def _wrap(d: float) -> float:
    return float((d + np.pi) % (2.0 * np.pi) - np.pi)


def passes_in_time(direction: FloatArray, t: FloatArray | None) -> list[Any]:
    order = np.argsort(t, kind="stable") if t is not None else np.arange(len(direction))
    d = direction[order]
    cuts = np.flatnonzero(np.diff(d) != 0) + 1
    return [order[a:b] for a, b in zip(np.r_[0, cuts], np.r_[cuts, len(d)], strict=True)]


def cyclic_locking(
    problem: Problem,
    terms: Sequence[Term],
    index: int,
    beta: FloatArray,
    twin: Candidate | None,
) -> dict[str, Any]:
    """The figures of the module docstring for the cyclic ``terms[index]`` (``twin``: the same
    law in the other coordinate, when there is one)."""
    term = terms[index]
    k = cyclic_axis(term)
    assert k is not None
    res = problem.res
    y = partial_residual(problem, terms, beta, {index})[:, k]
    env = term.candidate.envelope
    theta = term.theta
    period = float(theta[1] if isinstance(theta, tuple) else theta)
    out: dict[str, Any] = {}
    d = res.signals.get(f"dir_{'xyz'[k]}")
    if d is not None and np.any(d > 0) and np.any(d < 0):
        e = res.residual_um[:, k]
        out["reversal_um"] = float(np.mean(e[d < 0]) - np.mean(e[d > 0]))
        coords = {term.candidate.locked_to: term.candidate}
        if twin is not None:
            coords[twin.locked_to] = twin
        for locked, cand in coords.items():
            x = cand.design_uncached(res, theta)[:, k, :]
            _, phi_p = _phase(x[d > 0], y[d > 0], cand.envelope)
            _, phi_m = _phase(x[d < 0], y[d < 0], cand.envelope)
            # the fitted term is A·cos(φ(c) − θ): moved by δ, θ grows by 2πδ/p
            shift = _wrap(phi_m - phi_p) / (2.0 * np.pi) * period * 1000.0
            out[f"shift_in_{locked}_coordinates_um"] = shift
        out["meaning"] = (
            "how far the cyclic error moved from the + to the − passes in each coordinate: "
            "locked to the reading, −reversal in position coordinates and 0 in the reading's; "
            "locked to the position, the opposite"
        )
    if d is not None:
        x = term.candidate.design_uncached(res, theta)[:, k, :]
        phases = []
        for rows in passes_in_time(d, res.data.t_s):
            if len(rows) >= MIN_PASS_POINTS:
                amp, phi = _phase(x[rows], y[rows], env)
                if amp > 0:
                    phases.append(phi)
        if len(phases) >= 2:
            out["passes"] = len(phases)
            out["pass_phase_coherence"] = float(np.abs(np.mean(np.exp(1j * np.array(phases)))))
    return out


def _phase_and_var(
    x: FloatArray, y: FloatArray, envelope: int, sigma: float
) -> tuple[float, float]:
    """(phase rad, its variance rad²) of the first harmonic at the centre of the travel."""
    a = np.column_stack([np.ones(len(y)), x])
    coef, *_ = np.linalg.lstsq(a, y, rcond=None)
    c = np.asarray(coef[1:], float)
    amp, phi = _first_harmonic(c, envelope, 0.0)
    if amp <= 0:
        return phi, float("inf")
    cov = _harmonic_cov(x, sigma, envelope, 0.0)
    pj = np.polynomial.legendre.legvander(np.array([0.0]), envelope)[0]
    qa, qb = float(pj @ c[0 : 2 * (envelope + 1) : 2]), float(pj @ c[1 : 2 * (envelope + 1) : 2])
    grad = np.array([-qb, qa]) / amp**2  # ∂φ/∂(a, b) of φ = atan2(b, a)
    return phi, float(grad @ cov @ grad)


def shift_noncentrality(
    problem: Problem,
    terms: Sequence[Term],
    index: int,
    beta: FloatArray,
    twin: Candidate,
    sigma_um: float,
) -> float:
    """How clearly the cyclic ``terms[index]`` shows the two coordinates apart between the
    directions of travel: z² = (r/σ_r)², r (µm) the difference between its shift from the + to
    the − passes in its own coordinate and in the ``twin``'s (the coordinates' own difference
    between the directions — the reversal — as the term's phase sees it, modulo its period), σ_r
    that shift's standard deviation from the fit's covariance (residual σ ``sigma_um``). 0 when
    the session does not have both directions: a position then has one reading."""
    term = terms[index]
    k = cyclic_axis(term)
    res = problem.res
    d = res.signals.get(f"dir_{'xyz'[k]}") if k is not None else None
    if k is None or d is None or not (np.any(d > 0) and np.any(d < 0)):
        return 0.0
    y = partial_residual(problem, terms, beta, {index})[:, k]
    theta = term.theta
    period_um = 1000.0 * float(theta[1] if isinstance(theta, tuple) else theta)
    moved, var = [], 0.0
    for cand in (term.candidate, twin):
        x = cand.design_uncached(res, theta)[:, k, :]
        phi_p, v_p = _phase_and_var(x[d > 0], y[d > 0], cand.envelope, sigma_um)
        phi_m, v_m = _phase_and_var(x[d < 0], y[d < 0], cand.envelope, sigma_um)
        moved.append(phi_m - phi_p)
        var = max(var, v_p + v_m)  # the two coordinates' phases share their noise: the larger
    if not np.isfinite(var) or var <= 0:
        return 0.0
    r = _wrap(moved[1] - moved[0]) / (2.0 * np.pi) * period_um
    sigma_r = float(np.sqrt(var)) / (2.0 * np.pi) * period_um
    return float((r / sigma_r) ** 2)
