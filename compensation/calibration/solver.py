"""The least-squares solution: Levenberg–Marquardt / Gauss–Newton over the machine's parameters θ
and every block's nuisance parameters (plate poses, ball corrections, station positions, dead
paths), with a Gaussian prior, the variance of each group of readings and the smoothness of
each class of error function estimated from the data.

Objective (residuals µm or µrad, ``W = 1/σ_g`` per variance group g)::

    Σ_g ‖r_g‖² / σ_g²  +  θᵀ (ε·I + Σ_c λ_c·K_c) θ  +  Σ balls c² / u²

ε = 1/prior² is a weak prior on every value (it fixes what no data sees, at zero, and says so
through the posterior's uncertainty); ``K_c`` the roughness ``L³·∫f''²`` of the class-c
functions (:meth:`.basis.FunctionBasis.curvature`) — a smoothing spline's prior.

Internally each function's values are rotated into the eigenbasis of its roughness (the
mixed-model form of a smoothing spline: straight lines, which have no roughness, and scaled
shapes with unit roughness), so the prior is diagonal and the normal matrix, scaled to a unit
diagonal, stays well conditioned even where the data see nothing. σ_g and λ_c are estimated by
the fixed-point (MacKay / variance-component) updates::

    σ_g² ← ‖r_g‖² / (n_g − removed_g − tr(H⁻¹·J_gᵀJ_g)/σ_g²)
    λ_c  ← (rank K_c − λ_c·tr(H⁻¹ over the class' shapes)) / (θᵀ K_c θ)

Residuals are exact (the project's chain), the Jacobian first order in the errors
(:mod:`.model`), exact in the nuisance parameters.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import numpy as np
from numpy.typing import NDArray

from .model import MachineModel
from .normal import GAUGE_PRECISION, Normal, local_structure
from .observation import Block

__all__ = [
    "EffectGroup",
    "GroupFit",
    "Problem",
    "Solution",
    "solve",
]

FloatArray = NDArray[np.float64]
LAMBDA_RANGE = (1e-8, 1e6)  # τ = 1e4 … 1e-3 µm (µrad): beyond, the data have nothing to add
INITIAL_TAU = 1e4  # µm or µrad: start rough, the data first (the smoothness then grows to fit)
STEP_TOL = 1e-6  # µm, µrad (scaled): a step this small ends the iteration
FLAT_PRECISION = 1e-12  # a "flat" nuisance prior (poses, stations): keeps H positive definite
NULL_RATIO = 1e-3  # a direction whose data information is below 1e-3 of the weak prior's: unseen
PENALTY_ORDER = 3  # the third derivative is penalised: a parabola is free (docs §3)
HYPER_ITERATIONS = 30  # fixed-point updates of σ and λ per linearisation
HYPER_TOL = 3e-3  # relative σ change, γ change (dof): below this σ and λ have settled
HYPER_DOF = 1.0  # degrees of freedom of the smoothness hyperprior of each class
HYPER_TAU_PER_AMPLITUDE = 6.0  # τ0 = this × the class' RMS value: a cubic of that amplitude
HYPER_TAU0_MIN = 0.1  # µm or µrad: the smallest τ0
CLASS_WEIGHT = 1.0  # degrees of freedom of the class' smoothness in each function's estimate
COST_NOISE = 1e-4  # χ²: below this a cost change is numerical noise
STRAIGHTNESS_SLOPE_WEIGHT = 1e2  # the weak prior on a straightness slope: 10× tighter
EFFECT_SIGMA_MIN = 1e-3  # µm: the smallest σ of a random effect (per-point offsets)
DECREASE_TOL = 1e-6  # χ² (plus 1e-9 of the cost): a step promising less ends the iteration


@dataclass
class GroupFit:
    """One variance group: rows ``n``, degrees of freedom taken by removed constants/lines,
    a-priori and estimated σ (``estimated`` False when the group has too little redundancy)."""

    block: int
    local: int
    n: int
    removed: float
    sigma0: float
    sigma: float
    redundancy: float = 0.0
    estimated: bool = False


@dataclass
class EffectGroup:
    """Random-effect nuisance parameters (global indices ``index``) sharing a prior N(0, σ²),
    σ estimated like a variance group (``estimated`` False while too few are seen)."""

    block: int
    name: str
    index: NDArray[np.intp]
    sigma0: float
    sigma: float
    used: float = 0.0
    estimated: bool = False


@dataclass
class Solution:
    """The fit: θ, the blocks' nuisance states, the groups' σ, the classes' λ, the posterior
    covariance of θ and of each block's nuisance, residuals per block and how it went."""

    theta: FloatArray
    theta_internal: FloatArray
    states: list[Any]
    groups: list[GroupFit]
    lam: dict[str, float]
    covariance_theta: FloatArray
    covariance_theta_pinned: FloatArray
    covariance_nuisance: list[FloatArray]
    residuals: list[FloatArray]
    iterations: int
    converged: bool
    history: list[dict[str, float]] = field(default_factory=list)
    stats: list[Any] = field(default_factory=list)  # per group (JᵀJ, Jᵀr, rᵀr) at the solution
    #: each block's residuals with θ = 0 and only the nuisance fitted (the solver's first stage):
    #: what the data show before any error is identified (the report's "before")
    before: list[FloatArray] = field(default_factory=list)


