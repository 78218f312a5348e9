"""``cmm-comp calibrate plan``: the predicted U of the volumetric error agrees with the spread of
repeated simulated calibrations (virtual machines drawn from the guess' uncertainty model, each
simulated and calibrated anew) within ±30 %, and a richer plan predicts a smaller U. The plans
are laser-only and small; the command runs through the CLI's ``main()`` in this process.

Power: 16 simulated calibrations (30 before the suite's CPU budget, issue 26), each giving
7³ × 3 = 1,029 (node, component) differences. The RMS spread over them has a relative standard
error of ≈ 1/√(2·16·m), m the number of independent values a calibration carries (≥ 5: the
run's errors are smooth functions of a few coefficients), so ≤ 6 %: a predicted U 30 % off
(ratio outside 0.7–1.3) is still detected with a margin of ≥ 4 standard errors, and the
coverage of U (85–99.5 %) still fails a U ≈ 1.5× too small or too large.
"""

from __future__ import annotations

import json
import sys
from pathlib import Path

import numpy as np
import pytest

sys.path.insert(0, str(Path(__file__).resolve().parent))

from calibration_sim import Setup, laser_file, random_machine, write_plan
from doc_commands import cli

TRIALS = 16
SETUP = Setup(
    lower=np.zeros(3), upper=np.array([600.0, 500.0, 400.0]), stylus=np.array([0.0, 0.0, -100.0])
)
UNCERTAINTY = """
[uncertainty]
squareness = 2.0

[uncertainty.positional]
u = 0.5
u_per_m = 0.5
correlation_mm = 200.0

[uncertainty.straightness]
u = 0.5
correlation_mm = 200.0

[uncertainty.angular]
u = 1.0
correlation_mm = 200.0
"""


def _plan(folder: Path, targets: int) -> tuple[Path, Path]:
    rng = np.random.default_rng(4)
    guess = random_machine(rng, "MB1", SETUP, wave=False)
    folder.mkdir(parents=True, exist_ok=True)
    laser_file(guess, SETUP, rng, folder / "laser.csv", targets=targets, cycles=1)
    plan = write_plan(folder, "MB1", SETUP, ("laser",), None, nodes=7)
    guess.to_toml(folder / "guess.toml")
    with (folder / "guess.toml").open("a", encoding="utf-8") as fh:
        fh.write(UNCERTAINTY)
    return plan, folder / "guess.toml"


@pytest.mark.slow
@pytest.mark.timeout(1200)
def test_predicted_u_matches_the_spread_of_16_simulated_calibrations(tmp_path: Path) -> None:
    plan, guess = _plan(tmp_path, targets=11)
    proc = cli(
        "calibrate",
        "plan",
        plan,
        "--machine",
        guess,
        "--trials",
        str(TRIALS),
        "--seed",
        "3",
        "--json",
        "plan.json",
        "--quiet",
        cwd=tmp_path,
    )
    assert proc.returncode == 0, proc.stderr
    mc = json.loads((tmp_path / "plan.json").read_text())["monte_carlo"]
    assert mc["trials"] == TRIALS
    ratio = mc["spread_over_predicted_u"]["overall"]
    print(f"spread / predicted U: {ratio:.3f}; coverage of U {mc['coverage_of_predicted_U']:.3f}")
    assert 0.7 <= ratio <= 1.3, mc
    assert 0.85 <= mc["coverage_of_predicted_U"] <= 0.995, mc


@pytest.mark.timeout(600)
def test_more_targets_predict_a_smaller_u(tmp_path: Path) -> None:
    sparse, guess = _plan(tmp_path / "sparse", targets=6)
    dense, _ = _plan(tmp_path / "dense", targets=21)
    proc = cli(
        "calibrate",
        "plan",
        sparse,
        dense,
        "--machine",
        guess,
        "--json",
        "plans.json",
        "--quiet",
        cwd=tmp_path,
    )
    assert proc.returncode == 0, proc.stderr
    a, b = json.loads((tmp_path / "plans.json").read_text())
    assert max(b["volumetric_U_um"]["rms_um"]) < max(a["volumetric_U_um"]["rms_um"])
    assert "sparse" in proc.stdout or "calibration.toml" in proc.stdout
