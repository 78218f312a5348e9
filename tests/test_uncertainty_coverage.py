"""Coverage of the virtual CMM's U on many simulated true machines (issue 13, item 3).

The oracle draws true machines *independently* of the package's sampler: every table's
calibration error is drawn on a dense mesh from its covariance (written out here from
docs/uncertainty.md: u²·exp(−Δq²/2ℓ²) + u_per_m²·d·d' + u_relative²·v·v') by a Cholesky factor,
and becomes a tabulated table of a new ``Machine`` (evaluated by the model's own spline and exact
chain); squareness, expansion coefficients and the temperatures the sensors misread are drawn
likewise. Such a machine is sim_controller's ``TrueMachine``; it measures the points (with its
probing noise) and the nominal model corrects them.

* one point and one component per true machine (independent Bernoulli trials): the fraction whose
  true residual lies within ±U95 is 95 % within its binomial interval (99 %: 2.58 σ);
* the ISO 10360-2 E0 test run on true machines: its E0 values are distributed as the virtual
  CMM's E0 (quantiles within binomial intervals, and a Kolmogorov–Smirnov test), and the share of
  machines that pass an MPE equals the virtual CMM's probability of passing.

The tables' random bands are left out here (the random-part path has its own oracle, the
paper's RSS, in test_uncertainty_mc.py).
"""

from __future__ import annotations

import copy
import math
from typing import Any

import numpy as np
import pytest
from scipy.stats import ks_2samp

from cmm_comp.compensation import Machine
from cmm_comp.compensation.formats.measurements import Measurements
from cmm_comp.compensation.uncertainty import (
    MonteCarloSettings,
    e0_uncertainty,
    point_uncertainty,
)
from cmm_comp.sim_controller import TrueMachine
from cmm_comp.sim_controller.iso10360 import length_test
from cmm_comp.sim_controller.sessions import SessionPlan

VOLUME = {"x": [0.0, 700.0], "y": [0.0, 600.0], "z": [0.0, 400.0]}
TABLES: dict[str, dict[str, float]] = {  # name: polynomial slope, u, u_per_m, u_relative, ℓ
    "dx_x": {"c1": 0.004, "u": 0.6, "u_per_m": 1.5, "u_relative": 0.05, "ell": 120.0},
    "dy_y": {"c1": -0.003, "u": 0.5, "u_per_m": 1.0, "u_relative": 0.0, "ell": 200.0},
    "dz_z": {"c1": 0.002, "u": 0.4, "u_per_m": 0.8, "u_relative": 0.0, "ell": 100.0},
    "ey_x": {"c1": 0.01, "u": 1.0, "u_per_m": 0.5, "u_relative": 0.02, "ell": 150.0},
    "ez_y": {"c1": 0.006, "u": 1.2, "u_per_m": 0.0, "u_relative": 0.05, "ell": 90.0},
    "ex_z": {"c1": 0.004, "u": 0.8, "u_per_m": 0.0, "u_relative": 0.0, "ell": 130.0},
    "dy_x": {"c1": 0.001, "u": 0.5, "u_per_m": 0.0, "u_relative": 0.0, "ell": 160.0},
}
SQUARENESS = {"alpha": (6.0, 1.5), "beta1": (-2.0, 1.0), "beta2": (3.0, 1.2)}  # value, u
ALPHA = {"x": (11.5, 1.0, 0.15), "y": (10.0, 0.8, 0.1), "z": (0.0, 0.0, 0.0)}  # α, uα, uT
WORKPIECE = (12.0, 1.2, 0.3, [350.0, 300.0, 0.0])  # α, uα, uT, fixture
PROBE_UM = 0.4
TEMPS_READ = {"T_x": 22.5, "T_y": 18.5, "T_z": 20.0, "T_wp": 23.0}
STYLUS = np.array([25.0, -10.0, -120.0])