class Problem:
    """The stacked least-squares problem of a model and its observation blocks."""

    def __init__(
        self, model: MachineModel, blocks: list[Block], *, prior_sd: float, smoothness: float | None
    ) -> None:
        self.model = model
        self.blocks = blocks
        self.p = model.layout.n
        offsets = [self.p]
        for b in blocks:
            offsets.append(offsets[-1] + b.n_nuisance)
        self.offsets = offsets
        self.n = offsets[-1]
        self.ridge = 1.0 / prior_sd**2
        self.fixed_smoothness = smoothness
        self._transform(model)
        self.base_precision = np.concatenate(
            [self.ridge_internal]
            + [np.maximum(b.nuisance_precision(), FLAT_PRECISION) for b in blocks]
        )
        self.groups: list[GroupFit] = []
        self.group_index: list[NDArray[np.intp]] = []  # per block: global group of each row
        for bi, b in enumerate(blocks):
            removed_dof = getattr(b, "removed_dof", None)
            removed = removed_dof() if removed_dof else np.zeros(len(b.variance_groups))
            base = len(self.groups)
            for li, vg in enumerate(b.variance_groups):
                n = int(np.sum(b.groups == li))
                self.groups.append(GroupFit(bi, li, n, float(removed[li]), vg.sigma0, vg.sigma0))
            self.group_index.append(base + b.groups)
        self.support = [np.zeros(0, dtype=np.intp) for _ in self.groups]  # JᵀJ's columns
        # the local nuisance (a point's offsets) is eliminated from the normal matrix (.normal)
        self.kept, self.local = local_structure(self)
        self.effects = [
            EffectGroup(bi, name, self.offsets[bi] + idx, sigma0, sigma0)
            for bi, b in enumerate(blocks)
            for idx, name, sigma0 in b.random_effects()
        ]

    def _transform(self, model: MachineModel) -> None:
        """θ = T·θ_int per function: [straight lines | shapes scaled to unit roughness]."""
        self.t_blocks: list[tuple[slice, FloatArray]] = []
        self.ridge_internal = np.full(self.p, self.ridge)
        self.shape_class: list[str | None] = [None] * self.p  # the function of each shape
        self.rank: dict[str, int] = {}
        self.kind_of: dict[str, str] = {}
        for fn in model.layout.functions:
            k = fn.curvature(PENALTY_ORDER)
            if not np.any(k):
                if fn.kind == "straightness" and fn.basis == "polynomial":
                    # a slope no data see goes to the squareness, not the straightness (the
                    # laser's convention: a straightness has its line removed)
                    self.ridge_internal[fn.start] *= STRAIGHTNESS_SLOPE_WEIGHT  # P1
                continue
            w, u = np.linalg.eigh(k)
            shape = w > 1e-9 * w.max()
            free = _slope_first(fn, u[:, ~shape])  # the functions without roughness
            t = np.hstack([free, u[:, shape] / np.sqrt(w[shape])])
            self.t_blocks.append((fn.cols, t))
            n_line = free.shape[1]
            ridge = np.concatenate([np.full(n_line, self.ridge), self.ridge / w[shape]])
            if fn.kind == "straightness":  # as above: the unseen slope goes to the squareness
                ridge[0] *= STRAIGHTNESS_SLOPE_WEIGHT
            self.ridge_internal[fn.cols] = ridge
            for j in range(fn.start + n_line, fn.start + fn.size):
                self.shape_class[j] = fn.name
            self.rank[fn.name] = int(np.sum(shape))
            self.kind_of[fn.name] = fn.kind
        self.classes = tuple(self.rank)
        self.shape_index = {
            f: np.array([j for j, c in enumerate(self.shape_class) if c == f], dtype=np.intp)
            for f in self.classes
        }
        self.gamma: dict[str, float] = {}  # degrees of freedom each class uses (last update)
        self.null = np.zeros((self.p, 0))
        self.null_ratio = np.zeros(0)
        self._gauge(model)
        self.pins = self.gauge  # gauge + the null directions while iterating

    def free_information(
        self,
        stats: list[tuple[FloatArray, FloatArray, float]],
        lam: dict[str, float],
        blocks: set[int] | None = None,
    ) -> tuple[NDArray[np.intp], FloatArray]:
        """The data's information (of ``blocks``, default all) about the roughness-free
        coordinates of θ — each function's constant, slope (and parabola), the squareness —
        with every shape (its smoothness prior at ``lam``) and every nuisance parameter
        marginalised, whitened by the weak prior: (indices into θ, (F, F) matrix). Its
        eigenvalues are data/weak-prior information ratios."""
        info = np.zeros((self.n, self.n))
        for g, (a, _, _) in zip(self.groups, stats, strict=True):
            if blocks is None or g.block in blocks:
                info += a / g.sigma**2
        free = np.array([j for j in range(self.p) if self.shape_class[j] is None], dtype=np.intp)
        rest = np.setdiff1d(np.arange(self.n), free)
        prec = self.precision(lam)
        prec[self.p :] = np.maximum(prec[self.p :], FLAT_PRECISION)
        schur = info[np.ix_(free, free)]
        if rest.size:
            nu = info[np.ix_(rest, rest)] + np.diag(prec[rest])
            cross = info[np.ix_(free, rest)]
            schur = schur - cross @ np.linalg.solve(nu, cross.T)
        root = np.sqrt(self.ridge_internal[free])
        return free, schur / np.outer(root, root)

    def find_null_space(
        self, stats: list[tuple[FloatArray, FloatArray, float]], lam: dict[str, float]
    ) -> None:
        """The roughness-free θ directions (:meth:`free_information`) the data add less than
        :data:`NULL_RATIO` of the weak prior's information to: ``null`` (P, k) in the weak
        prior's whitened metric, orthonormal. They are pinned at the prior's zero while
        iterating (:attr:`pins`): a second-order term of the exact model must not push θ along
        a direction no reading constrains. The final covariance keeps their prior variance."""
        free, info = self.free_information(stats, lam)
        w, v = np.linalg.eigh(info)
        self.null = np.zeros((self.p, int(np.sum(w < NULL_RATIO))))
        self.null[free] = v[:, w < NULL_RATIO]
        self.null_ratio = w
        root = np.sqrt(self.ridge_internal)
        pins = np.zeros((self.null.shape[1], self.n))
        pins[:, : self.p] = (self.null * root[:, None]).T  # a·x = the null coordinate (whitened)
        self.pins = np.vstack([self.gauge, pins])

    def _gauge(self, model: MachineModel) -> None:
        """Pin the rigid rotations no data see (an inner constraint in the prior's metric):
        ``gauge`` (3, n) rows a_k with a_k·x the rotation θ carries (µrad), penalised by
        ``GAUGE_PRECISION``. Without it the step would wander along them, driven by
        second-order terms of the first-order Jacobian."""
        from .rigid import rotation_directions

        self.rotations, self.rotation_misfit = rotation_directions(model)
        self.gauge = np.zeros((0, self.n))
        if self.p == 0 or self.rotation_misfit > 1e-6:
            return
        r_int = self.rotations.copy()
        for cols, t in self.t_blocks:
            r_int[cols] = np.linalg.solve(t, self.rotations[cols])
        m = self.ridge_internal[:, None] * r_int
        a = m / np.sum(r_int * m, axis=0)
        self.gauge = np.zeros((3, self.n))
        self.gauge[:, : self.p] = a.T

    # ---------------------------------------------------------------- coordinates
    def theta(self, theta_int: FloatArray) -> FloatArray:
        """θ (node values, coefficients, squareness) from the internal coordinates."""
        out = theta_int.copy()
        for cols, t in self.t_blocks:
            out[cols] = t @ theta_int[cols]
        return out

    def to_theta_jacobian(self, jac: FloatArray) -> FloatArray:
        """A Jacobian with respect to θ turned into one with respect to θ_int (columns)."""
        out = jac.copy()
        for cols, t in self.t_blocks:
            out[:, cols] = jac[:, cols] @ t
        return out

    def theta_covariance(self, cov_int: FloatArray) -> FloatArray:
        """Cov(θ) from the covariance of θ_int (P × P)."""
        tm = np.eye(self.p)
        for cols, t in self.t_blocks:
            tm[cols, cols] = t
        return tm @ cov_int @ tm.T

    # ---------------------------------------------------------------- pieces
    def precision(self, lam: dict[str, float]) -> FloatArray:
        """(n,) the prior's diagonal precision in internal coordinates."""
        out = self.base_precision.copy()
        for f, idx in self.shape_index.items():
            out[idx] += lam[f]
        for e in self.effects:
            out[e.index] = 1.0 / e.sigma**2
        return out

    def absolute(self, theta_int: FloatArray, states: list[Any]) -> FloatArray:
        """The parameters the prior acts on: θ_int and the plates' ball corrections
        (absolute); zero for the flat nuisance (poses, stations: their steps only)."""
        x = np.zeros(self.n)
        x[: self.p] = theta_int
        for bi, (b, st) in enumerate(zip(self.blocks, states, strict=True)):
            if isinstance(st, np.ndarray):  # a block whose whole state has a prior (scales)
                x[self.offsets[bi] : self.offsets[bi + 1]] = st
                continue
            ball = getattr(st, "ball_um", getattr(st, "point_um", None))
            if ball is not None:
                start = self.offsets[bi] + b.n_nuisance - ball.size
                x[start : self.offsets[bi + 1]] = ball.reshape(-1)
        return x

    def linearize(
        self, theta_int: FloatArray, states: list[Any]
    ) -> tuple[list[FloatArray], list[FloatArray]]:
        """Residuals and full-width Jacobians (rows × all internal parameters) per block."""
        theta = self.theta(theta_int)
        res, jac = [], []
        for bi, (b, st) in enumerate(zip(self.blocks, states, strict=True)):
            lin = b.linearize(self.model, theta, st)
            full = np.zeros((lin.residual.shape[0], self.n))
            full[:, : self.p] = self.to_theta_jacobian(lin.jac_machine)
            full[:, self.offsets[bi] : self.offsets[bi + 1]] = lin.jac_nuisance
            res.append(lin.residual)
            jac.append(full)
        return res, jac

    def group_stats(
        self, res: list[FloatArray], jac: list[FloatArray]
    ) -> list[tuple[FloatArray, FloatArray, float]]:
        """Per group (JᵀJ, Jᵀr, rᵀr). JᵀJ is formed over the columns the group's rows touch
        (:attr:`support`, the union over every call: a laser run sees no pose or station)."""
        out = []
        for gi, g in enumerate(self.groups):
            rows = self.group_index[g.block] == gi
            j, r = jac[g.block][rows], res[g.block][rows]
            sup = np.union1d(self.support[gi], np.flatnonzero(np.any(j != 0.0, axis=0)))
            self.support[gi] = sup
            a = np.zeros((self.n, self.n))
            js = j[:, sup]
            a[np.ix_(sup, sup)] = js.T @ js
            out.append((a, j.T @ r, float(r @ r)))
        return out

    def cost(self, res: list[FloatArray], x_abs: FloatArray, lam: dict[str, float]) -> float:
        total = 0.0
        for gi, g in enumerate(self.groups):
            r = res[g.block][self.group_index[g.block] == gi]
            total += float(r @ r) / g.sigma**2
        pinned = float(np.sum((self.gauge @ x_abs) ** 2)) * GAUGE_PRECISION
        return total + float(np.sum(self.precision(lam) * x_abs**2)) + pinned

    def advance(
        self, theta_int: FloatArray, states: list[Any], delta: FloatArray
    ) -> tuple[FloatArray, list[Any]]:
        new_states = [
            b.advance(st, delta[self.offsets[bi] : self.offsets[bi + 1]])
            for bi, (b, st) in enumerate(zip(self.blocks, states, strict=True))
        ]
        return theta_int + delta[: self.p], new_states


