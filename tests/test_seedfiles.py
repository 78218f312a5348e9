"""Seed-style file sets (paper section 3): round trips, a hand-written set, mixed machines, bad files.

The hand-written set in tests/data/seed_umist was typed by hand from the paper's section 3
description (its README says so); the expected values below are computed by hand.
"""

from __future__ import annotations

import shutil
from pathlib import Path

import numpy as np
import pytest

from cmm_comp.compensation.errors import MachineFileError
from cmm_comp.compensation.formats.seedfiles import (
    find_seed_machines,
    load_seed_fileset,
    write_seed_fileset,
)
from cmm_comp.compensation.machine import Machine

ROOT = Path(__file__).resolve().parents[1]
EXAMPLES = ROOT / "examples" / "machines"
HAND = Path(__file__).resolve().parent / "data" / "seed_umist"


def random_points(machine: Machine, n: int = 60, seed: int = 0) -> np.ndarray:
    rng = np.random.default_rng(seed)
    return rng.uniform(machine.volume.lower_mm, machine.volume.upper_mm, (n, 3))


@pytest.mark.parametrize("example", ["npl-bridge", "gec-mh2"])
def test_round_trip_of_the_example_machines(example: str, tmp_path: Path) -> None:
    machine = Machine.from_toml(EXAMPLES / f"{example}.toml")
    written = write_seed_fileset(machine, tmp_path, "EX1")
    assert all(p.parent == tmp_path and p.name.startswith("EX1") for p in written)
    loaded = load_seed_fileset(tmp_path, "ex1")
    assert loaded.name == machine.name and loaded.model == machine.model
    pts = random_points(machine)
    stylus = (10.0, -20.0, -120.0)
    temps = {"T_x": 21.5, "T_y": 19.0, "T_z": 22.0, "T_wp": 23.0}
    np.testing.assert_array_equal(
        loaded.volumetric_error(pts, stylus, temps), machine.volumetric_error(pts, stylus, temps)
    )
    np.testing.assert_array_equal(
        loaded.random_error(pts, stylus), machine.random_error(pts, stylus)
    )


def test_round_trip_keeps_offsets_criteria_polynomials_and_bands(tmp_path: Path) -> None:
    data = {
        "name": "offsets demo",
        "model": "FB2",
        "volume": {"x": [0.0, 600.0], "y": [0.0, 500.0], "z": [0.0, 400.0], "steps": [7, 6, 5]},
        "probe": {"offset": [0.0, 0.0, -80.0], "random_um": 0.3},
        "squareness": {"alpha": 4.0, "beta1": 2.0, "beta2": -1.0, "offset": [300.0, 250.0, 0.0]},
        "errors": {
            "ez_x": {"position": [0.0, 300.0, 600.0], "value": [0.0, 4.0, 3.0]},
            "ey_x": {"polynomial": [0.0, 0.01, -1e-5], "random_band": 0.5},
            "dx_x": {
                "position": [0.0, 200.0, 400.0, 600.0],
                "value": [0.0, 1.0, 1.5, 1.2],
                "random": [0.1, 0.2, 0.2, 0.3],
                "offset": [0.0, 250.0, 200.0],
            },
            "dz_x": {
                "position": [0.0, 150.0, 300.0, 450.0, 600.0],
                "value": [0.0, 0.4, 0.9, 0.3, 0.2],
                "offset": [0.0, 300.0, 0.0],
                "criterion": "min_zone",
            },
        },
    }
    machine = Machine.from_dict(data)
    write_seed_fileset(machine, tmp_path, "OFS")
    text = (tmp_path / "OFSS.DZX").read_text()
    assert "OFFSET 0.0 300.0 0.0" in text and "CRITERION min_zone" in text
    loaded = load_seed_fileset(tmp_path, "OFS")
    pts = random_points(machine, seed=3)
    np.testing.assert_array_equal(loaded.volumetric_error(pts), machine.volumetric_error(pts))
    np.testing.assert_array_equal(loaded.random_error(pts), machine.random_error(pts))
    np.testing.assert_array_equal(loaded.squareness_urad, machine.squareness_urad)


