"""``cmm-comp calibrate plan``: how good will a measurement plan be, before anyone touches the
machine (docs/calibration.md §planner).

The plan's files give the geometry (where each run, ball and point is; their values are not
needed). A virtual machine is drawn from the guess' uncertainty model (:mod:`.virtual_truth`,
the virtual CMM's model), the plan's readings are simulated on it through the public machine API
(:mod:`.simulate`, noise of the plan's a-priori σ, plate poses from the file's centres, stations
at the guesses with dead paths) and calibrated exactly as ``cmm-comp calibrate`` would: the fit's
covariance is the predicted uncertainty of every identified error and of the volumetric error.
With ``trials`` the prediction is checked: that many further virtual machines are calibrated and
the spread of (identified − true) volumetric error (rigid-body free) is set against the
predicted U. Units: mm, µm, µrad.
"""

from __future__ import annotations

import time
from collections.abc import Callable
from dataclasses import replace
from typing import TYPE_CHECKING, Any

import numpy as np
from numpy.typing import NDArray

from .calibrate import CalibrationResult, calibrate
from .datasets import Dataset, load_datasets
from .laser import LaserData
from .multilateration import MultilaterationData
from .plan import Plan
from .plate import PlateData
from .rigid import rigid_basis
from .simulate import simulate_laser, simulate_multilateration, simulate_plate
from .virtual_truth import draw_machine

if TYPE_CHECKING:
    from ..machine import Machine

__all__ = ["predict_plan", "simulated_datasets"]

FloatArray = NDArray[np.float64]
DEAD_PATH_MM = 250.0  # dead paths drawn uniformly within ± this (they are estimated anyway)


def simulated_datasets(
    truth: Machine, geometry: list[Dataset], rng: np.random.Generator
) -> list[Dataset]:
    """The plan's data sets with the readings ``truth`` gives (plus the plan's noise)."""
    out = []
    for ds in geometry:
        d = ds.data
        if isinstance(d, LaserData):
            new: Any = simulate_laser(truth, d, rng)
        elif isinstance(d, PlateData):
            new = simulate_plate(truth, d, None, rng)
        else:
            assert isinstance(d, MultilaterationData)
            dead = rng.uniform(-DEAD_PATH_MM, DEAD_PATH_MM, len(d.stations))
            new = simulate_multilateration(truth, d, None, dead, rng)
        out.append(replace(ds, data=new))
    return out


def _rigid_free(points_mm: FloatArray, field_um: FloatArray) -> FloatArray:
    b = rigid_basis(points_mm)
    v = field_um.reshape(-1)
    return (v - b @ np.linalg.lstsq(b, v, rcond=None)[0]).reshape(-1, 3)


def _summary(r: CalibrationResult) -> dict[str, Any]:
    errors = {
        b.name: {
            "position_mm": b.position_mm.tolist(),
            "u": b.u.tolist(),
            "U_max": float(2.0 * np.max(b.u)),
            "unit": "urad" if b.name.startswith("e") else "um",
        }
        for b in r.bands
    }
    return {
        "errors": errors,
        "squareness": {k: {"u_urad": v["u_urad"]} for k, v in r.squareness.items()},
        "volumetric_U_um": r.volumetric.summary(),
        "null_dimension": r.gauge["all_data"]["null_dimension"],
        "reach": r.reach,
        "condition": r.gauge["condition"],
        "smoothness_tau": {c: float(1.0 / np.sqrt(v)) for c, v in r.solution.lam.items()},
    }


def predict_plan(
    plan: Plan,
    guess: Machine,
    *,
    trials: int = 0,
    seed: int = 0,
    progress: Callable[[str], None] | None = None,
) -> dict[str, Any]:
    """The predicted U of ``plan`` on the machine ``guess`` (and, with ``trials`` ≥ 1, the
    check against that many simulated calibrations)."""
    say = progress or (lambda _m: None)
    t0 = time.perf_counter()
    rng = np.random.default_rng(seed)
    geometry = load_datasets(plan, need_values=False)
    truth = draw_machine(guess, plan, rng)
    result = calibrate(plan, datasets=simulated_datasets(truth, geometry, rng))
    out: dict[str, Any] = {
        "plan": str(plan.source),
        "guess": guess.source,
        "model": plan.model,
        "datasets": [
            {"kind": d["kind"], "where": d["where"], "file": d["file"], "reach": d["reach"]}
            for d in result.datasets_summary
        ],
        "readings": sum(b.n_rows for b in result.problem.blocks),
        **_summary(result),
        "warnings": result.warnings,
    }
    say(
        f"predicted U (k = 2) of the volumetric error: max {max(out['volumetric_U_um']['max_um']):.3g} µm"
    )
    if trials:
        out["monte_carlo"] = _check(plan, guess, geometry, result, trials, rng, say)
    out["elapsed_s"] = time.perf_counter() - t0
    return out


def _check(
    plan: Plan,
    guess: Machine,
    geometry: list[Dataset],
    predicted: CalibrationResult,
    trials: int,
    rng: np.random.Generator,
    say: Callable[[str], None],
) -> dict[str, Any]:
    """Calibrate ``trials`` further virtual machines; compare the spread with the prediction."""
    q = predicted.volumetric.points_mm
    u_pred = predicted.volumetric.U_um / 2.0
    diffs = []
    for t in range(trials):
        truth = draw_machine(guess, plan, rng)
        r = calibrate(plan, datasets=simulated_datasets(truth, geometry, rng))
        true = truth.volumetric_error(q, plan.stylus_mm)
        diffs.append(_rigid_free(q, r.volumetric.error_um - true))
        say(f"simulated calibration {t + 1}/{trials}")
    d = np.asarray(diffs)  # (trials, N, 3)
    spread = np.sqrt(np.mean(d**2, axis=0))  # per node and component
    ratio = spread / np.where(u_pred > 0, u_pred, np.nan)
    covered = np.abs(d) <= 2.0 * u_pred[None]
    return {
        "trials": trials,
        "rms_spread_um": float(np.sqrt(np.mean(d**2))),
        "rms_predicted_u_um": float(np.sqrt(np.mean(u_pred**2))),
        "spread_over_predicted_u": {
            "overall": float(np.sqrt(np.mean(d**2)) / np.sqrt(np.mean(u_pred**2))),
            "median_per_node": float(np.nanmedian(ratio)),
        },
        "coverage_of_predicted_U": float(np.mean(covered)),
        "definition": "identified − true volumetric error at the calibration stylus over the grid "
        "(rigid-body free), RMS over trials, against the predicted standard uncertainty U/2",
    }
