"""Can a session tell a reference-locked ripple from a position-locked one? (issue 24)

A bidirectional session with a reversal r sees the carriage (and with it the reference's target)
at x = q + d·r/2 (q the axis' indicated position, d = ±1 the direction of its last motion). A
ripple locked to the reference is f(x): between directions it is shifted by r in axis
coordinates. A ripple locked to the axis is g(q): the same in both directions. The question is
not whether r is a large fraction of the period but whether the data can tell the two apart: the
expected Δχ² between the true model and the best fit of the other one — the noncentrality

    λ = Σ_i (s_i − ŝ_i)² / σ²,

s the noise-free true signal at the session's own sample points (both directions; the carriage
position x = q + d·r/2 with the drawn reversal r, signed), ŝ its
least-squares imitation by the other lock, σ the observation noise (µm). With Gaussian noise,
Δχ² = χ²(imitation) − χ²(truth) has mean λ and standard deviation ≈ 2√λ; λ ≥ 25 puts the mean
5 standard deviations of a single-noise-term (√λ = 5) away from zero, i.e. a twin that never fits
as well by chance.

The imitation ("what a position-locked machine error could physically be"): the same ripple law
in the other coordinate with free amplitude and phase, an amplitude linear along the travel, its
second harmonic with its own free amplitude/phase/slope (a screw pitch error or a scale's
interpolation error has exactly these degrees of freedom), plus a smooth table (cubic in
position), a constant offset and a free reversal step c·d (the reversal is fitted by every
diagnosis as a term of its own). The true signal lies exactly in the span of the same basis in its
own coordinate, so the true model's residual is zero and λ is the whole Δχ² noncentrality.

Not counted (conservative): a latency's own shift 2·v·τ between directions, which moves a
reference-locked ripple further; the correlated part of the reference noise is counted in σ as if
white (σ = the total of all noise parts).
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np
from numpy.typing import NDArray

FloatArray = NDArray[np.float64]
LAMBDA_MIN = 25.0
"""Threshold on λ: a twin worse by Δχ² = 25 on average (a 5σ separation, √λ = 5)."""


def lock_basis(
    coord_mm: FloatArray,
    direction: FloatArray,
    phase_of: Callable[[FloatArray], FloatArray],
    centre_mm: float,
    half_mm: float,
) -> FloatArray:
    """Columns of the ripple law locked to ``coord_mm`` (free amplitude, phase, slope, 2nd
    harmonic), a cubic table in ``coord_mm``, an offset and a reversal step in ``direction``."""
    c = np.asarray(coord_mm, dtype=float)
    u = (c - centre_mm) / max(half_mm, 1e-9)
    phi = phase_of(c)
    cols = [np.ones_like(c), np.asarray(direction, dtype=float), u, u**2, u**3]
    for k in (1, 2):
        for m in (np.ones_like(c), u):
            cols += [m * np.sin(k * phi), m * np.cos(k * phi)]
    return np.column_stack(cols)


def noncentrality(
    signal_um: FloatArray,
    imitation_basis: FloatArray,
    sigma_um: float,
) -> float:
    """λ = ‖signal − its least-squares projection on the imitation's columns‖² / σ²."""
    if sigma_um <= 0:
        raise ValueError(f"noise sigma must be > 0 µm, got {sigma_um}")
    s = np.asarray(signal_um, dtype=float)
    scale = np.linalg.norm(imitation_basis, axis=0)
    scale[scale == 0] = 1.0
    beta, *_ = np.linalg.lstsq(imitation_basis / scale, s, rcond=None)
    resid = s - (imitation_basis / scale) @ beta
    return float(resid @ resid / sigma_um**2)


#: Legendre order of the positional table a drift's imitation may use (the generator's own
#: positioning curves reach order 5).
DRIFT_TABLE_ORDER = 5


