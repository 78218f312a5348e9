"""``cmm-comp export``: every written file read back by an independent reader written from the
format's public documentation (tests/export_readers.py), applied as the control applies it, and
compared with the model: the residual the command reports is the residual measured this way.
Hand-checkable machines give exact table values; bad input gets one error line."""

from __future__ import annotations

import itertools
import json
from pathlib import Path

import numpy as np
import pytest
from export_readers import (
    cec_error_um,
    linuxcnc_error_um,
    read_cec,
    read_linuxcnc,
    read_twincat,
    twincat_axis,
    twincat_error_um,
)

from cmm_comp.compensation import Machine, ParametricErrors
from cmm_comp.compensation.effects import CouplingEffect, ReversalEffect
from cmm_comp.compensation.export import ExportError, ExportOptions, export_tables

ROOT = Path(__file__).resolve().parents[1]
NPL = ROOT / "examples" / "machines" / "npl-bridge.toml"
GOLDEN = ROOT / "tests" / "data" / "export"
FAST = {"points": 21, "eval_steps": (9, 9, 5)}


def _grid(machine: Machine, steps: list[int]) -> np.ndarray:
    axes = [
        np.linspace(machine.volume.lower_mm[k], machine.volume.upper_mm[k], steps[k])
        for k in range(3)
    ]
    return np.stack([m.ravel() for m in np.meshgrid(*axes, indexing="ij")], axis=1)


def _reader_error(
    fmt: str, files: dict[str, str], q: np.ndarray, dirs: np.ndarray, sign: int = 1
) -> np.ndarray:
    if fmt == "sinumerik-cec":
        tables = read_cec(files["NC_CEC.INI"])
        return cec_error_um(tables, ["AX1", "AX2", "AX3"], q, dirs, sign=sign)
    if fmt == "twincat-cnc":
        axes = [twincat_axis(read_twincat(files[f"achskw{n}.lis"])) for n in (1, 2, 3)]
        return twincat_error_um(axes, [1, 2, 3], q, dirs, cross_sign=sign)
    ini = files["linuxcnc-joints.ini"]
    file_type = int(ini.split("COMP_FILE_TYPE = ")[1][0])
    return linuxcnc_error_um(
        [read_linuxcnc(files[f"joint{j}.comp"]) for j in (0, 1, 2)], file_type, q, dirs
    )


def _measured(
    machine: Machine, fmt: str, files: dict[str, str], report: dict, sign: int = 1
) -> dict:
    """Residual statistics of the files, evaluated by the readers over the report's grid and
    every combination of travel directions, against the model at the report's tool; ``sign``
    −1 applies the opposite of the documented sign (CEC values, TwinCAT cross corrections)."""
    q = _grid(machine, report["evaluation"]["grid_steps"])
    dir_axes = ["xyz".index(a) for a in report["evaluation"]["direction_axes"]]
    res = []
    for combo in itertools.product((1.0, -1.0), repeat=len(dir_axes)):
        dirs = np.ones_like(q)
        inputs = {}
        for a, s in zip(dir_axes, combo, strict=True):
            dirs[:, a] = s
            inputs[f"dir_{'xyz'[a]}"] = s
        e = machine.volumetric_error(q, stylus_mm=report["tool_mm"], inputs=inputs)
        res.append(e - _reader_error(fmt, files, q, dirs, sign))
    r = np.concatenate(res)
    norm = np.linalg.norm(r, axis=1)
    return {
        "rms": float(np.sqrt(np.mean(norm**2))),
        "max": float(norm.max()),
        "per_axis": np.sqrt(np.mean(r**2, axis=0)),
    }


def _assert_same_residual(measured: dict, reported: dict) -> None:
    assert measured["rms"] == pytest.approx(reported["rms"], rel=1e-6, abs=2e-6)
    assert measured["max"] == pytest.approx(reported["max"], rel=1e-6, abs=2e-6)
    for k, a in enumerate("xyz"):
        assert measured["per_axis"][k] == pytest.approx(
            reported["per_axis"][a]["rms"], rel=1e-6, abs=2e-6
        )


