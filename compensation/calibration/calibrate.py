"""``cmm-comp calibrate``: a plan's measurements in, the identified machine with the uncertainty
of every error out (docs/calibration.md).

:func:`calibrate` reads the data, builds and solves the identification problem
(:mod:`.solver`), analyses what the data could not see (:mod:`.gauge`), turns the covariance
into uncertainties (:mod:`.covariance`), builds the machine description (:mod:`.writer`) and
checks that it reproduces the fit (:mod:`.checks`). Nothing is written here: the caller writes
the machine and the report (:mod:`.report`) once everything has succeeded.
Units: mm, µm, µrad.
"""

from __future__ import annotations

import time
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any

import numpy as np
from numpy.typing import NDArray

from .checks import exact_vs_first_order, resimulation, virtual_cmm_check
from .covariance import (
    FunctionBand,
    VolumetricU,
    function_bands,
    squareness_bands,
    volumetric_u,
)
from .datasets import Dataset, build_problem, load_datasets
from .gaps import dataset_reach, gap_warning, plate_gaps, reach_summary, reach_warning
from .gauge import analyse_gauge
from .plan import Plan
from .posterior import with_smoothness_spread
from .solver import Problem, Solution, solve
from .writer import build_machine, machine_description

if TYPE_CHECKING:
    from ..machine import Machine

__all__ = ["CalibrationResult", "calibrate", "dataset_summary"]

FloatArray = NDArray[np.float64]
MIN_PLATE_PLACEMENTS = 4
REVERSAL_P = 0.01  # a reversal is written when the data show one at this significance
MISFIT_WARNING = 3.0  # estimated σ more than this × the a-priori σ: the model does not fit


@dataclass
class CalibrationResult:
    """Everything :func:`calibrate` found; :attr:`description` is the machine to write."""

    plan: Plan
    datasets: list[Dataset]
    problem: Problem
    solution: Solution
    before: list[FloatArray]
    bands: list[FunctionBand]
    squareness: dict[str, Any]
    volumetric: VolumetricU
    gauge: dict[str, Any]
    description: dict[str, Any]
    machine: Machine
    checks: dict[str, Any]
    datasets_summary: list[dict[str, Any]]
    elapsed_s: float
    warnings: list[str] = field(default_factory=list)
    #: what the data reach per axis and the stretches no data set reaches (gaps.reach_summary)
    reach: dict[str, Any] = field(default_factory=dict)


def _rms(values: FloatArray) -> float | None:
    return float(np.sqrt(np.mean(values**2))) if values.size else None


def dataset_summary(
    problem: Problem, datasets: list[Dataset], before: list[FloatArray], after: list[FloatArray]
) -> list[dict[str, Any]]:
    """Per data set: the residual RMS before (no errors, nuisance fitted) and after the fit, per
    quantity with its a-priori and estimated σ. ``rms_*_um`` over the µm readings (a data set of
    angles only: over all its readings, µrad, said by ``unit``); ``reach`` the range of its
    measurement positions per axis (mm, % of the travel: :func:`.gaps.dataset_reach`)."""
    out = []
    lay = problem.model.layout
    for bi, (block, ds) in enumerate(zip(problem.blocks, datasets, strict=True)):
        quantities = {}
        um_rows = np.zeros(block.n_rows, dtype=bool)
        for gi, g in enumerate(problem.groups):
            if g.block != bi:
                continue
            rows = problem.group_index[bi] == gi
            vg = block.variance_groups[g.local]
            if vg.unit == "um":
                um_rows |= rows
            quantities[vg.quantity] = {
                "n": int(g.n),
                "rms_before": _rms(before[bi][rows]),
                "rms_after": _rms(after[bi][rows]),
                "unit": vg.unit,
                "sigma_prior": vg.sigma0,
                "sigma_estimated": g.sigma if g.estimated else None,
                "redundancy": float(g.redundancy),
            }
        rows = um_rows if um_rows.any() else np.ones(block.n_rows, dtype=bool)
        out.append(
            {
                "kind": ds.kind,
                "where": ds.where,
                "file": ds.source,
                "readings": int(block.n_rows),
                "rms_before_um": _rms(before[bi][rows]),
                "rms_after_um": _rms(after[bi][rows]),
                "unit": "um" if um_rows.any() else "urad",
                "quantities": quantities,
                "reach": dataset_reach(ds, lay.lower_mm, lay.upper_mm),
                "nuisance": None,  # the fitted poses / stations, filled in by calibrate()
            }
        )
    return out


