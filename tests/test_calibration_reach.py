"""What the data reach (issue 27): ``calibrate`` and ``calibrate plan`` state per data set and
axis the range its measurement positions cover (mm, % of the travel) and warn once, naming the
axis and the stretch, when part of the travel is reached by no data set.

The oracle is the plans' geometry, made by hand: data sets whose positions are chosen here, and a
laser plan simulated (tests/calibration_sim.py) on a volume that stops at x = 450 mm while the
plan's ``[volume]`` runs to 600 mm, so x 450–600 mm is reached by nothing — by construction.
"""

from __future__ import annotations

import json
import sys
from pathlib import Path
from types import SimpleNamespace as NS

import numpy as np
import pytest

sys.path.insert(0, str(Path(__file__).resolve().parent))

from calibration_sim import Setup, laser_file, random_machine, write_plan
from doc_commands import cli

from cmm_comp.compensation.calibration.gaps import dataset_reach, reach_summary, reach_warning

LOWER, UPPER = np.zeros(3), np.array([1000.0, 500.0, 400.0])


def _plate(q_mm: np.ndarray) -> NS:
    return NS(kind="plate", data=NS(q_mm=q_mm))


def test_reach_per_data_set_and_the_stretches_no_set_reaches() -> None:
    """Hand-made sets: a laser set with runs along x over 100–700 mm (and a squareness row at
    x = 950, which samples no error function along x), a plate whose balls span x 600–800,
    y 0–500, z 50–50.2, a multilateration at x 0 and 300, z 60: the union along x is 0–800, so
    x 800–1000 (20 %) is unreached; along z 0–50 (12.5 %) and 60–400 are, not 50.2–60 (2.5 %,
    under the 5 % threshold); along y nothing (the plate spans it)."""
    runs = (
        NS(kind="linear", axis=0, position_mm=np.linspace(100.0, 700.0, 13)),
        NS(kind="angle", axis=0, position_mm=np.linspace(100.0, 700.0, 13)),
        NS(kind="squareness", axis=0, position_mm=np.array([950.0])),
    )
    laser = NS(kind="laser", data=NS(runs=runs))
    g = np.linspace(0.0, 1.0, 5)
    plate = _plate(np.array([[600 + 200 * u, 500 * v, 50.0 + 0.2 * u] for u in g for v in g]))
    trac = NS(kind="multilateration", data=NS(q_mm=np.array([[0.0, 100, 60], [300, 400, 60]])))

    r = dataset_reach(laser, LOWER, UPPER)
    assert r["y"] is None and r["z"] is None
    assert r["x"] == {"from_mm": 100.0, "to_mm": 700.0, "percent_of_travel": 60.0}
    p = dataset_reach(plate, LOWER, UPPER)
    assert p["x"]["from_mm"] == 600.0 and p["x"]["to_mm"] == 800.0
    assert p["x"]["percent_of_travel"] == pytest.approx(20.0)
    assert p["y"]["percent_of_travel"] == pytest.approx(100.0)
    assert p["z"]["percent_of_travel"] == pytest.approx(0.05)

    s = reach_summary([laser, plate, trac], LOWER, UPPER)
    assert s["per_axis"]["x"]["covered_mm"] == [[0.0, 800.0]]
    assert s["per_axis"]["x"]["percent_of_travel"] == pytest.approx(80.0)
    assert s["per_axis"]["z"]["covered_mm"] == [[50.0, 50.2], [60.0, 60.0]]
    got = [(u["axis"], u["from_mm"], u["to_mm"]) for u in s["unreached"]]
    assert got == [("x", 800.0, 1000.0), ("z", 0.0, 50.0), ("z", 60.0, 400.0)]
    text = reach_warning(s["unreached"]) or ""
    assert "x = 800 … 1000 mm (20 % of its travel)" in text
    assert "z = 0 … 50 mm" in text and "smoothness prior" in text

    # short stretches (≤ 5 % of the travel) at the ends are not warned of
    tiny = _plate(np.array([[20.0, 10.0, 15.0], [980.0, 490.0, 390.0]]))
    assert reach_summary([tiny], LOWER, UPPER)["unreached"] == []
    assert reach_warning([]) is None


