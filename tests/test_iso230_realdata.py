"""Importers of real ISO 230-2 runs: synthetic files (good and bad) and the real data sets.

Real data lives in ../shared/realdata (never copied here); those tests skip when it is absent.
"""

from __future__ import annotations

import csv
from pathlib import Path

import numpy as np
import pytest

from cmm_comp.compensation.formats.realdata import (
    RealDataError,
    error_table_from_run,
    iso230_points_from_log,
    iso230_run_from_points,
    measurement_rows,
    read_camonitor_log,
    read_iso230_dat,
    write_measurements_csv,
)

# ------------------------------------------------------------------------- synthetic .dat files
GOOD_DAT = """TEST_DATA=# free text header
# a comment
UNIT=mm
CYCLES=2
POSITIONS=2
TGT_DATA[1]=0
TGT_DATA[2]=10
REF_DATA_FWD[1,1]=.001
REF_DATA_FWD[1,2]=0.003
REF_DATA_FWD[2,1]=10.002
REF_DATA_FWD[2,2]=10.004
REF_DATA_BWD[1,1]=-0.001
REF_DATA_BWD[1,2]=-0.001
REF_DATA_BWD[2,1]=10.000
REF_DATA_BWD[2,2]=10.000

"""


def _write(tmp_path: Path, text: str, name: str = "run.dat") -> Path:
    path = tmp_path / name
    path.write_text(text, encoding="utf-8")
    return path


def test_dat_good_file(tmp_path: Path) -> None:
    run = read_iso230_dat(_write(tmp_path, GOOD_DAT))
    assert run.target_mm.tolist() == [0.0, 10.0]
    assert run.fwd_mm.tolist() == [[0.001, 0.003], [10.002, 10.004]]
    assert run.bwd_mm.tolist() == [[-0.001, -0.001], [10.0, 10.0]]
    assert run.meta["UNIT"] == "mm" and "TEST_DATA" in run.meta
    r = run.evaluate()
    assert r.mean_fwd_um == pytest.approx([2.0, 3.0])
    assert r.reversal_um == pytest.approx([3.0, 3.0])


def test_dat_unit_um_is_scaled(tmp_path: Path) -> None:
    text = GOOD_DAT.replace("UNIT=mm", "UNIT=um").replace("=10.", "=10000.")
    text = text.replace("TGT_DATA[2]=10", "TGT_DATA[2]=10000")
    run = read_iso230_dat(_write(tmp_path, text))
    assert run.target_mm.tolist() == [0.0, 10.0]
    assert run.fwd_mm[0, 0] == pytest.approx(0.000001)


@pytest.mark.parametrize(
    ("old", "new", "message"),
    [
        ("REF_DATA_FWD[1,2]=0.003", "REF_DATA_FWD[1,2] 0.003", r":9: expected 'KEY=value'"),
        (
            "REF_DATA_FWD[1,2]=0.003",
            "REF_DATA_FWD[1,2]=0.0o3",
            r":9 \(REF_DATA_FWD\[1,2\]\): value '0.0o3' is not a number",
        ),
        ("REF_DATA_FWD[1,2]=0.003", "REF_DATA_FWD[1,2]=nan", r":9 .*not finite"),
        ("REF_DATA_BWD[2,1]=10.000\n", "", r"missing REF_DATA_BWD\[2,1\]"),
        ("TGT_DATA[1]=0\n", "", r"missing TGT_DATA\[1\]"),
        ("REF_DATA_FWD[1,2]=0.003", "REF_DATA_FWD[1,1]=0.003", r":9: duplicate key .*line 8"),
        ("REF_DATA_FWD[1,2]=0.003", "REF_DATA_FWD[1]=0.003", r":9: .*needs 2 index"),
        ("REF_DATA_FWD[1,2]=0.003", "REF_DATA_FWD[0,2]=0.003", r":9: .*index\(es\) >= 1"),
        ("CYCLES=2", "CYCLES=5", r":4: CYCLES=5 but the data has 2"),
        ("UNIT=mm", "UNIT=inch", r":3: unknown UNIT 'inch'"),
        ("UNIT=mm", "UNIT[2]=mm", r":3: unexpected index"),
        ("UNIT=mm", "UN-IT=mm", r":3: malformed key"),
    ],
)
def test_dat_bad_input_names_file_line_and_problem(
    tmp_path: Path, old: str, new: str, message: str
) -> None:
    assert old in GOOD_DAT
    path = _write(tmp_path, GOOD_DAT.replace(old, new))
    with pytest.raises(RealDataError, match=message):
        read_iso230_dat(path)
    with pytest.raises(RealDataError) as info:
        read_iso230_dat(path)
    assert str(info.value).startswith(str(path))


