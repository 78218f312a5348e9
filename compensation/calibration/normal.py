"""The normal matrix of the calibration's least squares (:mod:`.solver`), factorised with the
local nuisance parameters eliminated by a Schur complement.

``H = [[A, B], [Bᵀ, D]]``: ``A`` over the kept parameters (θ, poses, stations, dead paths),
``D`` over the *local* ones — a multilateration point's 3 offsets, each seen only by that
point's lengths — so ``D`` is block diagonal (3 × 3 per point) and its inverse is cheap. The
step and the posterior come from the Schur complement ``S = A − B·D⁻¹·Bᵀ`` (the size of the
kept parameters) instead of a factor of the whole ``H``:

    x_K = S⁻¹ (g_K − B D⁻¹ g_E),   x_E = D⁻¹ (g_E − Bᵀ x_K)
    C_KK = S⁻¹,  C_KE = −S⁻¹ B D⁻¹,  C_EE = D⁻¹ + D⁻¹ Bᵀ S⁻¹ B D⁻¹

The fixed-point updates need ``tr(H⁻¹·JᵀJ)`` per variance group and the diagonal of ``H⁻¹``:
the inverse is assembled from these blocks once per factor (:meth:`Normal.inverse`). The same
algebra as factorising ``H`` (exact, not an approximation); ``H`` is scaled to a unit
diagonal (Jacobi) before either factor, so solves stay accurate across the parameters' scales.
"""

from __future__ import annotations

from typing import TYPE_CHECKING, Any

import numpy as np
from numpy.typing import NDArray
from scipy.linalg import blas, cho_factor, cho_solve, lapack

from ..errors import CalibrationError

if TYPE_CHECKING:
    from .solver import Problem

__all__ = ["GAUGE_PRECISION", "Normal"]

FloatArray = NDArray[np.float64]
GAUGE_PRECISION = 1e8  # 1/µrad²: the rigid rotations no data see are pinned at zero in θ
LOCAL = 3  # parameters per local (eliminated) group: a point's offsets


def _singular() -> CalibrationError:
    return CalibrationError(
        "the calibration problem is singular even with its prior: a data set's "
        "nuisance (a plate pose, a station) is not determined by its readings"
    )


def _potri(chol: tuple[FloatArray, bool]) -> FloatArray:
    """The inverse of a Cholesky-factorised matrix (LAPACK potri: a third of a solve's work)."""
    factor, lower = chol
    inv, info = lapack.dpotri(factor, lower=lower)
    if info != 0:  # pragma: no cover - the factor exists, so its inverse does
        raise CalibrationError(f"inverting the normal matrix failed (LAPACK info {info})")
    return np.tril(inv) + np.tril(inv, -1).T if lower else np.triu(inv) + np.triu(inv, 1).T