def _nominal() -> Machine:
    return Machine.from_dict(
        {
            "name": "coverage",
            "model": "MB1",
            "volume": dict(VOLUME),
            "probe": {"offset": STYLUS.tolist()},
            "thermal": {
                "expansion": {a: v[0] for a, v in ALPHA.items()},
                "workpiece_expansion": WORKPIECE[0],
                "workpiece_fixture": WORKPIECE[3],
            },
            "squareness": {k: v[0] for k, v in SQUARENESS.items()},
            "errors": {c: {"polynomial": [0.0, t["c1"]]} for c, t in TABLES.items()},
            "uncertainty": {
                "probe_um": PROBE_UM,
                "squareness": {k: v[1] for k, v in SQUARENESS.items()},
                "expansion": {a: v[1] for a, v in ALPHA.items()},
                "scale_temperature_C": {a: v[2] for a, v in ALPHA.items()},
                "workpiece_expansion": WORKPIECE[1],
                "workpiece_temperature_C": WORKPIECE[2],
                "errors": {
                    c: {
                        "u": t["u"],
                        "u_per_m": t["u_per_m"],
                        "u_relative": t["u_relative"],
                        "correlation_mm": t["ell"],
                    }
                    for c, t in TABLES.items()
                },
            },
        }
    )


class _TrueMachines:
    """Independent sampler of true machines (dense-mesh Cholesky per table)."""

    def __init__(self, nominal: Machine) -> None:
        self.nominal = nominal
        self.factors: dict[str, tuple[np.ndarray, np.ndarray]] = {}
        for comp, t in TABLES.items():
            lo, hi = VOLUME[comp[-1]]
            mesh = np.linspace(lo, hi, 71)  # ≤ ℓ/9 apart: the spline follows a draw
            value = t["c1"] * mesh
            d = mesh / 1000.0  # reference at the lower corner (0)
            cov = (
                t["u"] ** 2 * np.exp(-0.5 * ((mesh[:, None] - mesh[None, :]) / t["ell"]) ** 2)
                + t["u_per_m"] ** 2 * np.outer(d, d)
                + t["u_relative"] ** 2 * np.outer(value, value)
            )
            w, v = np.linalg.eigh(cov)
            factor = v * np.sqrt(np.clip(w, 0.0, None))
            self.factors[comp] = (mesh, factor)

    def draw(self, rng: np.random.Generator) -> tuple[TrueMachine, dict[str, float]]:
        data: dict[str, Any] = {k: v for k, v in self.nominal.description.items()}
        data.pop("uncertainty")
        data["errors"] = {}
        data["squareness"] = {}
        data["thermal"] = copy.deepcopy(data["thermal"])
        for comp, (mesh, factor) in self.factors.items():
            value = TABLES[comp]["c1"] * mesh + factor @ rng.standard_normal(factor.shape[1])
            data["errors"][comp] = {"position": mesh.tolist(), "value": value.tolist()}
        for k, (val, u) in SQUARENESS.items():
            data["squareness"][k] = val + u * rng.standard_normal()
        temps = dict(TEMPS_READ)
        for axis, (alpha, u_a, u_t) in ALPHA.items():
            data["thermal"]["expansion"][axis] = alpha + u_a * rng.standard_normal()
            temps[f"T_{axis}"] += u_t * rng.standard_normal()
        data["thermal"]["workpiece_expansion"] = WORKPIECE[0] + WORKPIECE[1] * rng.standard_normal()
        temps["T_wp"] += WORKPIECE[2] * rng.standard_normal()
        return TrueMachine(model=Machine.from_dict(data), noise_um=PROBE_UM), temps


def _residuals_um(
    nominal: Machine, truth: TrueMachine, true_temps: dict[str, float], q: np.ndarray,
    rng: np.random.Generator,
) -> np.ndarray:  # fmt: skip
    """True position − corrected position (µm) of indicated points ``q`` measured on ``truth``."""
    n = len(q)
    plan = SessionPlan(
        data=Measurements(
            indicated_mm=q,
            reference_mm=q.copy(),
            temps_C={k: np.full(n, v) for k, v in true_temps.items()},
            stylus_mm=np.broadcast_to(STYLUS, (n, 3)).copy(),
        ),
        reference_C=20.0,
    )
    measured = truth.measure(plan, rng)
    corrected = q + nominal.volumetric_error(q, STYLUS, TEMPS_READ) / 1000.0
    return (measured.reference_mm - corrected) * 1000.0


@pytest.fixture(scope="module")
def nominal() -> Machine:
    return _nominal()


@pytest.fixture(scope="module")
def sampler(nominal: Machine) -> _TrueMachines:
    return _TrueMachines(nominal)


