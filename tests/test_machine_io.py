"""Machine descriptions: docs/formats.md §1 parsing, validation messages, round trips."""

from __future__ import annotations

import re
from pathlib import Path

import numpy as np
import pytest

from cmm_comp.compensation.errors import MachineFileError
from cmm_comp.compensation.machine import Machine

ROOT = Path(__file__).resolve().parents[1]
EXAMPLES = sorted((ROOT / "examples" / "machines").glob("*.toml"))
FORMATS_DOC = ROOT / "docs" / "formats.md"

MINIMAL = """
format = "cmm-machine/1"
name = "tiny"
model = "FB1"
[volume]
x = [0.0, 500.0]
y = [0.0, 400.0]
z = [0.0, 300.0]
reference = [0.0, 0.0, 0.0]
"""


def write(tmp_path: Path, text: str, name: str = "m.toml") -> Path:
    path = tmp_path / name
    path.write_text(text, encoding="utf-8")
    return path


@pytest.mark.parametrize("path", EXAMPLES, ids=lambda p: p.stem)
def test_examples_round_trip_through_to_toml(path: Path, tmp_path: Path) -> None:
    m = Machine.from_toml(path)
    out = tmp_path / "again.toml"
    m.to_toml(out)
    m2 = Machine.from_toml(out)
    rng = np.random.default_rng(0)
    pts = rng.uniform(m.volume.lower_mm, m.volume.upper_mm, (100, 3))
    temps = {"T_x": 23.0, "T_y": 21.0, "T_z": 19.5, "T_wp": 22.0}
    np.testing.assert_array_equal(
        m.volumetric_error(pts, (10, 20, -150), temps),
        m2.volumetric_error(pts, (10, 20, -150), temps),
    )
    assert m.identity_sha256() == m2.identity_sha256()


def test_minimal_machine_has_zero_error(tmp_path: Path) -> None:
    m = Machine.from_toml(write(tmp_path, MINIMAL))
    err = m.volumetric_error(np.array([[100.0, 200.0, 300.0]]), (0, 0, -100))
    np.testing.assert_array_equal(err, 0.0)


def test_iso_aliases_and_our_names_are_the_same_table(tmp_path: Path) -> None:
    ours = MINIMAL + "[errors.ey_x]\nposition = [0.0, 500.0]\nvalue = [0.0, 10.0]\n"
    iso = MINIMAL + "[errors.EBX]\nposition = [0.0, 500.0]\nvalue = [0.0, 10.0]\n"
    a = Machine.from_toml(write(tmp_path, ours, "a.toml"))
    b = Machine.from_toml(write(tmp_path, iso, "b.toml"))
    pts = np.array([[250.0, 100.0, 300.0]])
    np.testing.assert_array_equal(a.volumetric_error(pts), b.volumetric_error(pts))
    # FB1: ΔX = … + z·Ey(x): 300 mm × 5 µrad = 1.5 µm
    assert a.volumetric_error(pts)[0, 0] == pytest.approx(1.5)


def test_polynomial_and_curve_inputs(tmp_path: Path) -> None:
    poly = MINIMAL + "[errors.dx_x]\npolynomial = [1.0, 0.01, -2e-5]\n"
    m = Machine.from_toml(write(tmp_path, poly))
    assert m.volumetric_error(np.array([[200.0, 0, 0]]))[0, 0] == pytest.approx(1 + 2 - 0.8)
    # curve input: a least-squares cubic through a few samples of a known cubic is that cubic
    q = np.array([0.0, 100, 200, 300, 400, 500])
    v = 0.5 + 0.02 * q - 1e-4 * q**2 + 1e-7 * q**3
    curve = (
        MINIMAL
        + f"[errors.dy_y]\ncurve = {{ position = {q.tolist()}, value = {v.tolist()}, order = 3 }}\n"
    )
    m = Machine.from_toml(write(tmp_path, curve, "c.toml"))
    y = 150.0
    assert m.volumetric_error(np.array([[0.0, y, 0]]))[0, 1] == pytest.approx(
        0.5 + 0.02 * y - 1e-4 * y**2 + 1e-7 * y**3, abs=1e-9
    )


