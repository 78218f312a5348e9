"""``cmm-comp calibrate plan``: the predicted U of the volumetric error agrees with the spread of
repeated simulated calibrations (≥ 30 virtual machines drawn from the guess' uncertainty model,
each simulated and calibrated anew) within ±30 %, and a richer plan predicts a smaller U.
The plans are laser-only and small so that 30 calibrations take a minute or two.
"""

from __future__ import annotations

import json
import sys
from pathlib import Path

import numpy as np
import pytest

sys.path.insert(0, str(Path(__file__).resolve().parent))

from calibration_sim import Setup, laser_file, random_machine, run_cli, write_plan

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
def test_predicted_u_matches_the_spread_of_30_simulated_calibrations(tmp_path: Path) -> None:
    plan, guess = _plan(tmp_path, targets=11)
    proc = run_cli(
        [
            "calibrate",
            "plan",
            str(plan),
            "--machine",
            str(guess),
            "--trials",
            "30",
            "--seed",
            "3",
            "--json",
            "plan.json",
            "--quiet",
        ],
        tmp_path,
        1100,
    )
    assert proc.returncode == 0, proc.stderr
    mc = json.loads((tmp_path / "plan.json").read_text())["monte_carlo"]
    assert mc["trials"] == 30
    ratio = mc["spread_over_predicted_u"]["overall"]
    print(f"spread / predicted U: {ratio:.3f}; coverage of U {mc['coverage_of_predicted_U']:.3f}")
    assert 0.7 <= ratio <= 1.3, mc
    assert 0.85 <= mc["coverage_of_predicted_U"] <= 0.995, mc


@pytest.mark.timeout(600)
def test_more_targets_predict_a_smaller_u(tmp_path: Path) -> None:
    sparse, guess = _plan(tmp_path / "sparse", targets=6)
    dense, _ = _plan(tmp_path / "dense", targets=21)
    proc = run_cli(
        [
            "calibrate",
            "plan",
            str(sparse),
            str(dense),
            "--machine",
            str(guess),
            "--json",
            "plans.json",
            "--quiet",
        ],
        tmp_path,
        500,
    )
    assert proc.returncode == 0, proc.stderr
    a, b = json.loads((tmp_path / "plans.json").read_text())
    assert max(b["volumetric_U_um"]["rms_um"]) < max(a["volumetric_U_um"]["rms_um"])
    assert "sparse" in proc.stdout or "calibration.toml" in proc.stdout
