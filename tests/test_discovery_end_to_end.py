"""Model discovery end to end: a simulated machine with a hidden effect → diagnose → extend →
rebuild the grid → daemon on a virtual CAN bus → the ISO 10360-2 E0 improves over the grid of the
unextended model. Oracle: the hidden truth (the simulated machine carries the effect)."""

from __future__ import annotations

from pathlib import Path

import pytest

from cmm_comp.cli.demo import run_demo
from cmm_comp.compensation import CorrectionGrid, Machine, diagnose
from cmm_comp.sim_controller.true_machine import simulate

ROOT = Path(__file__).resolve().parents[1]
NPL = ROOT / "examples" / "machines" / "npl-bridge.toml"


@pytest.mark.slow
def test_hidden_coupling_found_extended_and_compensated_by_the_daemon(tmp_path: Path) -> None:
    model = Machine.from_toml(NPL)
    truth, session = simulate(model, ["coupling"], [6.0], seed=11, noise_um=0.5)
    hidden = truth.hidden[0].describe()

    diagnosis = diagnose(model, session)
    found = diagnosis.to_json()
    assert found["verdict"] == "found"
    first = found["effects"][0]
    assert (first["cause"], first["component"], first["varies_with"]) == (
        "coupling",
        hidden["component"],
        hidden["varies_with"],
    )
    assert found["heldout_rms_um"]["after"] < 0.5 * found["heldout_rms_um"]["before"]

    extended_path = tmp_path / "extended.toml"
    diagnosis.extended_machine().to_toml(extended_path)  # what `cmm-comp extend` writes
    extended = Machine.from_toml(extended_path)
    truth_path = tmp_path / "truth.toml"
    truth.machine.to_toml(truth_path)

    steps = model.volume.steps
    e0 = {}
    for name, machine in (("base", model), ("extended", extended)):
        grid_path = tmp_path / f"{name}.grid"
        CorrectionGrid.build(machine, steps=steps).save(grid_path)
        result = run_demo(
            machine_path=truth_path, grid_path=grid_path, n_random=50, seed=3, noise_um=0.1
        )
        assert result["corrected"] == result["readings"]
        e0[name] = result["e0_after_um"]
        e0["before"] = result["e0_before_um"]
    assert e0["extended"] < 0.6 * e0["base"], e0
    assert e0["base"] < e0["before"], e0