def test_dat_missing_file_and_empty(tmp_path: Path) -> None:
    with pytest.raises(RealDataError, match="cannot read"):
        read_iso230_dat(tmp_path / "absent.dat")
    with pytest.raises(RealDataError, match="no TGT_DATA"):
        read_iso230_dat(_write(tmp_path, "# nothing\nUNIT=mm\n"))
    with pytest.raises(RealDataError, match="no REF_DATA"):
        read_iso230_dat(_write(tmp_path, "TGT_DATA[1]=0\nTGT_DATA[2]=1\n"))


# -------------------------------------------------------------------------- synthetic log
def _synthetic_log(tmp_path: Path, deviation_um: float = 2.0, lie: bool = False) -> Path:
    """2 positions (0, 10 mm) × 2 cycles of the ecmc sequence; the reference reads 50 − true.

    Forward approaches land ``deviation_um`` high, backward ones as much low.
    """
    lines = ["TARGET_DU:X-PosCmd 2022-04-06 11:00:00.000000 -0.5"]
    lines.append("IOC_TEST:TestNumber 2022-04-06 11:00:00.000000 0")
    t = 10.0

    def emit(pv: str, value: float) -> None:
        nonlocal t
        t += 1.0
        lines.append(f"{pv} 2022-04-06 11:{int(t // 60):02d}:{t % 60:09.6f} {value!r} LOLO MAJOR")

    for cycle in (1, 2):
        sequence = [(1, 1, 0.0), (1, 2, 10.0), (2, 2, 10.0), (2, 1, 0.0)]
        for d, pos, target in sequence:
            if d == 2 and pos == 2:
                emit("TARGET_DU:X-PosCmd", 10.5)
            if d == 1 and pos == 1:
                emit("TARGET_DU:X-PosCmd", -0.5)
            emit("TARGET_DU:X-PosCmd", target)
            sign = 1 if d == 1 else -1
            true = target + sign * deviation_um / 1000
            emit("IOC_TEST:ILD_DownSample", 50.0 - true)
            emit("TARGET_DU:X-PosAct", target + sign * 0.0005)
            number = (3 - d if lie else d) * 1000 + cycle * 100 + pos
            emit("IOC_TEST:TestNumber", number)
    emit("IOC_TEST:TestNumber", 3001)  # another test in the same session: skipped
    return _write(tmp_path, "\n".join(lines) + "\n", "x.log")


def test_log_points_and_run(tmp_path: Path) -> None:
    log = read_camonitor_log(_synthetic_log(tmp_path))
    assert log["IOC_TEST:TestNumber"].time_s[0] == 0.0
    assert log["TARGET_DU:X-PosAct"].alarm[0] == "LOLO MAJOR"
    points = iso230_points_from_log(log)
    assert [p.test_number for p in points] == [1101, 1102, 2102, 2101, 1201, 1202, 2202, 2201]
    assert [p.direction for p in points[:4]] == [1, 1, -1, -1]
    assert points[1].ref_raw == pytest.approx(50.0 - 10.002)
    assert points[1].encoder_mm == pytest.approx(10.0005)
    assert points[1].target_mm == 10.0
    run, (gain, offset) = iso230_run_from_points(points, "synthetic")
    assert gain == pytest.approx(-1.0, abs=1e-6) and offset == pytest.approx(50.0, abs=1e-5)
    r = run.evaluate()
    assert r.mean_fwd_um == pytest.approx([2.0, 2.0], abs=0.01)
    assert r.reversal_um == pytest.approx([4.0, 4.0], abs=0.01)
    assert run.time_fwd_s is not None and np.all(np.diff(np.sort(run.time_fwd_s.ravel())) > 0)


