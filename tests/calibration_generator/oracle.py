"""Stand-ins for ``cmm-comp calibrate`` that prove the harness (its self-test).

``answer_with(case, machine, u_um)`` returns a ``calibrate(plan, out, report)`` that writes, in the
contract's formats, a given machine as the "identified" one: ``OUT.toml`` (docs/formats.md §1),
``DIR/volumetric_u.csv`` (its rigid-body-free error on the grid and the given U) and
``DIR/calibration.json`` (the contract's keys). Fed the true machine it must score coverage 100 %
and RMS difference 0; fed a wrong machine it must fail; fed a machine drawn around the truth with
an honest Monte-Carlo U it must land near 95 % coverage.
"""

from __future__ import annotations

import copy
import json
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from .case import Case, write_grid_csv
from .kinematics import AXES
from .machine import COMPONENTS, SQUARENESS, TrueMachine, machine_toml
from .scoring import Calibrate, remove_rigid

FloatArray = NDArray[np.float64]


def report_json(case: Case, machine: TrueMachine, u_um: FloatArray) -> dict[str, Any]:
    """A calibration.json with every key the contract lists."""
    errors = {}
    for name in COMPONENTS:
        k = AXES.index(name[3])
        q = np.linspace(machine.lower_mm[k], machine.upper_mm[k], 11)
        errors[name] = {
            "position_mm": q.tolist(),
            "value": machine.component(name, q).tolist(),
            "u": [0.1] * q.size,
        }
    return {
        "model": machine.model,
        "errors": errors,
        "squareness": {
            s: {"value_urad": machine.squareness_urad[s], "u_urad": 0.5} for s in SQUARENESS
        },
        "volumetric_U_um": {"max": float(np.max(u_um)), "median": float(np.median(u_um))},
        "datasets": [dict(d, rms_before_um=1.0, rms_after_um=0.1) for d in case.datasets],
        "gauge": ["rigid-body motion of the volume: 3 translations, 3 rotations"],
        "condition": 1.0,
    }


def answer_with(case: Case, machine: TrueMachine, u_um: float | FloatArray) -> Calibrate:
    """A calibrate that 'identifies' ``machine`` with expanded uncertainty ``u_um`` (µm)."""

    def calibrate(plan: Path, out_toml: Path, report_dir: Path) -> tuple[int, str, str]:
        del plan
        out_toml.write_text(machine_toml(machine, "(oracle)"), encoding="utf-8")
        report_dir.mkdir(parents=True, exist_ok=True)
        err = machine.error_um(case.nodes_mm, case.stylus_mm)
        free, _ = remove_rigid(case.nodes_mm, err)
        u = np.broadcast_to(np.asarray(u_um, dtype=float), free.shape)
        write_grid_csv(report_dir / "volumetric_u.csv", case.nodes_mm, free, u)
        doc = report_json(case, machine, u)
        (report_dir / "calibration.json").write_text(json.dumps(doc), encoding="utf-8")
        return 0, "", ""

    return calibrate


def perturbed(machine: TrueMachine, rng: np.random.Generator, sigma: float) -> TrueMachine:
    """The machine with every Legendre coefficient and squareness moved by N(0, sigma) (µm/µrad)."""
    out = copy.deepcopy(machine)
    for name in COMPONENTS:
        out.legendre[name] = machine.legendre[name] + rng.normal(
            0.0, sigma, machine.legendre[name].size
        )
    out.squareness_urad = {
        s: v + float(rng.normal(0.0, sigma)) for s, v in machine.squareness_urad.items()
    }
    return out


def montecarlo_u(
    case: Case, rng: np.random.Generator, sigma: float = 0.3, draws: int = 150
) -> FloatArray:
    """U (k = 2) per node and component of the rigid-free error of machines ``perturbed`` by
    ``sigma`` around the truth: twice the ensemble's standard deviation (µm)."""
    diffs = []
    for _ in range(draws):
        d = perturbed(case.machine, rng, sigma).error_um(case.nodes_mm, case.stylus_mm)
        diffs.append(remove_rigid(case.nodes_mm, d - case.truth_um)[0])
    return 2.0 * np.std(np.array(diffs), axis=0)


def translated(machine: TrueMachine, shift_um: FloatArray) -> TrueMachine:
    """The machine plus a constant translation (a rigid motion no data kind can see)."""
    out = copy.deepcopy(machine)
    for k, a in enumerate(AXES):
        name = f"d{a}_{a}"
        out.legendre[name] = machine.legendre[name].copy()
        out.legendre[name][0] += float(shift_um[k])
    return out