@pytest.mark.slow  # soak-like: a statistical claim over many seeds (tests/README.md rule 8)
def test_fraction_of_true_errors_within_U95_is_95_percent(
    nominal: Machine, sampler: _TrueMachines
) -> None:
    pts = np.array(
        [[50, 40, 30], [650, 560, 380], [350, 300, 200], [600, 80, 350], [120, 520, 60],
         [400, 450, 300]],
        dtype=float,
    )  # fmt: skip
    res = point_uncertainty(
        nominal, pts, STYLUS, TEMPS_READ, rng=np.random.default_rng(1),
        settings=MonteCarloSettings(trials=20_000),
    )  # fmt: skip
    rng = np.random.default_rng(2024)
    machines = 600
    inside95 = inside_k2 = 0
    for i in range(machines):
        truth, temps = sampler.draw(rng)
        p = i % len(pts)
        comp = (i // len(pts)) % 3
        r = _residuals_um(nominal, truth, temps, pts[p : p + 1], rng)[0, comp]
        inside95 += abs(r) <= res.U95_um[p, comp]
        inside_k2 += abs(r) <= res.U_um[p, comp]
    frac95, frac_k2 = inside95 / machines, inside_k2 / machines
    # binomial 99 % interval around the nominal coverage
    half95 = 2.58 * math.sqrt(0.95 * 0.05 / machines)
    print(f"coverage ±U95 {frac95:.4f}, ±2u {inside_k2 / machines:.4f} over {machines} machines")
    assert abs(frac95 - 0.95) <= half95, frac95
    p_k2 = 0.9545  # ±2u of a Gaussian residual (the residual is a sum of many small terms)
    assert abs(frac_k2 - p_k2) <= 2.58 * math.sqrt(p_k2 * (1 - p_k2) / machines), frac_k2


@pytest.mark.slow  # soak-like: 600 true machines for a statistical claim (rule 8)
def test_e0_distribution_and_pass_probability_match_true_machines(
    nominal: Machine, sampler: _TrueMachines
) -> None:
    tests = length_test(nominal.volume.lower_mm, nominal.volume.upper_mm)
    pairs = np.array([[t.a_mm, t.b_mm] for t in tests])
    lengths = np.linalg.norm(pairs[:, 1] - pairs[:, 0], axis=1)
    mpe = (3.0, 400.0)  # E0,MPE = 3 µm + L/400
    res = e0_uncertainty(
        nominal, pairs, STYLUS, TEMPS_READ, mpe=mpe, rng=np.random.default_rng(3),
        settings=MonteCarloSettings(trials=4000),
    )  # fmt: skip
    assert res.mc.values is not None
    e0_mc = res.mc.values[:, 0]
    p_pass = res.nominal["p_pass"]
    assert 0.1 < p_pass < 0.9  # a discriminating MPE for this machine
    rng = np.random.default_rng(77)
    n_true = 250
    e0_true = np.empty(n_true)
    passed = 0
    q = pairs.reshape(-1, 3)
    for i in range(n_true):
        truth, temps = sampler.draw(rng)
        r = _residuals_um(nominal, truth, temps, q, rng)
        corrected = q + nominal.volumetric_error(q, STYLUS, TEMPS_READ) / 1000.0
        true_pts = (corrected + r / 1000.0).reshape(-1, 2, 3)  # where the probe really was
        c = corrected.reshape(-1, 2, 3)
        true_len = np.linalg.norm(true_pts[:, 1] - true_pts[:, 0], axis=1)
        measured = np.linalg.norm(c[:, 1] - c[:, 0], axis=1)
        err = np.abs(true_len - measured) * 1000.0
        e0_true[i] = err.max()
        passed += bool(np.all(err <= mpe[0] + lengths / mpe[1]))
    for level in (0.25, 0.5, 0.9):
        q_mc = np.quantile(e0_mc, level)
        frac = float(np.mean(e0_true <= q_mc))
        assert abs(frac - level) <= 2.58 * math.sqrt(level * (1 - level) / n_true), (level, frac)
    assert ks_2samp(e0_true, e0_mc).pvalue > 0.001
    frac_pass = passed / n_true
    assert abs(frac_pass - p_pass) <= 2.58 * math.sqrt(p_pass * (1 - p_pass) / n_true)