def test_log_direction_disagreeing_with_motion_is_named(tmp_path: Path) -> None:
    log = read_camonitor_log(_synthetic_log(tmp_path, lie=True))
    with pytest.raises(RealDataError, match=r"test number 2101 .* direction -1 .* -0.5 → 0.0 mm"):
        iso230_points_from_log(log)


def test_log_bad_line_and_missing_pv(tmp_path: Path) -> None:
    path = _write(tmp_path, "A:PV 2022-04-06 11:00:00.0 1\nB:PV 2022-04-06\n", "bad.log")
    with pytest.raises(RealDataError, match=r"bad.log:2: expected 'PV date time value"):
        read_camonitor_log(path)
    path = _write(tmp_path, "A:PV 2022-04-06 11:00:00.0 1\n", "one.log")
    with pytest.raises(RealDataError, match=r"PV 'IOC_TEST:TestNumber' not in the log .*A:PV"):
        iso230_points_from_log(read_camonitor_log(path))
    text = "A:PV 2022-04-06 11:00:00.0 1\nA:PV *** disconnected\nA:PV 2022-04-06 11:00:01.5 <undefined> UDF INVALID\n"
    series = read_camonitor_log(_write(tmp_path, text, "disc.log"))["A:PV"]
    assert series.time_s.tolist() == [0.0, 1.5] and np.isnan(series.value[1])
    assert series.alarm[1] == "UDF INVALID" and series.at(1.0)[0] == 1.0
    path = _write(tmp_path, "A:PV 2022-04-06 25:00:00.0 1\n", "time.log")
    with pytest.raises(RealDataError, match=r"time.log: bad date/time"):
        read_camonitor_log(path)


def test_error_table_and_measurements(tmp_path: Path) -> None:
    run = read_iso230_dat(_write(tmp_path, GOOD_DAT))
    name, table = error_table_from_run(run, axis="y")
    assert name == "dy_y"
    assert table["position"] == [0.0, 10.0]
    assert table["value"] == pytest.approx([0.5, 1.5])  # x̄_i = (x̄↑ + x̄↓)/2
    assert table["reversal"] == pytest.approx([1.5, 1.5])  # B_i / 2
    assert run.evaluate().mean_fwd_um == pytest.approx(np.add(table["value"], table["reversal"]))
    assert table["random"] == pytest.approx([2 * np.sqrt(2.0), 2 * np.sqrt(2.0)])
    rows = measurement_rows(run, axis="y")
    assert len(rows) == 8 and "t" not in rows[0]
    assert rows[0] == {
        "x": 0.0,
        "y": 0.0,
        "z": 0.0,
        "ref_x": 0.0,
        "ref_y": 0.001,
        "ref_z": 0.0,
        "dir_y": 1,
        "group": "fwd-c1",
    }
    out = write_measurements_csv(tmp_path / "m.csv", rows)
    with out.open(newline="") as fh:
        back = list(csv.DictReader(fh))
    assert list(back[0])[:6] == ["x", "y", "z", "ref_x", "ref_y", "ref_z"]
    assert float(back[1]["ref_y"]) == 0.003 and back[-1]["dir_y"] == "-1"
    with pytest.raises(ValueError, match="unknown axis 'w'"):
        error_table_from_run(run, axis="w")
    with pytest.raises(ValueError, match="required column"):
        write_measurements_csv(tmp_path / "n.csv", [{"x": 1.0}])
    assert not (tmp_path / "n.csv").exists()