def test_csv_file_table(tmp_path: Path) -> None:
    (tmp_path / "dz_z.csv").write_text("position,value,random\n0,0,0.2\n150,2.0,0.2\n300,1.0,0.4\n")
    m = Machine.from_toml(write(tmp_path, MINIMAL + '[errors.dz_z]\nfile = "dz_z.csv"\n'))
    assert m.volumetric_error(np.array([[0, 0, 150.0]]))[0, 2] == pytest.approx(2.0)
    assert m.random_error(np.array([[0, 0, 300.0]]))[0, 2] == pytest.approx(0.4)


def test_spline_interpolates_the_table_exactly_at_nodes(tmp_path: Path) -> None:
    q = [0.0, 100.0, 250.0, 400.0, 500.0]
    v = [0.0, 3.0, -1.0, 2.0, 0.5]
    m = Machine.from_toml(
        write(tmp_path, MINIMAL + f"[errors.dx_x]\nposition = {q}\nvalue = {v}\n")
    )
    got = m.volumetric_error(np.column_stack([q, np.zeros(5), np.zeros(5)]))[:, 0]
    np.testing.assert_allclose(got, v, atol=1e-12)


def test_custom_chain(tmp_path: Path) -> None:
    text = (
        MINIMAL.replace('model = "FB1"', 'model = "custom"')
        + '[chain]\ntool = ["x", "z"]\nworkpiece = ["y"]\n'
    )
    text += "[errors.ez_y]\nposition = [0.0, 400.0]\nvalue = [0.0, 40.0]\n"
    custom = Machine.from_toml(write(tmp_path, text))
    fb1 = Machine.from_toml(
        write(
            tmp_path,
            text.replace('model = "custom"', 'model = "FB1"').split("[chain]")[0]
            + "[errors.ez_y]\nposition = [0.0, 400.0]\nvalue = [0.0, 40.0]\n",
            "fb1.toml",
        )
    )
    pts = np.array([[300.0, 200.0, 100.0]])
    np.testing.assert_allclose(custom.volumetric_error(pts), fb1.volumetric_error(pts))


BAD = [
    ("format = 'cmm-machine/9'\n" + MINIMAL.split("\n", 2)[2], "format", "unsupported format"),
    (MINIMAL.replace('model = "FB1"', 'model = "XX9"'), "model", "unknown model"),
    (MINIMAL.replace("x = [0.0, 500.0]", "x = [500.0, 0.0]"), "volume.x", "greater than lower"),
    (MINIMAL.replace('name = "tiny"', ""), "name", "name is required"),
    (
        MINIMAL + "[errors.dq_x]\nposition = [0.0]\nvalue = [1.0]\n",
        "errors.dq_x",
        "unknown error component",
    ),
    (
        MINIMAL + "[errors.dx_x]\nposition = [0.0, 1.0]\nvalue = [1.0]\n",
        "errors.dx_x",
        "position has 2 values",
    ),
    (
        MINIMAL + "[errors.dx_x]\nposition = [0.0, 0.0]\nvalue = [1.0, 2.0]\n",
        "errors.dx_x.position",
        "increase strictly",
    ),
    (MINIMAL + "[errors.dx_x]\npostion = [0.0]\nvalue = [1.0]\n", "errors.dx_x", "unknown key"),
    (
        MINIMAL + "[errors.dx_x]\nposition = [0.0, 1.0]\nvalue = [1.0, 'a']\n",
        "errors.dx_x.value[1]",
        "'a' must be a number",
    ),
    (
        MINIMAL
        + "[errors.dx_x]\nposition = [0.0, 1.0]\nvalue = [1.0, 2.0]\ncriterion = 'flattest'\n",
        "errors.dx_x.criterion",
        "criterion = 'flattest'; allowed: least_squares, end_points, min_zone",
    ),
    (
        MINIMAL + "[errors.dy_x]\nposition = [0.0, 1.0]\nvalue = [1.0, 2.0]\ncriterion = 'best'\n",
        "errors.dy_x.criterion",
        "criterion = 'best'; allowed: least_squares",
    ),
    (
        MINIMAL + "[errors.dx_x]\npolynomial = [" + ", ".join(["1.0"] * 12) + "]\n",
        "errors.dx_x.polynomial",
        "allowed: 1 to 11 values (order ≤ 10)",
    ),
    (MINIMAL + "[errors.dx_x]\nfile = 'missing.csv'\n", "errors.dx_x.file", "cannot read"),
    (
        MINIMAL
        + "[errors.EXX]\nposition = [0.0]\nvalue = [1.0]\n[errors.dx_x]\nposition = [0.0]\nvalue = [1.0]\n",
        "errors.dx_x",
        "given twice",
    ),
    (
        MINIMAL + "[thermal]\nexpansion = { x = 10.0, w = 3.0 }\n",
        "thermal.expansion",
        "unknown key",
    ),
    (MINIMAL + "[squareness]\nalpha = nan\n", "squareness.alpha", "finite"),
    (MINIMAL + "[volume2]\nx = 1\n", "volume2", "unknown table"),
    (MINIMAL + "[[effects]]\ncause = 'gremlins'\n", "effects[0]", "unknown effect cause"),
    ("name = 'x'\nmodel = 'MB1'\n[volume\n", "", "invalid TOML"),
]