def test_hand_written_file_set() -> None:
    """Expected values by hand (tests/data/seed_umist/README.md, MB1, A.1 first order)."""
    m = load_seed_fileset(HAND, "UMIST1")
    assert (m.name, m.model) == ("umist-demo bridge", "MB1")
    np.testing.assert_array_equal(m.volume.upper_mm, [400.0, 300.0, 200.0])
    assert m.volume.steps == (5, 4, 3)
    np.testing.assert_array_equal(m.probe.offset_mm, [0.0, 0.0, -50.0])
    np.testing.assert_array_equal(m.squareness_urad, [10.0, -4.0, 0.0])
    np.testing.assert_array_equal(m.squareness_random_urad, [1.0, 0.0, 0.0])
    np.testing.assert_array_equal(m.thermal.expansion, [11.5, 0.0, 0.0])
    assert sorted(m.tables) == ["dx_x", "dy_x", "ex_x", "ez_y"]
    # dy_x measured at z = 100 mm: + 0.1 m · ex_x(x) with ex_x = 1e-5·x² µrad, then end points:
    # 0.01, 0.04, 0.09, 0.16 µm added, the chord 0.0004·x removed → −0.03, −0.04, −0.03
    np.testing.assert_allclose(m.tables["dy_x"].value, [0.0, 0.47, 0.76, 0.47, 0.0], atol=1e-12)
    # at (200, 150, 100) mm, stylus 0: ΔX = δx(x) + z(−β1) = 2 + 0.1·4;
    # ΔY = δy(x) + x(−α + Ez(y)) − z·Ex(x) = 0.76 + 0.2·(−10 + 3) − 0.1·0.4; ΔZ = 0
    err = m.volumetric_error([[200.0, 150.0, 100.0]], stylus_mm=(0, 0, 0))
    np.testing.assert_allclose(err, [[2.4, -0.68, 0.0]], atol=1e-4)
    # random: X band 0.6 ⊕ probe 0.4; Y: δy(x) 0.3 ⊕ x·Rα = 0.2 ⊕ 0.4; Z: probe 0.4
    rnd = m.random_error([[200.0, 150.0, 100.0]], stylus_mm=(0, 0, 0))
    np.testing.assert_allclose(
        rnd, [[np.hypot(0.6, 0.4), np.sqrt(0.09 + 0.04 + 0.16), 0.4]], rtol=1e-12
    )
    # X scale at 22 °C: 11.5 µm/(m·°C) · 2 °C · 0.2 m
    hot = m.volumetric_error([[200.0, 150.0, 100.0]], (0, 0, 0), temps_C={"T_x": 22.0})
    np.testing.assert_allclose(hot - err, [[4.6, 0.0, 0.0]], atol=1e-12)


def test_mixed_machines_in_one_directory(tmp_path: Path) -> None:
    assert find_seed_machines(HAND) == ["LAB2", "UMIST1"]
    lab = load_seed_fileset(HAND, "lab2")
    assert lab.model == "FB1" and lab.name == "LAB2"
    np.testing.assert_allclose(lab.volumetric_error([[0.0, 250.0, 0.0]]), [[0.0, 2.5, 0.0]])
    npl = Machine.from_toml(EXAMPLES / "npl-bridge.toml")
    gec = Machine.from_toml(EXAMPLES / "gec-mh2.toml")
    write_seed_fileset(npl, tmp_path, "NPL")
    write_seed_fileset(gec, tmp_path, "GEC")
    write_seed_fileset(gec, tmp_path, "NPLX")  # a name that extends another
    assert find_seed_machines(tmp_path) == ["GEC", "NPL", "NPLX"]
    pts = random_points(npl, seed=2)
    np.testing.assert_array_equal(
        load_seed_fileset(tmp_path, "NPL").volumetric_error(pts), npl.volumetric_error(pts)
    )
    assert load_seed_fileset(tmp_path, "GEC").model == "MH2"
    # rewriting a machine removes its own stale files and no one else's
    write_seed_fileset(gec, tmp_path, "NPL")
    assert not (tmp_path / "NPLS.DXY").exists() and (tmp_path / "NPLXS.CTL").exists()
    assert load_seed_fileset(tmp_path, "NPL").model == "MH2"


def test_write_refuses_a_bad_spec_name(tmp_path: Path) -> None:
    machine = Machine.from_toml(EXAMPLES / "npl-bridge.toml")
    for bad in ("TOOLONG8", "NPL-1", ""):
        with pytest.raises(ValueError, match="1–7 letters or digits"):
            write_seed_fileset(machine, tmp_path, bad)
    assert list(tmp_path.iterdir()) == []