def _slope_first(fn: Any, free: FloatArray) -> FloatArray:
    """An orthonormal basis of the roughness-free functions of ``fn`` (columns, parameter
    space) whose first column is the straight line through the reference (the slope)."""
    if fn.nodes_mm is None or free.shape[1] == 0:
        return free
    line = (fn.nodes_mm - fn.lo_mm) / (fn.hi_mm - fn.lo_mm)
    if fn.fixed_reference:
        line = line[1:]
    slope = free @ (free.T @ line)  # the line, within the free functions
    if np.linalg.norm(slope) < 1e-9:
        return free
    q, _ = np.linalg.qr(np.column_stack([slope, free]))
    return q[:, : free.shape[1]]


def _class_scale(problem: Problem, theta_int: FloatArray) -> dict[str, float]:
    """Per class of smoothed function, the hyperprior's roughness scale τ0 (µm, µrad):
    :data:`HYPER_TAU_PER_AMPLITUDE` × the RMS of the class' identified values at their nodes
    (a cubic of amplitude A has roughness 6·A, :meth:`.basis.FunctionBasis.curvature`)."""
    theta = problem.theta(theta_int)
    sums: dict[str, list[float]] = {}
    for fn in problem.model.layout.functions:
        if fn.name in problem.kind_of:
            sums.setdefault(fn.kind, []).append(float(np.mean(theta[fn.cols] ** 2)))
    return {
        k: max(HYPER_TAU_PER_AMPLITUDE * float(np.sqrt(np.mean(v))), HYPER_TAU0_MIN)
        for k, v in sums.items()
    }