@pytest.mark.parametrize(("text", "where", "problem"), BAD, ids=[b[2] for b in BAD])
def test_bad_files_give_one_clear_error(
    tmp_path: Path, text: str, where: str, problem: str
) -> None:
    path = write(tmp_path, text)
    with pytest.raises(MachineFileError) as info:
        Machine.from_toml(path)
    msg = str(info.value)
    assert info.value.lines == [msg], msg  # one problem: one line
    assert str(path) in msg
    assert where in msg
    assert problem in msg


def test_pose_error_reproduces_volumetric_error_for_any_stylus() -> None:
    m = Machine.from_toml(EXAMPLES[0])
    rng = np.random.default_rng(5)
    pts = rng.uniform(m.volume.lower_mm, m.volume.upper_mm, (50, 3))
    temps = {"T_x": 25.0, "T_wp": 18.0}
    pose = m.pose_error(pts, temps)
    for _ in range(3):
        p = rng.uniform(-200, 200, 3)
        np.testing.assert_allclose(pose.error_um(p), m.volumetric_error(pts, p, temps), atol=1e-9)


def test_reversal_table_follows_the_travel_direction(tmp_path: Path) -> None:
    text = (
        MINIMAL
        + "[errors.dx_x]\nposition = [0.0, 500.0]\nvalue = [1.0, 3.0]\nreversal = [2.0, 4.0]\n"
    )
    m = Machine.from_toml(write(tmp_path, text))
    assert m.runtime_signals()["dir_x"] == 0.0
    pts = np.array([[250.0, 0, 0]] * 3)
    err = m.volumetric_error(pts, inputs={"dir_x": np.array([1.0, -1.0, 0.0])})[:, 0]
    np.testing.assert_allclose(
        err, [2.0 + 3.0, 2.0 - 3.0, 2.0]
    )  # value ± half reversal; unknown → mean
    with pytest.raises(MachineFileError, match="positional tables"):
        Machine.from_toml(write(tmp_path, text.replace("dx_x", "dy_x"), "bad.toml"))