SETUP = Setup(
    lower=np.zeros(3), upper=np.array([600.0, 500.0, 400.0]), stylus=np.array([0.0, 0.0, -100.0])
)


def _laser_plan(folder: Path, x_end_mm: float) -> Path:
    """Laser runs over x 0…``x_end_mm`` (the whole y and z travel) in a plan whose volume is
    the full SETUP (x to 600 mm)."""
    rng = np.random.default_rng(5)
    data_setup = Setup(
        lower=SETUP.lower, upper=np.array([x_end_mm, 500.0, 400.0]), stylus=SETUP.stylus
    )
    machine = random_machine(rng, "MB1", data_setup, wave=False)
    folder.mkdir(parents=True, exist_ok=True)
    laser_file(machine, data_setup, rng, folder / "laser.csv", targets=11, cycles=1)
    machine.to_toml(folder / "guess.toml")
    return write_plan(folder, "MB1", SETUP, ("laser",), None, nodes=7)


@pytest.mark.timeout(600)
def test_calibrate_states_the_reach_and_warns_of_the_unreached_end(tmp_path: Path) -> None:
    plan = _laser_plan(tmp_path / "short", 450.0)
    proc = cli("calibrate", plan, "-o", "m.toml", "--report", "rep", cwd=plan.parent)
    assert proc.returncode == 0, proc.stderr
    doc = json.loads((plan.parent / "rep" / "calibration.json").read_text())
    (ds,) = doc["datasets"]
    assert ds["reach"]["x"]["from_mm"] == pytest.approx(0.0)
    assert ds["reach"]["x"]["to_mm"] == pytest.approx(450.0)
    assert ds["reach"]["x"]["percent_of_travel"] == pytest.approx(75.0)
    assert ds["reach"]["y"]["percent_of_travel"] == pytest.approx(100.0)
    assert doc["reach"]["per_axis"]["x"]["covered_mm"] == [[0.0, 450.0]]
    assert [(u["axis"], u["from_mm"], u["to_mm"]) for u in doc["reach"]["unreached"]] == [
        ("x", pytest.approx(450.0), pytest.approx(600.0))
    ]
    warned = [w for w in doc["warnings"] if "reached by no data set" in w]
    assert len(warned) == 1 and "x = 450 … 600 mm (25 % of its travel)" in warned[0]
    assert proc.stderr.count("reached by no data set") == 1
    assert "reach x 75 %, y 100 %, z 100 % of the travel" in proc.stdout
    page = (plan.parent / "rep" / "index.html").read_text()
    assert "Where the data reach" in page and "450.0 … 600.0 mm" in page

    full = _laser_plan(tmp_path / "full", 600.0)
    proc = cli("calibrate", full, "-o", "m.toml", "--report", "rep", cwd=full.parent)
    assert proc.returncode == 0, proc.stderr
    doc = json.loads((full.parent / "rep" / "calibration.json").read_text())
    assert doc["reach"]["unreached"] == []
    assert "reached by no data set" not in proc.stderr


@pytest.mark.timeout(600)
def test_plan_prediction_states_the_reach(tmp_path: Path) -> None:
    plan = _laser_plan(tmp_path, 450.0)
    guess = plan.parent / "guess.toml"
    proc = cli("calibrate", "plan", plan, "--machine", guess, "--json", "p.json", cwd=tmp_path)
    assert proc.returncode == 0, proc.stderr
    doc = json.loads((tmp_path / "p.json").read_text())
    assert doc["datasets"][0]["reach"]["x"]["percent_of_travel"] == pytest.approx(75.0)
    assert doc["reach"]["per_axis"]["x"]["percent_of_travel"] == pytest.approx(75.0)
    assert "the data reach x 75 %, y 100 %, z 100 % of the travel" in proc.stdout
    assert proc.stderr.count("reached by no data set") == 1
    assert "x = 450 … 600 mm" in proc.stderr