def _lm(
    problem: Problem,
    theta: FloatArray,
    states: list[Any],
    lam: dict[str, float],
    max_iter: int,
    frozen: NDArray[np.bool_] | None = None,
) -> tuple[FloatArray, list[Any], int, bool]:
    """Levenberg–Marquardt with fixed σ and λ; ``frozen`` (n,) True for parameters held."""
    res, jac = problem.linearize(theta, states)
    x_abs = problem.absolute(theta, states)
    cost = problem.cost(res, x_abs, lam)
    mu = 0.0
    for it in range(1, max_iter + 1):
        if frozen is not None:
            jac = [j * ~frozen for j in jac]
        stats = problem.group_stats(res, jac)
        while True:
            normal = Normal(problem, stats, x_abs * (1 if frozen is None else ~frozen), lam, mu)
            delta = normal.step()
            t_new, s_new = problem.advance(theta, states, delta)
            res_new, jac_new = problem.linearize(t_new, s_new)
            x_new = problem.absolute(t_new, s_new)
            cost_new = problem.cost(res_new, x_new, lam)
            # χ² changes below ~1e-4 are rounding and second-order noise, not a worse fit
            if cost_new <= cost * (1 + 1e-9) + COST_NOISE or mu > 1e8:
                break
            mu = max(mu * 10.0, 1e-4)
        theta, states, res, jac, x_abs, cost = t_new, s_new, res_new, jac_new, x_new, cost_new
        mu = mu / 10.0 if mu > 1e-6 else 0.0
        promised = -float(normal.grad @ delta)  # the decrease of χ² the step aimed at
        small = float(np.max(np.abs(delta), initial=0.0)) < STEP_TOL
        if small or promised < DECREASE_TOL + 1e-9 * cost:
            return theta, states, it, True
    return theta, states, max_iter, False