def test_straightness_criterion_removes_the_reference_line(tmp_path: Path) -> None:
    q = [0.0, 100.0, 200.0, 300.0, 400.0, 500.0]
    v = [0.0, 1.0, 3.0, 2.0, 4.0, 5.0]  # a tilted line with a bump
    text = MINIMAL + f"[errors.dy_x]\nposition = {q}\nvalue = {v}\ncriterion = 'least_squares'\n"
    m = Machine.from_toml(write(tmp_path, text))
    resid = m.tables["dy_x"].value
    slope, icpt = np.polyfit(q, v, 1)
    np.testing.assert_allclose(resid, np.array(v) - (slope * np.array(q) + icpt), atol=1e-12)


def test_the_formats_example_loads_with_a_warning_for_its_positional_criterion(
    tmp_path: Path,
) -> None:
    """docs/formats.md §1's own example puts ``criterion`` (straightness only) on dx_x: the file
    loads, the criterion is ignored for that table (a positional error must keep its slope: the
    scale error) and a warning names the key."""
    text = FORMATS_DOC.read_text(encoding="utf-8")
    start = text.index("```toml") + len("```toml")
    example = text[start : text.index("```", start)]
    m = Machine.from_toml(write(tmp_path, example))
    assert m.model == "MB1" and m.name == "npl-bridge"
    assert any("errors.dx_x.criterion" in w and "ignored" in w for w in m.warnings)
    table = m.tables["dx_x"]
    # offset (0, 200, 100) from the reference: MB1 has no angular table here, so only the
    # values given remain, unchanged by any line removal
    np.testing.assert_allclose(table.value, [0.0, 1.2, 2.1])


def test_every_complete_toml_example_of_the_formats_doc_loads(tmp_path: Path) -> None:
    """The user documentation's complete machine examples (```toml blocks with a ``format``
    line) load as written, and there are several of them."""
    import re

    blocks = re.findall(r"```toml\n(.*?)```", FORMATS_DOC.read_text(encoding="utf-8"), re.S)
    complete = [b for b in blocks if 'format = "cmm-machine/1"' in b]
    assert len(complete) >= 4
    for i, body in enumerate(complete):
        m = Machine.from_toml(write(tmp_path, body, f"example{i}.toml"))
        err = m.volumetric_error(np.array([[100.0, 100.0, 100.0]]), m.probe.offset_mm)
        assert np.all(np.isfinite(err)), body


def test_cli_prints_load_warnings(tmp_path: Path) -> None:
    import subprocess
    import sys

    text = (
        MINIMAL
        + "[errors.dx_x]\nposition = [0.0, 500.0]\nvalue = [0.0, 1.0]\ncriterion = 'end_points'\n"
    )
    path = write(tmp_path, text)
    r = subprocess.run(
        [sys.executable, "-m", "cmm_comp.cli", "diagonals", str(path)],
        capture_output=True,
        text=True,
        cwd=ROOT,
        timeout=120,
    )
    assert r.returncode == 0, r.stderr
    assert "warning" in r.stderr and "errors.dx_x.criterion" in r.stderr


def test_the_static_image_example_of_the_formats_doc_loads(tmp_path: Path) -> None:
    """The `[[effects]]` fragment with a static image (§1.9) loads onto a machine and its
    static part is the effect evaluated at the calibration state it names."""
    blocks = re.findall(r"```toml\n(.*?)```", FORMATS_DOC.read_text(encoding="utf-8"), re.S)
    fragment = next(b for b in blocks if "static_image" in b)
    m = Machine.from_toml(write(tmp_path, MINIMAL + fragment, "image.toml"))
    (effect,) = m.effects
    assert effect.cause == "thermal_gradient"
    assert effect.to_table()["static_image"]["signals"] == {"T_top": 21.6, "T_bottom": 20.3}
    pts = np.array([[400.0, 100.0, 100.0]])
    # at the calibration state the dynamic and static parts are both the effect's value there
    at_cal = m.volumetric_error(pts, temps_C={"T_top": 21.6, "T_bottom": 20.3})
    flat = m.volumetric_error(pts, temps_C={"T_top": 20.0, "T_bottom": 20.0})
    assert np.all(np.isfinite(at_cal)) and np.abs(at_cal - flat).max() > 1e-3