@pytest.mark.parametrize(
    ("fname", "content", "match"),
    [
        ("UMIST1S.DPX", "0 0\n100 abc\n", r"UMIST1S.DPX: line 2: expected a number, got 'abc'"),
        ("UMIST1S.DPX", "0 0\n100 1\n100 2\n", r"UMIST1S.DPX: line 3: positions must increase"),
        ("UMIST1S.DPX", "0 0 0\n", r"UMIST1S.DPX: line 1: expected 'position value', got 3"),
        ("UMIST1S.DPX", "# c\nTYPE FB2\n0 0\n", r"UMIST1S.DPX: line 2: machine type 'FB2' differs"),
        ("UMIST1S.DPX", "MACHINE OTHER\n0 0\n", r"UMIST1S.DPX: line 1: .*'OTHER' differs"),
        ("UMIST1S.DPX", "SPEED 3\n0 0\n", r"UMIST1S.DPX: line 1: unknown keyword 'SPEED'"),
        ("UMIST1S.DPX", "0 0\nOFFSET 0 0 1\n", r"UMIST1S.DPX: line 2: keyword OFFSET after"),
        ("UMIST1S.DPX", "OFFSET 0 1\n0 0\n", r"UMIST1S.DPX: line 1: OFFSET needs 3 numbers"),
        ("UMIST1S.DPX", "CRITERION min_zone\n0 0\n", r"line 1: a straightness criterion"),
        ("UMIST1S.DYX", "CRITERION best\n0 0\n1 1\n", r"UMIST1S.DYX: line 1: unknown criterion"),
        ("UMIST1S.DPX", "# nothing\n", r"UMIST1S.DPX: no data rows"),
        ("UMIST1R.DYX", "0 0.2\n100 0.2\n", r"UMIST1R.DYX: line 1: positions differ"),
        ("UMIST1R.DYX", "0 0.2\n100 -0.2\n200 0\n300 0\n400 0\n", r"line 2: a random part"),
        ("UMIST1R.dpx", "BAND -1\n", r"UMIST1R.dpx: line 1: a random band must be ≥ 0"),
        ("UMIST1S.ALP", "1.0\n2.0\n", r"UMIST1S.ALP: line 2: expected exactly one value"),
        ("UMIST1S.THX", "VALUE warm\n", r"UMIST1S.THX: line 1: expected a number"),
        ("UMIST1S.EZY", "UNIT um\n0 0\n1 1\n", r"UMIST1S.EZY: line 1: unit 'um': this file holds"),
        ("UMIST1S.CTL", "TYPE XX9\nINITIAL 0 0 0\nFINAL 1 1 1\n", r"line 1: machine type 'XX9'"),
        ("UMIST1S.CTL", "TYPE MB1\nINITIAL 0 0 0\n", r"UMIST1S.CTL: give FINAL"),
        ("UMIST1S.CTL", "TYPE MB1\nINITIAL 0 0 0\nFINAL 1 1 0\n", r"volume.z.*upper"),
        ("UMIST1S.DPX", b"0 0\n\xff\xfe 1\n", r"UMIST1S.DPX: not an ASCII/UTF-8 text file"),
    ],
)
def test_bad_files_name_the_file_line_and_problem(
    fname: str, content: str | bytes, match: str, tmp_path: Path
) -> None:
    shutil.copytree(HAND, tmp_path, dirs_exist_ok=True)
    data = content if isinstance(content, bytes) else content.encode()
    (tmp_path / fname).write_bytes(data)
    with pytest.raises(MachineFileError, match=match):
        load_seed_fileset(tmp_path, "UMIST1")


def test_missing_machine_lists_the_ones_present() -> None:
    with pytest.raises(MachineFileError, match=r"no master control file for NOPE; .*LAB2, UMIST1"):
        load_seed_fileset(HAND, "NOPE")
    with pytest.raises(MachineFileError, match="1–7 letters/digits"):
        load_seed_fileset(HAND, "UMIST1S.CTL")


def test_squareness_files_with_their_own_offsets(tmp_path: Path) -> None:
    """Each squareness file carries its own measurement offset (section 3.3): each is referred
    to the reference point as if it had been given alone with that offset in machine.toml."""
    shutil.copytree(HAND, tmp_path, dirs_exist_ok=True)
    (tmp_path / "UMIST1S.ALP").write_text("OFFSET 0 0 150\nVALUE 10\n")
    (tmp_path / "UMIST1S.BT2").write_text("OFFSET 300 0 0\nVALUE 2\n")
    got = load_seed_fileset(tmp_path, "UMIST1").squareness_urad
    ref = load_seed_fileset(HAND, "UMIST1")
    data = ref.description | {"squareness": {"alpha": 10.0, "offset": [0.0, 0.0, 150.0]}}
    alone_alpha = Machine.from_dict(data).squareness_urad[0]
    data = ref.description | {"squareness": {"beta2": 2.0, "offset": [300.0, 0.0, 0.0]}}
    alone_beta2 = Machine.from_dict(data).squareness_urad[2]
    np.testing.assert_allclose(got, [alone_alpha, -4.0, alone_beta2], atol=1e-12)
    assert alone_alpha != 10.0  # the offset mattered (roll of X with a Z arm)
