"""U at the nodes of a correction grid: the covariance of the residual error pose from the
virtual CMM, carried into the grid file (docs/formats.md §7, docs/uncertainty.md).

At every node the virtual CMM draws the residual pose (translation at stylus 0, µm; rotation
vector of ``R_true·R_modelᵀ``, µrad) of the geometric part: the tables' calibration errors, the
squareness errors and the tables' random parts, at the reference temperatures. The node stores
the 15 covariance entries a per-component U at any stylus needs
(:data:`..grid.uncertainty.COVARIANCE_COMPONENTS`); the thermal and probing parts depend on the
run-time signals and are added analytically when a point is corrected.

Trials: a fixed number (default 1000: a standard uncertainty to ≈ 2.2 % relative, 1/√(2(M−1))),
or adaptive runs in the spirit of JCGM 101 §7.9 until every node's u of every pose component is
stable to ``rel_tolerance`` (2·s_u ≤ rel_tolerance·u over the runs).
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from typing import TYPE_CHECKING, Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from ..grid.uncertainty import GridUncertainty, ThermalUncertainty
from .model import UncertaintyModel
from .virtual_cmm import VirtualCMM

if TYPE_CHECKING:
    from ..grid.correction_grid import CorrectionGrid
    from ..machine import Machine

__all__ = ["PAIRS", "grid_uncertainty", "node_covariance"]

FloatArray = NDArray[np.float64]
ProgressFn = Callable[[float, str], None]
#: (a, b) indices into the pose residual (tx, ty, tz, wx, wy, wz) of each stored entry.
PAIRS: tuple[tuple[int, int], ...] = (
    (0, 0), (1, 1), (2, 2),
    (0, 4), (0, 5), (1, 3), (1, 5), (2, 3), (2, 4),
    (3, 3), (4, 4), (5, 5), (3, 4), (3, 5), (4, 5),
)  # fmt: skip
_A = np.array([p[0] for p in PAIRS])
_B = np.array([p[1] for p in PAIRS])


class _Moments:
    """Running mean (N, 6) and co-moments (N, 15) of pose residuals (Chan et al. merging)."""

    def __init__(self, n: int) -> None:
        self.count = 0
        self.mean = np.zeros((n, 6))
        self.m2 = np.zeros((n, len(PAIRS)))

    def add(self, y: FloatArray) -> None:  # y (T, N, 6)
        t = y.shape[0]
        mean_c = y.mean(axis=0)
        # one (t, N) product per stored pair, summed over the trials (no gathered copies)
        dev = np.ascontiguousarray((y - mean_c).transpose(2, 0, 1))  # (6, t, N)
        m2_c = np.empty((len(PAIRS), y.shape[1]))
        for p, (a, b) in enumerate(PAIRS):
            m2_c[p] = np.einsum("tn,tn->n", dev[a], dev[b])
        m2_c = m2_c.T
        delta = mean_c - self.mean
        total = self.count + t
        self.m2 += m2_c + delta[:, _A] * delta[:, _B] * (self.count * t / total)
        self.mean += delta * (t / total)
        self.count = total

    def covariance(self) -> FloatArray:
        return self.m2 / max(self.count - 1, 1)


def node_covariance(
    machine: Machine,
    nodes_mm: ArrayLike,
    *,
    rng: np.random.Generator,
    trials: int = 1000,
    rel_tolerance: float | None = None,
    batch: int = 1000,
    max_trials: int = 100_000,
    model: UncertaintyModel | None = None,
    progress: ProgressFn | None = None,
) -> tuple[FloatArray, dict[str, Any]]:
    """Covariance entries (N, 15) of the geometric residual pose at ``nodes_mm`` (N, 3), and a
    provenance dict (trials, runs, stability). ``trials`` fixed unless ``rel_tolerance`` is
    given (then runs of ``batch`` until stable, at most ``max_trials``)."""
    if trials < 2:
        raise ValueError(f"trials must be ≥ 2, got {trials}")
    if rel_tolerance is not None and not (math.isfinite(rel_tolerance) and rel_tolerance > 0):
        raise ValueError(f"rel_tolerance must be finite and > 0, got {rel_tolerance}")
    vcmm = VirtualCMM(machine, model)
    nodes = np.asarray(nodes_mm, dtype=float)
    prep = vcmm.prepare(nodes, np.zeros(3))
    total = _Moments(prep.n)
    target = trials if rel_tolerance is None else max_trials
    run = min(batch, target) if rel_tolerance is not None else target
    run_sd: list[FloatArray] = []
    done, worst, stable = 0, math.nan, False
    while done < target:
        m = min(run, target - done)
        # a fixed number of trials is one run: its moments are the total's (kept once)
        mom = _Moments(prep.n) if rel_tolerance is not None else total
        for y in vcmm.pose_residuals(prep, m, rng):
            mom.add(y)
            if mom is not total:
                total.add(y)
            done_now = done + mom.count
            if progress is not None:
                progress(min(1.0, done_now / target), f"{done_now} trials at {prep.n} nodes")
        done += m
        run_sd.append(np.sqrt(mom.covariance()[:, [0, 1, 2, 9, 10, 11]]))
        if len(run_sd) >= 2:
            arr = np.stack(run_sd)
            s_u = arr.std(axis=0, ddof=1) / math.sqrt(len(run_sd))
            u = np.sqrt(total.covariance()[:, [0, 1, 2, 9, 10, 11]])
            rel = np.where(u > 0, 2.0 * s_u / np.where(u > 0, u, 1.0), 0.0)
            worst = float(rel.max())
            stable = rel_tolerance is not None and worst <= rel_tolerance
        if stable:
            break
    info = {
        "trials": done,
        "runs": len(run_sd),
        "adaptive": rel_tolerance is not None,
        "rel_tolerance": rel_tolerance,
        "stable": bool(stable) if rel_tolerance is not None else None,
        "worst_2s_u_over_u": None if not math.isfinite(worst) else worst,
        "relative_standard_error_of_u": 1.0 / math.sqrt(2.0 * max(done - 1, 1)),
    }
    return total.covariance(), info


def grid_uncertainty(
    machine: Machine,
    axes_mm: Sequence[ArrayLike],
    *,
    rng: np.random.Generator,
    seed: int | None = None,
    trials: int = 1000,
    rel_tolerance: float | None = None,
    batch: int = 1000,
    model: UncertaintyModel | None = None,
    progress: ProgressFn | None = None,
    coverage_factor: float = 2.0,
) -> GridUncertainty:
    """The :class:`GridUncertainty` of a grid over ``axes_mm`` (three node arrays, mm) for
    ``machine``: node covariances by Monte Carlo (:func:`node_covariance`), the thermal and
    probing data from its uncertainty model. ``seed`` is recorded (the generator is ``rng``)."""
    axes = [np.asarray(a, dtype=float) for a in axes_mm]
    steps = tuple(len(a) for a in axes)
    nodes = np.stack(np.meshgrid(*axes, indexing="ij"), axis=-1).reshape(-1, 3)
    mdl = model if model is not None else machine.uncertainty_model()
    cov, info = node_covariance(
        machine,
        nodes,
        rng=rng,
        trials=trials,
        rel_tolerance=rel_tolerance,
        batch=batch,
        model=mdl,
        progress=progress,
    )
    th = machine.thermal
    fixture = th.workpiece_fixture_mm if th.workpiece_fixture_mm is not None else None
    if fixture is None:
        fixture = machine.volume.reference_mm
    thermal = ThermalUncertainty(
        reference_C=float(th.reference_C),
        reference_mm=_vec3(machine.volume.reference_mm),
        expansion=_vec3(th.expansion),
        u_expansion=_vec3(mdl.expansion),
        u_temperature_C=_vec3(mdl.scale_temperature_C),
        workpiece_expansion=float(th.workpiece_expansion or 0.0),
        u_workpiece_expansion=float(mdl.workpiece_expansion),
        u_workpiece_temperature_C=float(mdl.workpiece_temperature_C),
        workpiece_fixture_mm=_vec3(fixture),
    )
    return GridUncertainty(
        covariance=cov.reshape(*steps, -1),
        probe_um=float(mdl.probe_um),
        thermal=thermal,
        coverage_factor=coverage_factor,
        info={
            "method": "virtual CMM Monte Carlo (ISO/TS 15530-4, JCGM 101) of the residual "
            "error pose at every node, at the reference temperatures",
            "seed": seed,
            "machine_sha256": machine.identity_sha256(),
            **info,
            "defaulted": list(mdl.defaulted),
            "taken_as_zero": list(mdl.zero),
            "notes": list(mdl.notes),
        },
    )


def add_uncertainty(
    grid: CorrectionGrid,
    machine: Machine,
    *,
    rng: np.random.Generator,
    seed: int | None = None,
    trials: int = 1000,
    rel_tolerance: float | None = None,
    model: UncertaintyModel | None = None,
    progress: ProgressFn | None = None,
) -> CorrectionGrid:
    """``grid`` (built from ``machine``) carrying U: :meth:`CorrectionGrid.with_uncertainty` of
    :func:`grid_uncertainty` at its nodes."""
    gu = grid_uncertainty(
        machine,
        grid.axes,
        rng=rng,
        seed=seed,
        trials=trials,
        rel_tolerance=rel_tolerance,
        model=model,
        progress=progress,
    )
    return grid.with_uncertainty(gu)


def _vec3(v: Any) -> tuple[float, float, float]:
    a = [float(x) for x in np.asarray(v, dtype=float).reshape(3)]
    return (a[0], a[1], a[2])