def calibrate(
    plan: Plan,
    *,
    datasets: list[Dataset] | None = None,
    progress: Callable[[str], None] | None = None,
) -> CalibrationResult:
    """Identify the plan's machine from its data sets (read from the plan's files unless
    given). :class:`CalibrationError` for bad input; the fit itself never raises on data it
    cannot explain — it says so in :attr:`CalibrationResult.warnings`."""
    from threadpoolctl import threadpool_limits

    t0 = time.perf_counter()
    with threadpool_limits(limits=1, user_api="blas"):  # small dense algebra: one thread
        return _calibrate(plan, datasets, progress or (lambda _m: None), t0)


def _calibrate(
    plan: Plan, datasets: list[Dataset] | None, say: Callable[[str], None], t0: float
) -> CalibrationResult:
    if datasets is None:
        datasets = load_datasets(plan)
    say(f"read {len(datasets)} data set(s): " + ", ".join(f"{d.kind} {d.where}" for d in datasets))
    problem = build_problem(plan, datasets)
    say(
        f"{problem.p} error parameters, {problem.n - problem.p} nuisance parameters, "
        f"{sum(b.n_rows for b in problem.blocks)} readings"
    )
    sol = solve(problem, progress=say)
    # the residuals with the nuisance alone fitted (θ = 0): the solver's first stage
    before = sol.before
    kept, dropped = _significant_reversals(problem, sol)
    if dropped:  # a reversal the data do not show is not written (it would need dir signals)
        say("no significant reversal on " + ", ".join(dropped) + ": fitted again without")
        problem = build_problem(plan, datasets, reversal=kept)
        sol = solve(problem, progress=say)
    # the smoothness was estimated, not known: its uncertainty widens the volumetric U
    sol = with_smoothness_spread(problem, sol)
    layout = problem.model.layout
    cov = sol.covariance_theta
    kinds = [b.kind for b in problem.blocks]
    gauge = analyse_gauge(problem, sol.stats, kinds, plan.stylus_mm, sol.lam)
    # per function: the data-determined part (what no reading sees held at its zero: the
    # gauge report lists it); the volumetric U keeps everything, prior variance included
    bands = function_bands(layout, sol.theta, sol.covariance_theta_pinned)
    sq = squareness_bands(layout, sol.theta, sol.covariance_theta_pinned)
    vol = volumetric_u(problem.model, sol.theta, cov, plan.stylus_mm, plan.steps)
    plate_sigma = [g.sigma for g in problem.groups if problem.blocks[g.block].kind == "plate"]
    description = machine_description(
        plan,
        layout,
        sol.theta,
        bands,
        {k: v["u_urad"] for k, v in sq.items()},
        probe_um=float(np.sqrt(np.mean(np.square(plate_sigma)))) if plate_sigma else None,
        meta={"calibration_plan": str(plan.source)},
    )
    machine = build_machine(description, f"calibrated from {plan.source}")
    checks = {
        "resimulation": resimulation(problem, sol.theta, sol.states, machine),
        "exact_vs_first_order": exact_vs_first_order(
            problem, sol.theta, machine, vol.points_mm, plan.stylus_mm
        ),
        "virtual_cmm": virtual_cmm_check(machine, vol.points_mm, plan.stylus_mm, vol.U_um),
    }
    summary = dataset_summary(problem, datasets, before, sol.residuals)
    for block, st, cn, entry in zip(
        problem.blocks, sol.states, sol.covariance_nuisance, summary, strict=True
    ):
        entry["nuisance"] = block.describe_state(st, cn) or None
    result = CalibrationResult(
        plan=plan,
        datasets=datasets,
        problem=problem,
        solution=sol,
        before=before,
        bands=bands,
        squareness=sq,
        volumetric=vol,
        gauge=gauge,
        description=description,
        machine=machine,
        checks=checks,
        datasets_summary=summary,
        elapsed_s=time.perf_counter() - t0,
        reach=reach_summary(datasets, layout.lower_mm, layout.upper_mm),
    )
    result.warnings = _warnings(result)
    return result