def _hyper_step(
    problem: Problem,
    stats: list[tuple[FloatArray, FloatArray, float]],
    x_abs: FloatArray,
    lam: dict[str, float],
    estimate_lambda: bool,
) -> tuple[dict[str, float], float, FloatArray]:
    """One fixed-point update of σ_g and λ_c on the linearised problem; returns the new λ,
    the largest relative change and the step δ."""
    # one linear problem: its solution has no cause to wander along unseen directions (that is
    # the re-linearisation's doing), so the real posterior gives both the step and the traces
    normal = Normal(problem, stats, x_abs, lam, pinned=False)
    delta = normal.step()
    diag = normal.diagonal()
    change = 0.0
    for g, (a, b, c) in zip(problem.groups, stats, strict=True):
        rss = c + 2.0 * float(b @ delta) + float(delta @ a @ delta)
        used = normal.trace(a) / g.sigma**2
        g.redundancy = g.n - g.removed - used
        if g.redundancy >= 2.0 and rss > 0:
            new = float(np.sqrt(rss / g.redundancy))
            change = max(change, abs(new / g.sigma - 1.0))
            g.sigma = new
            g.estimated = True
    for e in problem.effects:
        # σ of a random effect: the MacKay update, like a variance group's (γ = the effects
        # the data determine); floored, so a vanishing effect stays a (tight) prior
        effect = x_abs[e.index] + delta[e.index]
        e.used = e.index.size - float(np.sum(diag[e.index])) / e.sigma**2
        if e.used >= 1.0:
            new = max(float(np.sqrt(float(effect @ effect) / e.used)), EFFECT_SIGMA_MIN)
            change = max(change, abs(new / e.sigma - 1.0))
            e.sigma = new
            e.estimated = True
    new_lam = dict(lam)
    if estimate_lambda:
        theta = x_abs[: problem.p] + delta[: problem.p]
        gamma, rough = {}, {}
        for f in problem.classes:
            idx = problem.shape_index[f]
            gamma[f] = problem.rank[f] - lam[f] * float(np.sum(diag[idx]))
            rough[f] = float(np.sum(theta[idx] ** 2))
        pooled: dict[str, tuple[float, float]] = {}
        for f, kind in problem.kind_of.items():
            g0, r0 = pooled.get(kind, (0.0, 0.0))
            pooled[kind] = (g0 + gamma[f], r0 + rough[f])
        tau0 = _class_scale(problem, theta)
        for f in problem.classes:
            # each function its own smoothness, shrunk towards its class' (the pooled estimate
            # of e.g. all angular errors) by CLASS_WEIGHT degrees of freedom: where the data
            # say little about one function, its class speaks for it (smoothly: no switching)
            gc, rc = pooled[problem.kind_of[f]]
            # the class' own hyperprior (a Gamma of HYPER_DOF degrees of freedom at τ0, the
            # roughness the class' identified amplitude could carry): where the data hardly
            # see a class' shapes, their roughness falls back towards what the seen part of the
            # errors suggests, instead of collapsing to zero ("no curvature at all")
            t0 = tau0[problem.kind_of[f]]
            lam_class = (gc + HYPER_DOF) / (rc + HYPER_DOF * t0**2)
            g_f = gamma[f] + CLASS_WEIGHT
            r_f = rough[f] + CLASS_WEIGHT / lam_class
            value = g_f / r_f if r_f > 0 and g_f > 0 else LAMBDA_RANGE[1]
            value = float(np.clip(value, *LAMBDA_RANGE))
            # converged when the shapes the data use (γ, a number of degrees of freedom) no
            # longer change: λ may still creep towards "straight" where that changes nothing
            previous = problem.gamma.get(f)
            problem.gamma[f] = gamma[f]
            if previous is None:
                change = max(change, 1.0)
            else:
                change = max(change, abs(gamma[f] - previous) / max(1.0, problem.rank[f] * 0.01))
            new_lam[f] = value
    return new_lam, change, delta