def _reversal_machine() -> Machine:
    """A bridge from an `extend`-like description: tables plus [[effects]] (reversal on X and Y
    — two direction axes —, a coupling: the roll of Y changing with X)."""
    base = Machine.from_toml(NPL)
    return base.with_effects(
        [
            ReversalEffect("x", [0.8, 0.3], (0.0, 900.0)),
            ReversalEffect("y", [-0.5, 0.0], (0.0, 1150.0)),
            CouplingEffect("ex_y", "x", [2.0, -0.5], (0.0, 1150.0), (0.0, 900.0)),
        ]
    )


@pytest.fixture(scope="module")
def extended_toml(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """The reversal machine written as a file, as `extend` writes one (Machine.to_toml)."""
    path = tmp_path_factory.mktemp("extended") / "extended.toml"
    _reversal_machine().to_toml(path)
    return path


@pytest.mark.parametrize("fmt", ["sinumerik-cec", "twincat-cnc", "linuxcnc"])
def test_reported_residual_is_what_the_control_would_leave(fmt: str, extended_toml: Path) -> None:
    machine = Machine.from_toml(extended_toml)
    assert "[[effects]]" in extended_toml.read_text(encoding="utf-8")
    result = export_tables(machine, fmt, (0.0, 40.0, -150.0), ExportOptions(max_tables=14, **FAST))
    rep = result.report
    assert rep["evaluation"]["direction_axes"] == ["x", "y"]
    measured = _measured(machine, fmt, result.files, rep)
    _assert_same_residual(measured, rep["residual_um"])
    # the tables do work, and the order of formats by what they can carry holds
    assert rep["residual_um"]["rms"] < 0.6 * rep["uncompensated_um"]["rms"]


def test_direction_tables_carry_the_reversal_exactly() -> None:
    """Reversal only (a half step 1.5 µm + 0.4 µm·s along X): every format has direction tables
    on X's own axis, so nothing but rounding remains."""
    machine = Machine.from_parts(model="MB1", volume=((0, 600), (0, 400), (0, 300))).with_effects(
        [ReversalEffect("x", [1.5, 0.4], (0.0, 600.0))]
    )
    for fmt, tol, file_type in (
        ("sinumerik-cec", 0.051, 0),
        ("twincat-cnc", 0.051, 0),
        ("linuxcnc", 1e-3, 0),
        ("linuxcnc", 1e-3, 1),
    ):
        opts = ExportOptions(linuxcnc_file_type=file_type, **FAST)
        result = export_tables(machine, fmt, (0, 0, 0), opts)
        rep = result.report
        measured = _measured(machine, fmt, result.files, rep)
        _assert_same_residual(measured, rep["residual_um"])
        assert rep["uncompensated_um"]["max"] == pytest.approx(1.9, abs=1e-6)
        assert measured["max"] <= tol, fmt


def test_hand_values_positional_and_squareness() -> None:
    """X positional 10 µm/m, squareness α = 20 µrad (ΔY = −α·x): SINUMERIK holds +e in mm (the
    K3 reading: a positive value moves the axis negative), TwinCAT +e in 0.1 µm, LinuxCNC the
    actual position; the values are known by hand."""
    errors = ParametricErrors.from_polynomials({"dx_x": [0.0, 0.01]})
    machine = Machine.from_parts(model="MB1", volume=((0, 400), (0, 300), (0, 200)), errors=errors)
    data = machine.description
    data["squareness"] = {"alpha": 20.0}
    machine = Machine.from_dict(data)
    opts = ExportOptions(points=11, eval_steps=(9, 7, 5), products=False)
    x = np.linspace(0.0, 400.0, 11)
    cec = export_tables(machine, "sinumerik-cec", (0, 0, 0), opts)
    tables = read_cec(cec.files["NC_CEC.INI"])
    by_pair = {(t.params["INPUT_AXIS"], t.params["OUTPUT_AXIS"]): t for t in tables.values()}
    xx = by_pair[("(AX1)", "(AX1)")]
    xy = by_pair[("(AX1)", "(AX2)")]
    got_xx = np.array([xx.values[n] for n in range(11)])
    got_xy = np.array([xy.values[n] for n in range(11)])
    assert np.allclose(got_xx - got_xx[0], 0.01 * x / 1000.0, atol=1e-4 + 1e-12)
    assert np.allclose(got_xy - got_xy[0], -0.02 * x / 1000.0, atol=1e-4 + 1e-12)
    assert cec.report["residual_um"]["max"] < 0.11  # two 0.1 µm roundings at most
    tc = export_tables(machine, "twincat-cnc", (0, 0, 0), opts)
    y_list = twincat_axis(read_twincat(tc.files["achskw2.lis"]))
    assert y_list.master_nr == 1
    assert np.allclose(y_list.cross_val - y_list.cross_val[0], np.round(-0.02 * x * 10), atol=1)
    lc = export_tables(machine, "linuxcnc", (0, 0, 0), opts)
    j0 = read_linuxcnc(lc.files["joint0.comp"])
    assert np.allclose(j0[:, 1] - j0[:, 0] - (j0[0, 1] - j0[0, 0]), 0.01 * x / 1000.0, atol=1e-7)
    # LinuxCNC has no cross table: the squareness is left, all of it (−0.02·x µm on Y)
    xs = np.linspace(0, 400, 9)
    assert lc.report["residual_um"]["per_axis"]["y"]["max"] == pytest.approx(8.0 - 4.0, abs=0.02)
    assert lc.report["residual_um"]["per_axis"]["y"]["rms"] == pytest.approx(
        float(np.sqrt(np.mean((0.02 * (xs - xs.mean())) ** 2))), rel=0.01
    )


def test_products_carry_an_abbe_term_only_when_asked() -> None:
    """Y pitch growing along Y on a bridge with a long stylus: X's error gets ε(y)·(z + p_z),
    a product of two axes. By default no $AN_CEC_MULT_BY_TABLE is written and the term is left;
    with ``products`` it is carried in Siemens' example semantics (read by the passages' reader:
    the referenced table only as the factor), and either reading of the referencing table's own
    value gives the same residual within ``product_rate_own_max_um``."""
    errors = ParametricErrors.from_polynomials({"ey_y": [0.0, 0.05]})
    machine = Machine.from_parts(model="MB1", volume=((0, 500), (0, 600), (0, 400)), errors=errors)
    without = export_tables(
        machine, "sinumerik-cec", (0, 0, -200), ExportOptions(max_tables=20, **FAST)
    )
    with_p = export_tables(
        machine, "sinumerik-cec", (0, 0, -200), ExportOptions(max_tables=20, products=True, **FAST)
    )
    assert all(
        t.params["MULT_BY_TABLE"] == "0" for t in read_cec(without.files["NC_CEC.INI"]).values()
    )
    tables = read_cec(with_p.files["NC_CEC.INI"])
    assert any(t.params["MULT_BY_TABLE"] != "0" for t in tables.values())
    for res in (with_p, without):
        _assert_same_residual(
            _measured(machine, "sinumerik-cec", res.files, res.report), res.report["residual_um"]
        )
    assert with_p.report["residual_um"]["max"] < 0.15
    assert without.report["residual_um"]["max"] > 2.0
    assert with_p.report["residual_without_products_um"]["rms"] == pytest.approx(
        without.report["residual_um"]["rms"], rel=1e-9
    )
    # the other reading of "added as an additional compensation value": no own value
    q = _grid(machine, [9, 9, 5])
    ones = np.ones_like(q)
    both = [
        cec_error_um(tables, ["AX1", "AX2", "AX3"], q, ones, referencing_own=own)
        for own in (True, False)
    ]
    bound = with_p.report["limits"]["product_rate_own_max_um"]
    assert 0 < np.max(np.abs(both[0] - both[1])) <= bound + 1e-9
    assert bound < 1e-3 * with_p.report["uncompensated_um"]["max"]


def test_golden_files_reproduce_and_read_back(tmp_path: Path) -> None:
    """tests/data/export/README.md: the files checked in are what the command writes for the
    golden machine (byte for byte), and they carry its errors as derived there by hand."""
    machine = Machine.from_toml(GOLDEN / "golden-machine.toml")
    opts = ExportOptions(points=11, eval_steps=(9, 7, 5))
    cases = [(fmt, fmt, opts) for fmt in ("sinumerik-cec", "twincat-cnc", "linuxcnc")]
    cases.append(
        (
            "sinumerik-cec",
            "sinumerik-cec-products",
            ExportOptions(products=True, points=11, eval_steps=(9, 7, 5)),
        )
    )
    for fmt, folder, o in cases:
        result = export_tables(machine, fmt, None, o)
        for name, text in result.files.items():
            assert (GOLDEN / folder / name).read_text(encoding="utf-8") == text, (folder, name)
        golden = {p.name: p.read_text(encoding="utf-8") for p in (GOLDEN / folder).iterdir()}
        _assert_same_residual(
            _measured(machine, fmt, golden, result.report), result.report["residual_um"]
        )
    cec = read_cec((GOLDEN / "sinumerik-cec" / "NC_CEC.INI").read_text(encoding="utf-8"))
    plus = np.array([cec[0].values[n] for n in range(11)])
    minus = np.array([cec[1].values[n] for n in range(11)])
    assert (cec[0].params["DIRECTION"], cec[1].params["DIRECTION"]) == ("1", "-1")
    assert np.allclose(plus - minus, 0.001)  # half reversal +0.5 µm after +X, −0.5 after −X
    assert np.allclose(np.diff(plus), 0.0004)  # 10 µm/m over 40 mm steps, as +error
    prod = read_cec((GOLDEN / "sinumerik-cec-products" / "NC_CEC.INI").read_text(encoding="utf-8"))
    (rate_t,) = [t for t in prod if prod[t].params["MULT_BY_TABLE"] != "0"]
    rate, arm = prod[rate_t], prod[int(prod[rate_t].params["MULT_BY_TABLE"]) - 1]
    assert (rate.params["INPUT_AXIS"], arm.params["INPUT_AXIS"]) == ("(AX1)", "(AX2)")
    assert rate.params["OUTPUT_AXIS"] == arm.params["OUTPUT_AXIS"] == "(AX3)"
    # ΔZ = −0.02·x·y·10⁻³ µm; its two-axis part −0.02·(x − 200)·(y − 150)·10⁻³ µm is rate × arm
    r, a = (np.array([t.values[n] for n in range(11)]) for t in (rate, arm))
    assert max(abs(a)) == 1000.0
    assert r[0] * a[0] == pytest.approx(-0.02e-3 * (-200) * (-150) / 1000, rel=1e-4)
    j0 = read_linuxcnc((GOLDEN / "linuxcnc" / "joint0.comp").read_text(encoding="utf-8"))
    assert np.allclose(j0[:, 1] - j0[:, 2], 0.001, atol=2e-7)


def test_reader_is_not_the_writer() -> None:
    """The comparison can fail: a CEC table with one value changed by 1 µm changes the residual
    the reader measures, the direction selection matters, and so does the sign: the tables read
    with the opposite sign (the exporter's earlier −error) leave twice the model's error."""
    machine = Machine.from_toml(GOLDEN / "golden-machine.toml")
    result = export_tables(
        machine, "sinumerik-cec", None, ExportOptions(points=11, eval_steps=(9, 7, 5))
    )
    text = result.files["NC_CEC.INI"].replace("$AN_CEC[0,5]=0.0025", "$AN_CEC[0,5]=0.0035")
    assert text != result.files["NC_CEC.INI"]
    bad = _measured(machine, "sinumerik-cec", {"NC_CEC.INI": text}, result.report)
    assert bad["max"] > result.report["residual_um"]["max"] + 0.5
    swapped = (
        result.files["NC_CEC.INI"]
        .replace("DIRECTION[0]=1", "DIRECTION[0]=-1")
        .replace("DIRECTION[1]=-1", "DIRECTION[1]=1")
    )
    assert _measured(machine, "sinumerik-cec", {"NC_CEC.INI": swapped}, result.report)["max"] > 0.9
    flipped = _measured(machine, "sinumerik-cec", result.files, result.report, sign=-1)
    model = result.report["uncompensated_um"]["rms"]
    assert flipped["rms"] == pytest.approx(2 * model, abs=result.report["residual_um"]["rms"])


def test_invert_sign_writes_the_opposite_reading() -> None:
    """--invert-sign (after a check showing the opposite sign): the CEC values and TwinCAT cross
    corrections are negated; read with the opposite sign they leave the same residual."""
    machine = Machine.from_toml(GOLDEN / "golden-machine.toml")
    for fmt in ("sinumerik-cec", "twincat-cnc"):
        plain = export_tables(machine, fmt, None, ExportOptions(points=11, eval_steps=(9, 7, 5)))
        inv = export_tables(
            machine, fmt, None, ExportOptions(points=11, eval_steps=(9, 7, 5), invert_sign=True)
        )
        _assert_same_residual(
            _measured(machine, fmt, inv.files, inv.report, sign=-1), inv.report["residual_um"]
        )
        assert inv.report["residual_um"]["rms"] == pytest.approx(
            plain.report["residual_um"]["rms"], abs=1e-9
        )
    y_plain = twincat_axis(read_twincat(plain.files["achskw2.lis"]))
    y_inv = twincat_axis(read_twincat(inv.files["achskw2.lis"]))
    assert np.array_equal(y_inv.cross_val, -y_plain.cross_val)
    assert np.array_equal(y_inv.ssfk_plus, y_plain.ssfk_plus)  # the leadscrew sign is verified


def test_limits_and_bad_input() -> None:
    machine = Machine.from_toml(GOLDEN / "golden-machine.toml")
    with pytest.raises(ExportError, match="finite"):
        export_tables(machine, "linuxcnc", (0.0, float("nan"), 0.0))
    with pytest.raises(ExportError, match="outside reason"):
        export_tables(machine, "linuxcnc", (0.0, 0.0, -5000.0))
    with pytest.raises(ExportError, match="at most 200"):
        export_tables(machine, "sinumerik-cec", None, ExportOptions(points=300))
    with pytest.raises(ExportError, match="256"):
        export_tables(machine, "linuxcnc", None, ExportOptions(max_points=300))
    with pytest.raises(ExportError, match="eval-steps"):
        export_tables(machine, "linuxcnc", None, ExportOptions(eval_steps=(1, 5, 5)))
    with pytest.raises(ExportError, match="--format"):
        export_tables(machine, "heidenhain", None)
    with pytest.raises(ExportError, match="axis-names"):
        export_tables(machine, "sinumerik-cec", None, ExportOptions(cec_axis_names=("X1", ")", "")))
    with pytest.raises(ExportError, match=r"distinct integers in 1…"):
        export_tables(machine, "twincat-cnc", None, ExportOptions(twincat_axis_numbers=(0, 1, 2)))
    with pytest.raises(ExportError, match="distinct"):
        export_tables(machine, "linuxcnc", None, ExportOptions(linuxcnc_joints=(0, 0, 1)))
    for bad_sum in (float("nan"), -1.0, float("inf")):
        with pytest.raises(ExportError, match="cec-max-sum-mm"):
            export_tables(
                machine, "sinumerik-cec", None, ExportOptions(cec_max_sum_mm=bad_sum, **FAST)
            )
    with pytest.raises(ExportError, match="max-tables"):
        export_tables(machine, "sinumerik-cec", None, ExportOptions(max_tables=0, **FAST))
    with pytest.raises(ExportError, match="at least 2"):
        export_tables(machine, "twincat-cnc", None, ExportOptions(points=-3))
    # errors beyond the format's value range: a clear error, never a limited table
    big = Machine.from_parts(
        model="MB1",
        volume=((0, 400), (0, 300), (0, 200)),
        errors=ParametricErrors.from_polynomials({"dx_x": [0.0, 5.0]}),  # 2 mm at the far end
    )
    with pytest.raises(ExportError, match=r"CEC_MAX_SUM = 1 mm"):
        export_tables(big, "sinumerik-cec", (0, 0, 0), ExportOptions(**FAST))
    ok = export_tables(big, "sinumerik-cec", (0, 0, 0), ExportOptions(cec_max_sum_mm=3.0, **FAST))
    assert max(ok.report["limits"]["total_compensation_peak_mm"]) > 1.9
    huge = Machine.from_parts(
        model="MB1",
        volume=((0, 400), (0, 300), (0, 200)),
        errors=ParametricErrors.from_polynomials({"dx_x": [0.0, 1.0e6]}),  # 400 m: beyond SGN32
    )
    with pytest.raises(ExportError, match="SGN32"):
        export_tables(huge, "twincat-cnc", (0, 0, 0), ExportOptions(**FAST))


def test_cli_writes_everything_and_refuses_bad_input(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """The command line in process (``cmm_comp.cli.main``: the same code as the entry point)."""
    from cmm_comp.cli.main import main

    golden = str(GOLDEN / "golden-machine.toml")
    out = tmp_path / "cec"
    args = ["export", golden, "--format", "sinumerik-cec", "--points", "11"]
    assert main([*args, "--eval-steps", "9", "7", "5", "-o", str(out)]) == 0
    printed = capsys.readouterr().out
    names = {p.name for p in out.iterdir()}
    assert names == {"NC_CEC.INI", "export.json", "export.png", "export.html"}
    report = json.loads((out / "export.json").read_text(encoding="utf-8"))
    assert f"RMS {report['residual_um']['rms']:.3f} µm" in printed
    assert (out / "export.png").read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    assert "data:image/png;base64," in (out / "export.html").read_text(encoding="utf-8")
    before = {p.name: p.read_bytes() for p in out.iterdir()}
    for bad, message in (
        (["--format", "linuxcnc", "--tool", "0", "nan", "0", "-o", str(tmp_path / "a")], "finite"),
        (["--format", "linuxcnc", "--tool", "0", "0", "inf", "-o", str(tmp_path / "b")], "finite"),
        (["--format", "linuxcnc", "-o", str(out)], "not empty"),
        (
            ["--format", "sinumerik-cec", "--points", "500", "-o", str(tmp_path / "c")],
            "at most 200",
        ),
    ):
        assert main(["export", golden, *bad]) == 2
        err = capsys.readouterr().err.strip().splitlines()
        assert err[-1].startswith("cmm-comp: error: ") and message in err[-1], err
    assert not any((tmp_path / n).exists() for n in ("a", "b", "c"))
    assert {p.name: p.read_bytes() for p in out.iterdir()} == before  # nothing lost


def _cec_text(tables: list[tuple[str, str, list[float], float, float, int]]) -> str:
    """An NC_CEC.INI written by hand: (input, output, values mm, MIN, STEP, MULT_BY_TABLE)."""
    lines = ["%_N_NC_CEC_INI", "CHANDATA(1)"]
    for t, (inp, out, values, lo, step, mult) in enumerate(tables):
        lines += [f"$AN_CEC[{t},{n}]={v!r}" for n, v in enumerate(values)]
        lines += [
            f"$AN_CEC_INPUT_AXIS[{t}]=({inp})",
            f"$AN_CEC_OUTPUT_AXIS[{t}]=({out})",
            f"$AN_CEC_STEP[{t}]={step}",
            f"$AN_CEC_MIN[{t}]={lo}",
            f"$AN_CEC_MAX[{t}]={lo + step * (len(values) - 1)}",
            f"$AN_CEC_DIRECTION[{t}]=0",
            f"$AN_CEC_MULT_BY_TABLE[{t}]={mult}",
            f"$AN_CEC_IS_MODULO[{t}]=0",
        ]
    return "\n".join([*lines, "M17"]) + "\n"


def test_siemens_foundation_sag_example() -> None:
    """K3 p. 252: ΔX1 = Z1·sinβ(X1); table 1 (index 0) X1 → X1 holds sinβ(X1) with
    $AN_CEC_MULT_BY_TABLE[0] = 2, table 2 (index 1) Z1 → X1 holds Z1 (mm, linear). The reader
    (from the passages) gives the example's ΔX1, within the referencing table's own value, and
    not Z1 itself; the writer, given such a machine, writes the same structure."""
    beta_urad = [0.0, 20.0, 50.0, 60.0, 40.0]
    sin_beta = [float(np.sin(b * 1e-6)) for b in beta_urad]
    z_pts = [0.0, 500.0, 1000.0, 1500.0, 2000.0]
    text = _cec_text([("X1", "X1", sin_beta, 0.0, 1000.0, 2), ("Z1", "X1", z_pts, 0.0, 500.0, 0)])
    rng = np.random.default_rng(7)
    q = np.column_stack([rng.uniform(0, 4000, 200), np.zeros(200), rng.uniform(0, 2000, 200)])
    total_mm = cec_error_um(read_cec(text), ["X1", "Y1", "Z1"], q, np.ones_like(q))[:, 0] / 1000
    sin_at_x = np.interp(q[:, 0], [0, 1000, 2000, 3000, 4000], sin_beta)
    example = q[:, 2] * sin_at_x  # ΔX1 = Z1·sinβ(X1), mm
    assert np.max(np.abs(total_mm - example)) <= max(sin_beta) + 1e-12
    assert np.max(np.abs(example)) > 100 * max(sin_beta)  # the product dominates
    # the writer: X's error ε(x)·(z + p_z) from a pitch of the X carriage
    errors = ParametricErrors.from_polynomials({"ey_x": [0.0, 0.0, 1e-4]})
    machine = Machine.from_parts(model="MB1", volume=((0, 800), (0, 500), (0, 400)), errors=errors)
    opts = ExportOptions(products=True, points=21, eval_steps=(9, 9, 5))
    result = export_tables(machine, "sinumerik-cec", (0, 0, -150), opts)
    tables = read_cec(result.files["NC_CEC.INI"])
    (t,) = [i for i in tables if tables[i].params["MULT_BY_TABLE"] != "0"]
    rate, arm = tables[t], tables[int(tables[t].params["MULT_BY_TABLE"]) - 1]
    assert (rate.params["INPUT_AXIS"], rate.params["OUTPUT_AXIS"]) == ("(AX1)", "(AX1)")
    assert (arm.params["INPUT_AXIS"], arm.params["OUTPUT_AXIS"]) == ("(AX3)", "(AX1)")
    arm_values = np.array([arm.values[n] for n in range(len(arm.values))])
    assert np.allclose(np.diff(arm_values), arm_values[1] - arm_values[0], atol=2e-4)  # linear
    _assert_same_residual(
        _measured(machine, "sinumerik-cec", result.files, result.report),
        result.report["residual_um"],
    )
    assert result.report["residual_um"]["rms"] < 0.02 * result.report["uncompensated_um"]["rms"]


def test_check_table_states_what_the_passages_predict(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """`export --check-table`: the check table, read by the passages' reader at the positions the
    instructions name, gives the step they state; the documented sign moves the output axis by
    minus it. The product check's 'this export' line is the reader's total; 'product only' is
    the reader without the referencing table's own value. LinuxCNC has nothing to check."""
    from cmm_comp.cli.main import main

    golden = str(GOLDEN / "golden-machine.toml")
    out = tmp_path / "cec"
    args = ["--check-table", "--products", "-o", str(out)]
    assert main(["export", golden, "--format", "sinumerik-cec", *args]) == 0
    printed = capsys.readouterr().out
    rep = json.loads((out / "check-table.json").read_text(encoding="utf-8"))
    assert (out / "check-table.txt").read_text(encoding="utf-8") in printed
    tables = read_cec((out / "NC_CEC.INI").read_text(encoding="utf-8"))
    assert list(tables) == [0]
    q = np.full((2, 3), 100.0)
    q[:, 1] = [rep["inside_mm"], rep["outside_mm"]]  # input Y, output X (the default)
    taken_um = cec_error_um(tables, ["AX1", "AX2", "AX3"], q, np.ones_like(q))
    # the error the control takes off is the axis' move with the sign reversed
    assert -taken_um[0, 0] / 1000 == pytest.approx(rep["expected_output_move_mm"]["documented"])
    assert rep["expected_output_move_mm"]["documented"] == -0.010
    assert taken_um[1, 0] == 0.0 and np.all(taken_um[:, 1:] == 0.0)
    assert "the tool moved 0.010 mm in -X: the documentation's reading holds" in printed
    assert f"Move Y to {rep['inside_mm']:g} mm" in printed
    prod = read_cec((out / "NC_CEC_PRODUCT.INI").read_text(encoding="utf-8"))
    moves = rep["product_check"]["expected_output_move_mm"]
    (ours,) = [v for name, v in moves.items() if name.startswith("this export")]
    q1 = np.full((1, 3), 50.0)
    for own, expected in ((True, ours), (False, moves["product only (neither table's own value)"])):
        total = cec_error_um(prod, ["AX1", "AX2", "AX3"], q1, np.ones((1, 3)), referencing_own=own)
        assert -total[0, 0] / 1000 == pytest.approx(expected)
        assert f"{expected:+.3f}" in printed
    assert len({round(v, 6) for v in moves.values()}) == len(moves)  # every reading tells apart

    tc = tmp_path / "tc"
    args = ["--check-table", "--check-axes", "x", "z", "-o", str(tc)]
    assert main(["export", golden, "--format", "twincat-cnc", *args]) == 0
    printed = capsys.readouterr().out
    rep = json.loads((tc / "check-table.json").read_text(encoding="utf-8"))
    slave = twincat_axis(read_twincat((tc / "achskw3.lis").read_text(encoding="utf-8")))
    assert slave.master_nr == 1 and not slave.ssfk_plus.any()
    qx = np.zeros((2, 3))
    qx[:, 0] = [rep["inside_mm"], rep["outside_mm"]]
    taken_um = twincat_error_um([slave], [1, 2, 3], qx, np.ones_like(qx))
    assert -taken_um[0, 2] / 1000 == pytest.approx(rep["expected_output_move_mm"]["documented"])
    assert taken_um[1, 2] == 0.0
    assert (
        "Z moved 0.010 mm in -Z" in printed
        and "achs_kw[0]" in (tc / "startup-snippet.txt").read_text()
    )

    assert (
        main(["export", golden, "--format", "linuxcnc", "--check-table", "-o", str(tmp_path / "l")])
        == 2
    )
    err = capsys.readouterr().err.strip().splitlines()
    assert err[-1].startswith("cmm-comp: error: ") and "no unverified sign" in err[-1], err
    assert not (tmp_path / "l").exists()


def _doc_row(flags: str) -> tuple[float, float]:
    """(left RMS, left max) µm of the docs/export.md table row whose flags are ``flags``."""
    text = (ROOT / "docs" / "export.md").read_text(encoding="utf-8")
    (row,) = [ln for ln in text.splitlines() if ln.startswith(f"| `{flags}`")]
    rms, peak = row.split("|")[4].replace("*", "").split("/")
    return float(rms), float(peak)


def test_npl_bridge_figures() -> None:
    """docs/export.md's NPL rows for SINUMERIK (the documented command's defaults), recomputed:
    the reported residual, the same measured by the passages' reader, and the opposite sign
    (the tables as the exporter wrote them before) leaving the 20.55 µm the docs state."""
    machine = Machine.from_toml(NPL)
    docs = (ROOT / "docs" / "export.md").read_text(encoding="utf-8")
    for flags, opts in (
        ("--format sinumerik-cec", ExportOptions()),
        (
            "--format sinumerik-cec --max-tables 24 --products",
            ExportOptions(max_tables=24, products=True),
        ),
    ):
        result = export_tables(machine, "sinumerik-cec", None, opts)
        rep = result.report["residual_um"]
        assert (round(rep["rms"], 3), round(rep["max"], 3)) == _doc_row(flags), flags
        _assert_same_residual(_measured(machine, "sinumerik-cec", result.files, result.report), rep)
        if not opts.products:
            flipped = _measured(machine, "sinumerik-cec", result.files, result.report, sign=-1)
            assert f"{flipped['rms']:.2f} µm RMS ({flipped['max']:.2f} µm max)" in docs