class Normal:
    """H and the gradient at a linearisation point (``stats`` per group (JᵀJ, Jᵀr, rᵀr)),
    factorised; ``problem.local`` (global indices, in triples) are eliminated."""

    def __init__(
        self,
        problem: Problem,
        stats: list[tuple[FloatArray, FloatArray, float]],
        x_abs: FloatArray,
        lam: dict[str, float],
        damping: float = 0.0,
        *,
        pinned: bool = True,
    ) -> None:
        prec = problem.precision(lam)
        pins = problem.pins if pinned else problem.gauge
        h = GAUGE_PRECISION * pins.T @ pins
        h[np.diag_indices_from(h)] += prec
        grad = prec * x_abs + GAUGE_PRECISION * pins.T @ (pins @ x_abs)
        flat = h.reshape(-1)
        for g, (a, b, _) in zip(problem.groups, stats, strict=True):
            blas.daxpy(a.reshape(-1), flat, a=1.0 / g.sigma**2)  # in place: h += a/σ²
            grad += b / g.sigma**2
        if damping:
            h[np.diag_indices_from(h)] *= 1.0 + damping
        self.n = h.shape[0]
        self.grad = grad
        self.kept: NDArray[np.intp] = problem.kept
        self.local: NDArray[np.intp] = problem.local
        self.m = self.local.size // LOCAL
        kk = h[np.ix_(self.kept, self.kept)]
        if self.m:
            d = h[np.ix_(self.local, self.local)].reshape(self.m, LOCAL, self.m, LOCAL)
            blocks = d[np.arange(self.m), :, np.arange(self.m), :]  # (m, 3, 3)
            try:
                self.d_inv = np.linalg.inv(blocks)
            except np.linalg.LinAlgError:
                raise _singular() from None
            b = h[np.ix_(self.kept, self.local)].reshape(-1, self.m, LOCAL)
            self.bd = np.einsum("kia,iab->kib", b, self.d_inv).reshape(len(self.kept), -1)
            kk = kk - self.bd @ b.reshape(len(self.kept), -1).T
        self.scale = 1.0 / np.sqrt(np.diag(kk))
        try:
            self.chol = cho_factor(kk * np.outer(self.scale, self.scale), lower=False)
        except np.linalg.LinAlgError:
            raise _singular() from None
        self._ckk: FloatArray | None = None
        self._full: FloatArray | None = None

    def _solve_kept(self, rhs: FloatArray) -> FloatArray:
        return self.scale * np.asarray(cho_solve(self.chol, self.scale * rhs))

    def step(self) -> FloatArray:
        """The Gauss–Newton step −H⁻¹·g (all parameters)."""
        out = np.empty(self.n)
        g_k = self.grad[self.kept]
        if not self.m:
            out[self.kept] = -self._solve_kept(g_k)
            return out
        g_e = self.grad[self.local]
        x_k = self._solve_kept(g_k - self.bd @ g_e)
        b_x = (self.bd.T @ x_k).reshape(self.m, LOCAL)  # D⁻¹Bᵀx_K
        x_e = np.einsum("iab,ib->ia", self.d_inv, g_e.reshape(self.m, LOCAL)) - b_x
        out[self.kept] = -x_k
        out[self.local] = -x_e.reshape(-1)
        return out

    def kept_inverse(self) -> FloatArray:
        """C_KK, the covariance of the kept parameters (θ first: ``[:p, :p]`` is θ's)."""
        if self._ckk is None:
            self._ckk = _potri(self.chol) * np.outer(self.scale, self.scale)
        return self._ckk

    def diagonal(self) -> FloatArray:
        """The diagonal of H⁻¹ (all parameters)."""
        return np.diag(self.inverse()).copy()

    def trace(self, a: FloatArray) -> float:
        """tr(H⁻¹·a) for a symmetric (n, n) ``a`` (a group's JᵀJ): one dense dot product."""
        return float(np.vdot(self.inverse(), a))

    def inverse(self) -> FloatArray:
        """H⁻¹, every parameter (assembled from the blocks once, then kept)."""
        if self._full is not None:
            return self._full
        out = np.empty((self.n, self.n))
        out[np.ix_(self.kept, self.kept)] = self.kept_inverse()
        if self.m:
            q = self.kept_inverse() @ self.bd  # S⁻¹·B·D⁻¹ = −C_KE
            out[np.ix_(self.kept, self.local)] = -q
            out[np.ix_(self.local, self.kept)] = -q.T
            d = np.zeros((self.m, LOCAL, self.m, LOCAL))
            idx = np.arange(self.m)
            d[idx, :, idx, :] = self.d_inv
            out[np.ix_(self.local, self.local)] = d.reshape(self.local.size, -1) + self.bd.T @ q
        self._full = out
        return out


def local_structure(problem: Any) -> tuple[NDArray[np.intp], NDArray[np.intp]]:
    """(kept, local) global indices of ``problem``: local = its blocks' :meth:`local_nuisance`
    (triples of parameters each seen by its own rows only), kept = the rest in order."""
    local = [
        problem.offsets[bi] + np.asarray(b.local_nuisance(), dtype=np.intp)
        for bi, b in enumerate(problem.blocks)
    ]
    loc = np.concatenate(local) if local else np.zeros(0, dtype=np.intp)
    if loc.size % LOCAL:
        raise ValueError(f"local nuisance parameters come in groups of {LOCAL}")
    kept = np.setdiff1d(np.arange(problem.n), loc)
    return kept, loc.astype(np.intp)