def solve(problem: Problem, *, max_iter: int = 60, progress: Any = None) -> Solution:
    """Fit θ and the nuisance parameters, estimating σ_g and (unless fixed) λ_c."""
    theta = np.zeros(problem.p)
    states = [b.initial_state(problem.model, theta) for b in problem.blocks]
    tau = problem.fixed_smoothness if problem.fixed_smoothness is not None else INITIAL_TAU
    lam = {c: 1.0 / tau**2 for c in problem.classes}
    estimate = problem.fixed_smoothness is None
    total_it, converged = 0, False
    history: list[dict[str, float]] = []
    if problem.n > problem.p:  # the poses and stations first: a start near the solution
        frozen = np.zeros(problem.n, dtype=bool)
        frozen[: problem.p] = True
        theta, states, total_it, _ = _lm(problem, theta, states, lam, max_iter, frozen)
    res, jac = problem.linearize(theta, states)
    before = [r.copy() for r in res]  # θ is still zero: the nuisance alone fitted
    problem.find_null_space(problem.group_stats(res, jac), lam)
    for rnd in range(12):
        theta, states, it, ok = _lm(problem, theta, states, lam, max_iter)
        total_it += it
        res, jac = problem.linearize(theta, states)
        x_abs = problem.absolute(theta, states)
        stats = problem.group_stats(res, jac)
        total = 0.0  # what σ and λ moved in this round (they change the fit: refit if so)
        for _ in range(HYPER_ITERATIONS):
            lam, change, _ = _hyper_step(problem, stats, x_abs, lam, estimate)
            total += change
            if change < HYPER_TOL:
                break
        history.append({"round": rnd + 1, "lm_iterations": it, "hyper_change": total})
        if progress is not None:
            progress(f"fit round {rnd + 1}: {it} step(s), σ/λ change {total:.1e}")
        if ok and total < 10 * HYPER_TOL and it <= 3 and rnd > 0:
            converged = True
            break
    res, jac = problem.linearize(theta, states)
    stats = problem.group_stats(res, jac)
    x_abs = problem.absolute(theta, states)
    cov = Normal(problem, stats, x_abs, lam, pinned=False).inverse()
    pinned = Normal(problem, stats, x_abs, lam).kept_inverse()[: problem.p, : problem.p]
    return Solution(
        theta=problem.theta(theta),
        theta_internal=theta,
        states=states,
        groups=problem.groups,
        lam=lam,
        covariance_theta=problem.theta_covariance(cov[: problem.p, : problem.p]),
        covariance_theta_pinned=problem.theta_covariance(pinned),
        covariance_nuisance=[
            cov[
                problem.offsets[i] : problem.offsets[i + 1],
                problem.offsets[i] : problem.offsets[i + 1],
            ]
            for i in range(len(problem.blocks))
        ],
        residuals=res,
        iterations=total_it,
        converged=converged,
        history=history,
        stats=stats,
        before=before,
    )