def _significant_reversals(problem: Problem, sol: Solution) -> tuple[tuple[int, ...], list[str]]:
    """The axes whose estimated reversal is significant and the names of those that are not.

    Two Wald tests at p < :data:`REVERSAL_P` each, the reversal kept when either rejects "no
    reversal": its mean over the travel (1 degree of freedom: a backlash is mostly one step,
    and a test spread over every node's value misses it) and its whole profile (all its
    degrees of freedom). Dropping a real reversal is not harmless where the data's directions
    of travel correlate with position (a multilateration program): the fit would read it as a
    scale error."""
    from scipy.special import chdtrc  # χ² survival function (scipy.stats costs ~1 s to import)

    kept, dropped = [], []
    cov = sol.covariance_theta_pinned
    for fn in problem.model.layout.functions:
        if not fn.is_reversal:
            continue
        h = sol.theta[fn.cols]
        c = cov[fn.cols, fn.cols]
        w, v = np.linalg.eigh(c)
        ok = w > 1e-12 * max(float(w.max()), 1e-300)
        stat = float(np.sum((v[:, ok].T @ h) ** 2 / w[ok]))
        mean = fn.matrix(np.linspace(fn.lo_mm, fn.hi_mm, 201)).mean(axis=0)
        var_mean = float(mean @ c @ mean)
        p_mean = chdtrc(1, float(mean @ h) ** 2 / var_mean) if var_mean > 0 else 1.0
        if min(chdtrc(int(np.sum(ok)), stat), p_mean) < REVERSAL_P:
            kept.append(fn.axis)
        else:
            dropped.append(fn.component)
    return tuple(kept), dropped


def _warnings(r: CalibrationResult) -> list[str]:
    out = []
    if not r.solution.converged:
        out.append(
            f"the fit did not converge in {r.solution.iterations} iterations: check the "
            "station guesses and the data; the result is the last iterate"
        )
    for ds in r.datasets:
        placements = getattr(ds.data, "placements", None)
        if placements is not None and len(placements) < MIN_PLATE_PLACEMENTS:
            out.append(
                f"{ds.where}: {len(placements)} plate placement(s); the PTB method uses at "
                f"least {MIN_PLATE_PLACEMENTS} (two planes, two orientations)"
            )
    for entry in r.datasets_summary:
        for name, q in entry["quantities"].items():
            s = q["sigma_estimated"]
            if s is not None and s > MISFIT_WARNING * q["sigma_prior"]:
                out.append(
                    f"{entry['where']} ({entry['file']}): {name} scatter about the fit "
                    f"{s:.3g} {q['unit']} is {s / q['sigma_prior']:.1f}× its a-priori "
                    f"{q['sigma_prior']:g}: the data hold something the model does not "
                    "describe (or the a-priori σ is too small); U is scaled to the scatter"
                )
    lay = r.problem.model.layout
    gaps = gap_warning(plate_gaps(r.datasets, lay.lower_mm, lay.upper_mm))
    if gaps:
        out.append(gaps)
    unreached = reach_warning(r.reach.get("unreached", []))
    if unreached:
        out.append(unreached)
    unseen = [
        f"{'+'.join(f['errors'])} ({f['what']})"
        for f in r.gauge["all_data"]["freedoms"]
        if f.get("consequence", "").startswith("not identified")
    ]
    if unseen:
        out.append(
            "not identified by the data, yet the volumetric error at the calibration "
            "stylus depends on it (its U carries the prior): " + "; ".join(unseen)
        )
    worst = r.checks["resimulation"]["max_abs"]
    if worst > 1e-6:
        out.append(f"the written machine reproduces the fit only to {worst:.3g} µm/µrad")
    return out
