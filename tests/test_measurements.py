"""Measurements CSV (docs/formats.md §2): round trip, and bad files named by file, line and column."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from cmm_comp.compensation.errors import MeasurementFileError
from cmm_comp.compensation.formats.measurements import read_measurements, write_measurements
from cmm_comp.compensation.machine import Machine
from cmm_comp.sim_controller.sessions import plan_session

ROOT = Path(__file__).resolve().parents[1]
NPL = ROOT / "examples" / "machines" / "npl-bridge.toml"
GOOD = "x,y,z,ref_x,ref_y,ref_z,t,dir_x,nx,ny,nz,group\n1,2,3,1.001,2,3,0,1,1,0,0,a\n4,5,6,4,5.002,6,1,-1,0,1,0,b\n"


def test_round_trip(tmp_path) -> None:
    plan = plan_session(Machine.from_toml(NPL), np.random.default_rng(0), n_points=100)
    path = write_measurements(tmp_path / "m.csv", plan.data)
    back = read_measurements(path)
    np.testing.assert_array_equal(back.indicated_mm, plan.data.indicated_mm)
    np.testing.assert_array_equal(back.normals, plan.data.normals)
    assert back.temps_C.keys() == plan.data.temps_C.keys()
    assert list(back.group) == list(plan.data.group)


def test_observed_error_sign(tmp_path) -> None:
    (tmp_path / "m.csv").write_text(GOOD)
    m = read_measurements(tmp_path / "m.csv")
    np.testing.assert_allclose(m.observed_error_um(), [[1.0, 0, 0], [0, 2.0, 0]], atol=1e-9)
    assert m.inputs()["dir_x"].tolist() == [1.0, -1.0]


@pytest.mark.parametrize(
    ("text", "match"),
    [
        ("", "empty file"),
        ("x,y,z,ref_x,ref_y\n1,2,3,4,5\n", "missing required column.*ref_z"),
        (
            "x,y,z,ref_x,ref_y,ref_z\n1,2,3,4,5,6\n1,zz,3,4,5,6\n",
            r"line 3, column 'y': not a number: 'zz'",
        ),
        (
            "x,y,z,ref_x,ref_y,ref_z,dir_x\n1,2,3,4,5,6,0.5\n",
            r"line 2, column 'dir_x': direction must be \+1 or -1",
        ),
        ("x,y,z,ref_x,ref_y,ref_z,nx,ny,nz\n1,2,3,4,5,6,1,1,0\n", "unit vector"),
        ("x,y,z,ref_x,ref_y,ref_z\n1,2,3,4,5\n", "line 2: 5 fields, the header has 6"),
        ("x,y,z,ref_x,ref_y,ref_z\n1,2,3,4,5,nan\n", "not a finite number"),
        ("x,y,z,ref_x,ref_y,ref_z,px\n1,2,3,4,5,6,1\n", "go together"),
        ("x,y,z,ref_x,ref_y,ref_z\n", "no data rows"),
    ],
)
def test_bad_files(tmp_path, text, match) -> None:
    p = tmp_path / "bad.csv"
    p.write_text(text)
    with pytest.raises(MeasurementFileError, match=match) as info:
        read_measurements(p)
    assert str(p) in str(info.value)


def test_cli_bad_file_no_traceback_nothing_written(tmp_path, capsys) -> None:
    from cmm_comp.cli import main

    p = tmp_path / "bad.csv"
    p.write_text("x,y,z,ref_x,ref_y,ref_z\n1,2,3,4,5,6\n1,2,oops,4,5,6\n")
    out = tmp_path / "out.json"
    assert main(["diagnose", str(NPL), str(p), "--json", str(out)]) == 2
    err = capsys.readouterr().err
    assert "line 3, column 'z'" in err and "Traceback" not in err
    assert not out.exists()
    assert (
        main(["extend", str(NPL), str(tmp_path / "absent.csv"), "-o", str(tmp_path / "e.toml")])
        == 2
    )
    assert "no such file" in capsys.readouterr().err
    assert not (tmp_path / "e.toml").exists()
