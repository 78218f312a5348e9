"""ISO 230-2 on the real data in ../shared/realdata (skipped when the folder is absent).

The ecmc reports are an independent implementation; we compare wherever they follow the standard.
Their tables labelled "forward" hold the .dat file's REF_DATA_BWD (and vice versa), so their ↑
parameters are our ↓ ones and their B_i has the opposite sign; their E (= their E_fwd) and R
(= max of the unidirectional R) do not follow ISO 230-2 (docs/iso230.md).
"""

from __future__ import annotations

import csv
import re
from pathlib import Path

import numpy as np
import pytest

from cmm_comp.compensation.formats.realdata import (
    error_table_from_run,
    iso230_points_from_log,
    iso230_run_from_points,
    measurement_rows,
    read_camonitor_log,
    read_iso230_dat,
    write_measurements_csv,
)

pytestmark = pytest.mark.realdata


def report_values_mm(path: Path) -> dict[str, float]:
    """``NAME = value [mm]`` lines of an ecmc report (bold or not), as a dict."""
    pattern = re.compile(r"^\**(\w+) = ([-+0-9.e]+) \[mm\]\**\s*$")
    out = {}
    for line in path.read_text(encoding="utf-8").splitlines():
        m = pattern.match(line.strip())
        if m:
            out[m.group(1)] = float(m.group(2))
    return out


@pytest.mark.parametrize(
    ("folder", "dat", "report", "abs_um"),
    [
        ("ess-target-b02", "target_x.md_ISO230.dat", "x_iso230_2_report.md", 0.006),
        ("psi-ecmccfg", "report.md_ISO230.dat", "report.md", 0.0001),
    ],
)
def test_against_ecmc_reports(
    realdata_dir: Path, folder: str, dat: str, report: str, abs_um: float
) -> None:
    r = read_iso230_dat(realdata_dir / folder / dat).evaluate()
    rep = {k: v * 1000.0 for k, v in report_values_mm(realdata_dir / folder / report).items()}

    def close(ours: float, theirs: float) -> bool:
        return abs(ours - theirs) <= max(abs_um, 1e-3 * abs(theirs))

    # where the report follows the standard (with its direction labels swapped)
    assert close(r.A_um, rep["A"]) and close(r.M_um, rep["M"]) and close(r.B_um, rep["B"])
    assert close(r.B_mean_um, -rep["B_avg"])
    assert close(r.A_fwd_um, rep["A_bwd"]) and close(r.A_bwd_um, rep["A_fwd"])
    assert close(r.E_fwd_um, rep["E_bwd"]) and close(r.E_bwd_um, rep["E_fwd"])
    assert close(r.R_fwd_um, rep["R_bwd"]) and close(r.R_bwd_um, rep["R_fwd"])
    # where it does not: its E is smaller than M (impossible), its R is max(R↑, R↓)
    assert rep["E"] < rep["M"] <= r.E_um
    assert close(rep["E"], rep["E_fwd"]) and not close(r.E_um, rep["E"])
    assert close(rep["R"], max(r.R_fwd_um, r.R_bwd_um)) and r.R_um > rep["R"]


def test_ess_x_numbers(realdata_dir: Path) -> None:
    run = read_iso230_dat(realdata_dir / "ess-target-b02" / "target_x.md_ISO230.dat")
    assert run.target_mm.tolist() == list(np.arange(-20.0, 20.1, 5.0))
    assert run.fwd_mm.shape == (9, 5)
    r = run.evaluate()
    got = [r.A_um, r.B_um, r.E_um, r.M_um, r.R_um]
    assert got == pytest.approx([135.271, 33.576, 122.847, 93.653, 55.161], abs=0.001)
    # README: backward − forward ≈ 20–40 µm everywhere
    assert np.all((-r.reversal_um > 15) & (-r.reversal_um < 40))
    name, table = error_table_from_run(run, axis="x")
    assert name == "dx_x" and table["value"][0] == pytest.approx(-35.591, abs=1e-3)


@pytest.mark.parametrize("name", ["report_target_y.md_ISO230.dat", "report_z.md_ISO230.dat"])
def test_ess_y_z_load_and_obey_invariants(realdata_dir: Path, name: str) -> None:
    r = read_iso230_dat(realdata_dir / "ess-target-b02" / name).evaluate()
    assert r.cycles == 5 and r.positions in (5, 9)
    assert r.A_um >= r.E_um >= r.M_um > 0 and r.R_um >= max(r.R_fwd_um, r.R_bwd_um, r.B_um)


def test_ess_x_raw_log_reproduces_dat(realdata_dir: Path, tmp_path: Path) -> None:
    folder = realdata_dir / "ess-target-b02"
    log = read_camonitor_log(folder / "x_230_2.log")
    assert len(log["IOC_TEST:ILD_DownSample"].value) == 25072
    points = iso230_points_from_log(log)
    assert len(points) == 90
    run, (gain, offset) = iso230_run_from_points(points, "x_230_2.log")
    # the ecmc report's "gear ratio" Target Position → Reference: -1.00357, 50.31931
    assert gain == pytest.approx(-1.0035779146, abs=1e-9)
    assert offset == pytest.approx(50.3193131396, abs=1e-9)
    dat = read_iso230_dat(folder / "target_x.md_ISO230.dat")
    np.testing.assert_array_equal(run.target_mm, dat.target_mm)
    # same approach, same sample: agreement to the .dat's printed precision (≪ 1 nm)
    assert np.abs(run.fwd_mm - dat.fwd_mm).max() < 1e-8
    assert np.abs(run.bwd_mm - dat.bwd_mm).max() < 1e-8
    # the servo settles within 1 µm of the target, on the approach side
    assert run.encoder_fwd_mm is not None and run.encoder_bwd_mm is not None
    lag_fwd_um = (run.encoder_fwd_mm - run.target_mm[:, None]) * 1000
    lag_bwd_um = (run.encoder_bwd_mm - run.target_mm[:, None]) * 1000
    assert np.all((lag_fwd_um > 0) & (lag_fwd_um < 1)) and np.all(
        (lag_bwd_um < 0) & (lag_bwd_um > -1)
    )

    rows = measurement_rows(run, axis="x")
    assert len(rows) == 90
    times = [row["t"] for row in rows]
    assert times == sorted(times) and 0 < times[0] < times[-1] < 3600
    out = write_measurements_csv(tmp_path / "x.csv", rows)
    with out.open(newline="") as fh:
        back = list(csv.DictReader(fh))
    assert len(back) == 90 and back[0]["group"] == "fwd-c1" and back[0]["dir_x"] == "1"
    assert float(back[0]["ref_x"]) == pytest.approx(dat.fwd_mm[0, 0], abs=1e-8)
    assert float(back[0]["y"]) == 0.0 and float(back[0]["ref_z"]) == 0.0