def drift_lambda(
    q_mm: FloatArray, direction: FloatArray, signal_um: FloatArray, sigma_um: float
) -> float:
    """λ of a drift's noise-free signal (µm at the session's rows) against its best imitation
    by errors that have no time: a positional table of the axis (Legendre, order
    :data:`DRIFT_TABLE_ORDER`, offset included) and a reversal constant or growing linearly along
    the travel (d, d·u; ISO 230-2's reversal, which wear or preload makes position-dependent).

    A session that visits each (position, direction) once in time — one back-and-forth cycle —
    cannot tell a drift from those: time is a function of position and direction there (a drift
    linear in time is exactly a linear table plus a growing reversal, λ = 0). Only a session
    that returns to the same places at other times shows the drift as a drift."""
    q = np.asarray(q_mm, dtype=float)
    d = np.asarray(direction, dtype=float)
    if q.size == 0:
        return 0.0
    lo, hi = float(np.min(q)), float(np.max(q))
    u = 2.0 * (q - lo) / (hi - lo) - 1.0 if hi > lo else np.zeros_like(q)
    basis = np.column_stack([np.polynomial.legendre.legvander(u, DRIFT_TABLE_ORDER), d, d * u])
    return noncentrality(np.asarray(signal_um, dtype=float), basis, sigma_um)


#: Legendre order in time of a uniform drift imitating a position-dependent one (a slow warm-up,
#: a wander: the reference drifts the generator draws are of this order).
DRIFT_TIME_ORDER = 3


def uniform_drift_lambda(
    q_mm: FloatArray,
    direction: FloatArray,
    t_s: FloatArray,
    signal_um: FloatArray,
    sigma_um: float,
    table: bool,
    reversal: bool,
) -> float:
    """λ of a position-dependent drift's noise-free signal (a thermal expansion about a point)
    against its best imitation by a drift the same at every position (Legendre in time, order
    :data:`DRIFT_TIME_ORDER`, offset included) — the reference's drift — together with what
    the session holds anyway: a positional table (``table``: a smooth curve of the axis or of the
    sensor is among its effects) and a reversal constant or growing (``reversal``). One cause is
    not imitated by two the session does not hold (the parsimony every diagnosis applies).

    In a one-directional scan at one speed, time is a linear function of position within each
    pass, so ΔT(t)·(q − q_f) with ΔT linear in t is exactly a uniform drift quadratic in t plus
    a quadratic table: with a table in the session, nothing tells the machine's expansion from
    the sensor's drift."""
    q = np.asarray(q_mm, dtype=float)
    t = np.asarray(t_s, dtype=float)
    d = np.asarray(direction, dtype=float)
    if q.size == 0:
        return 0.0

    def unit(v: FloatArray) -> FloatArray:
        lo, hi = float(np.min(v)), float(np.max(v))
        return 2.0 * (v - lo) / (hi - lo) - 1.0 if hi > lo else np.zeros_like(v)

    u = unit(q)
    cols = [np.polynomial.legendre.legvander(unit(t), DRIFT_TIME_ORDER)]
    if table:
        cols.append(np.polynomial.legendre.legvander(u, DRIFT_TABLE_ORDER)[:, 1:])
    if reversal:
        cols.append(np.column_stack([d, d * u]))
    return noncentrality(np.asarray(signal_um, dtype=float), np.column_stack(cols), sigma_um)


def lock_lambda(
    q_mm: FloatArray,
    carriage_mm: FloatArray,
    direction: FloatArray,
    sigma_um: float,
    signal_of: Callable[[FloatArray], FloatArray],
    phase_of: Callable[[FloatArray], FloatArray],
    locked: str,
) -> float:
    """λ for a ripple ``signal_of`` (µm, of a position in mm) locked to ``locked``
    (``reference``: the carriage position x, where the reference's target is; ``machine``: the
    axis' own position q), imitated by the other lock, at the session's sample points (q, x, d)
    with noise σ (µm).For a pure reversal r, x = q + d·r/2000."""
    q = np.asarray(q_mm, dtype=float)
    x = np.asarray(carriage_mm, dtype=float)
    d = np.asarray(direction, dtype=float)
    if q.size == 0:
        return 0.0
    own, other = (x, q) if locked == "reference" else (q, x)
    centre = 0.5 * (float(np.min(other)) + float(np.max(other)))
    half = 0.5 * (float(np.max(other)) - float(np.min(other)))
    basis = lock_basis(other, d, phase_of, centre, half)
    return noncentrality(signal_of(own), basis, sigma_um)
