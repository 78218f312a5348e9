"""Bad values on internal paths: numbers that are valid input but overflow or turn non-finite
inside a computation, and values that pass a check yet corrupt what is written. Each case gets
one clear error (never a NaN/inf figure reported as a result, never a corrupted file), and JSON
the project writes parses without the non-standard NaN/Infinity tokens."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from cmm_comp.compensation import Machine, ParametricErrors
from cmm_comp.compensation.export import ExportError, ExportOptions, export_tables

ROOT = Path(__file__).resolve().parents[1]
GOLDEN = ROOT / "tests" / "data" / "export" / "golden-machine.toml"
FAST = {"points": 11, "eval_steps": (5, 5, 3)}
FAST_STEPS = {"eval_steps": (5, 5, 3)}


def _strict_json(text: str) -> object:
    def refuse(token: str) -> object:
        raise AssertionError(f"non-standard JSON token {token}")

    return json.loads(text, parse_constant=refuse)


def _machine_dx(values: list[float]) -> Machine:
    """X positional error tabulated at x = 0, 200, 400 mm (µm)."""
    return Machine.from_parts(
        model="MB1",
        volume=((0, 400), (0, 300), (0, 200)),
        errors=ParametricErrors.from_tables({"dx_x": ([0.0, 200.0, 400.0], values)}),
    )


@pytest.fixture
def unchecked(monkeypatch: pytest.MonkeyPatch) -> None:
    """Machines built without the description's magnitude check (Machine.from_dict): the
    internal guards behind it (export, reports) are tested on what it would refuse."""
    import cmm_comp.compensation.machine as machine_module

    monkeypatch.setattr(machine_module, "_check_magnitudes", lambda machine: None)


# ---------------------------------------------------------------- machine description
@pytest.mark.parametrize(
    ("errors", "message"),
    [
        ({"dx_x": ([0.0, 200.0, 400.0], [0.0, 1e300, 0.0])}, r"errors\.dx_x: value reaches"),
        # 2π·1e6 µrad is a whole turn: sin/cos gave a plausible, wrong error of a few µm
        ({"ey_y": ([0.0, 150.0, 300.0], [0.0, 6283185.307, 0.0])}, r"errors\.ey_y: value reaches"),
        ({"dx_x": ([0.0, 400.0], [0.0, 2e9])}, r"beyond ±1e\+09 um"),
    ],
)
def test_machine_refuses_errors_beyond_any_machine(errors: dict, message: str) -> None:
    with pytest.raises(ValueError, match=message):
        Machine.from_parts(
            model="MB1",
            volume=((0, 400), (0, 300), (0, 200)),
            errors=ParametricErrors.from_tables(errors),
        )


def test_machine_refuses_a_random_band_or_squareness_beyond_any_machine(tmp_path: Path) -> None:
    """A 2σ band of 1e300 µm made the uncertainty's U inf (written into its JSON)."""
    text = GOLDEN.read_text(encoding="utf-8")
    bad_random = tmp_path / "random.toml"
    bad_random.write_text(
        text.replace("reversal = [0.5", "random = [0.0, 1e300, 0.0, 0.0, 0.0]\nreversal = [0.5"),
        encoding="utf-8",
    )
    with pytest.raises(ValueError, match=r"errors\.dx_x: random reaches"):
        Machine.from_toml(bad_random)
    bad_square = tmp_path / "square.toml"
    bad_square.write_text(text.replace("alpha = 20.0", "alpha = 2e6"), encoding="utf-8")
    with pytest.raises(ValueError, match="squareness"):
        Machine.from_toml(bad_square)
    # the limits themselves are machines: 1 km and 1 rad load (by hand: 4e8 µm at x = 400 mm)
    Machine.from_parts(
        model="MB1",
        volume=((0, 400), (0, 300), (0, 200)),
        errors=ParametricErrors.from_polynomials({"dx_x": [0.0, 1e6], "ez_x": [9e5]}),
    )


# ---------------------------------------------------------------- export
@pytest.mark.usefixtures("unchecked")
@pytest.mark.parametrize("fmt", ["sinumerik-cec", "linuxcnc"])
def test_export_refuses_an_error_whose_statistics_overflow(fmt: str) -> None:
    """1e300 µm is finite, its square is not: the RMS was reported as inf/NaN (exit 0, garbage
    controller files); now one error naming the cause."""
    machine = _machine_dx([0.0, 1e300, 0.0])
    with pytest.raises(ExportError, match="not a finite number"):
        export_tables(machine, fmt, (0, 0, 0), ExportOptions(cec_max_sum_mm=1e308, **FAST))


@pytest.mark.usefixtures("unchecked")
def test_export_refuses_tables_the_control_cannot_hold() -> None:
    """LinuxCNC's trims are single precision: 4e146 mm becomes inf in the control's arithmetic,
    the residual NaN (was printed as 'RMS nan µm', exit 0)."""
    machine = Machine.from_parts(
        model="MB1",
        volume=((0, 400), (0, 300), (0, 200)),
        errors=ParametricErrors.from_polynomials({"dx_x": [0.0, 1e150]}),
    )
    with pytest.raises(ExportError, match=r"residual .* not a finite number"):
        export_tables(machine, "linuxcnc", (0, 0, 0), ExportOptions(**FAST))


def test_export_large_but_representable_error_is_reported_finite() -> None:
    """400 m at the far end is absurd but a machine by the description's limits: the report
    is finite and strict JSON."""
    from cmm_comp.compensation.export.report import report_json

    machine = Machine.from_parts(
        model="MB1",
        volume=((0, 400), (0, 300), (0, 200)),
        errors=ParametricErrors.from_polynomials({"dx_x": [0.0, 1e6]}),
    )
    result = export_tables(machine, "linuxcnc", (0, 0, 0), ExportOptions(**FAST))
    report = _strict_json(report_json(result))
    assert isinstance(report, dict)
    # the model's max is at x = 400 mm: 400 · 1e6 µm, worked out by hand
    assert report["uncompensated_um"]["max"] == pytest.approx(4e8, rel=1e-9)


def test_cli_export_of_an_absurd_table_is_one_line_and_writes_nothing(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    from cmm_comp.cli.main import main

    src = tmp_path / "big.toml"
    src.write_text(
        GOLDEN.read_text(encoding="utf-8").replace(
            "value = [0.0, 1.0, 2.0, 3.0, 4.0]", "value = [0.0, 1.0, 1e300, 3.0, 4.0]"
        ),
        encoding="utf-8",
    )
    out = tmp_path / "out"
    args = ["export", str(src), "--format", "linuxcnc", "--points", "11"]
    assert main([*args, "--eval-steps", "5", "5", "3", "-o", str(out)]) == 2
    err = capsys.readouterr().err
    assert "Warning" not in err, err
    lines = err.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("cmm-comp: error: ")
    assert "errors.dx_x: value reaches" in lines[0]
    assert not out.exists()


@pytest.mark.parametrize("fmt", ["sinumerik-cec", "twincat-cnc"])
def test_export_axis_name_with_a_trailing_newline_is_refused(fmt: str) -> None:
    """``re.match(r'^…$')`` accepts 'AX1\\n' ($ matches before a final newline): the name
    was written into the controller file, splitting '$AN_CEC_INPUT_AXIS[0]=(AX1' from ')'."""
    machine = Machine.from_toml(GOLDEN)
    names = ("AX1\n", "AX2", "AX3")
    opts = ExportOptions(cec_axis_names=names, twincat_axis_names=names, **FAST)
    with pytest.raises(ExportError, match="axis-names"):
        export_tables(machine, fmt, None, opts)


def test_export_points_beyond_what_the_fit_can_hold_are_refused_at_once() -> None:
    """--max-points lifts the format's default without a bound: --points 100000 ran the fit out
    of memory (the process was killed); now refused before any work."""
    machine = Machine.from_toml(GOLDEN)
    with pytest.raises(ExportError, match="at most 5000"):
        export_tables(machine, "twincat-cnc", None, ExportOptions(points=100_000, max_points=10**9))


def test_binned_statistics_of_a_quantised_variable_has_no_empty_bins() -> None:
    """A temperature read in 0.1 °C steps has three levels: its equal-count bin edges repeat and
    five of eight bins were empty, listed with NaN centre and means (NaN tokens in the report's
    diagnosis.json). Now only bins with points, and they add up to the data."""
    from cmm_comp.compensation.diagnosis.residuals import binned_statistics

    x = np.array([20.0] * 50 + [20.1] * 40 + [20.2] * 10)
    r = np.zeros((100, 3))
    r[:, 0] = 1.0
    r[:, 1] = (x - 20.0) * 10.0  # 0, 1, 2 µm
    stats = binned_statistics(x, r)
    _strict_json(json.dumps(stats))
    counts = np.asarray(stats["count"])
    assert counts.sum() == 100 and np.all(counts > 0)
    # weighted sums over the bins equal the sums over the data, worked out by hand
    assert float(np.dot(counts, stats["centre"])) == pytest.approx(
        50 * 20.0 + 40 * 20.1 + 10 * 20.2
    )
    assert float(np.dot(counts, stats["mean_x_um"])) == pytest.approx(100.0)
    assert float(np.dot(counts, stats["mean_y_um"])) == pytest.approx(40 * 1.0 + 10 * 2.0)


# ---------------------------------------------------------------- model reports (map, diagonals, line)
BIG_TOML = """format = "cmm-machine/1"
name = "big"
model = "MB1"
[volume]
x = [0.0, 400.0]
y = [0.0, 300.0]
z = [0.0, 200.0]
[errors.dx_x]
position = [0.0, 200.0, 400.0]
value = [0.0, 1e300, 0.0]
"""


@pytest.mark.usefixtures("unchecked")
def test_reports_refuse_a_model_error_beyond_any_machine() -> None:
    """A table value of 1e300 µm: the diagonals' lengths and the line's resultant overflowed and
    were printed (and written to JSON) as inf; now one error naming the point."""
    from cmm_comp.compensation.reports.maps import diagonals_um, line_report, volumetric_map

    big = _machine_dx([0.0, 1e300, 0.0])
    for run in (
        lambda: diagonals_um(big),
        lambda: line_report(big, "x", (0.0, 0.0, 0.0)),
        lambda: volumetric_map(big, (3, 3, 3)),
    ):
        with pytest.raises(ValueError, match="not a finite error"):
            run()
    machine = Machine.from_toml(GOLDEN)
    with pytest.raises(ValueError, match="finite"):
        line_report(machine, "x", (0.0, float("nan"), 0.0))
    with pytest.raises(ValueError, match="stylus"):
        diagonals_um(machine, (float("nan"), 0.0, 0.0))


def test_cli_model_commands_refuse_non_finite_inputs_and_write_nothing(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    from cmm_comp.cli.main import main

    npl = str(ROOT / "examples" / "machines" / "npl-bridge.toml")
    big = tmp_path / "big.toml"
    big.write_text(BIG_TOML, encoding="utf-8")
    for argv, message, written in (
        (
            ["diagonals", str(big), "--json", str(tmp_path / "d.json")],
            "value reaches",
            "d.json",
        ),
        (
            ["report", str(big), "--steps", "3", "3", "3", "--out", str(tmp_path / "r")],
            "value reaches",
            "r",
        ),
        (
            ["line", npl, "--axis", "x", "--through", "0", "0", "0", "--temp-x", "nan"],
            "--temp-x",
            "",
        ),
        (
            ["line", npl, "--axis", "x", "--through", "0", "0", "0", "--temp-x", "1e300"],
            "--temp-x",
            "",
        ),
    ):
        assert main(argv) == 2, argv
        captured = capsys.readouterr()
        err = captured.err.strip().splitlines()
        assert len(err) == 1 and err[0].startswith("cmm-comp: error: ") and message in err[0], err
        assert "inf" not in captured.out and "nan" not in captured.out
        if written:
            assert not (tmp_path / written).exists()


def test_write_json_atomic_refuses_nan_and_keeps_the_previous_file(tmp_path: Path) -> None:
    from cmm_comp.cli.common import write_json_atomic

    path = tmp_path / "summary.json"
    path.write_text('{"ok": 1}\n', encoding="utf-8")
    with pytest.raises(ValueError, match="not a finite number"):
        write_json_atomic(path, {"rms_um": float("nan")})
    assert path.read_text(encoding="utf-8") == '{"ok": 1}\n'
    write_json_atomic(path, {"rms_um": 1.5})
    assert _strict_json(path.read_text(encoding="utf-8")) == {"rms_um": 1.5}


def test_iso230_refuses_a_deviation_whose_statistics_overflow() -> None:
    """One reading of 1e200 mm: s↑, R and A were printed as inf and E as a 200-digit number
    (exit 0); now one error naming the reading. A large but representable deviation is
    evaluated: worked by hand, x̄↑ at the 2nd target = (1000 + 0) / 2 µm."""
    from cmm_comp.compensation.reports.iso230 import evaluate_iso230

    target = [0.0, 10.0]
    bwd = [[0.0, 0.0], [10.0, 10.0]]
    with pytest.raises(ValueError, match=r"1e\+200 mm at target 10 mm \(position 2, cycle 1\)"):
        evaluate_iso230(target, [[0.0, 0.0], [1e200, 10.0]], bwd)
    result = evaluate_iso230(target, [[0.0, 0.0], [11.0, 10.0]], bwd)
    assert result.mean_fwd_um[1] == pytest.approx(500.0)
    assert np.isfinite(result.A_um) and np.isfinite(result.R_um)


def test_residuals_refuse_a_reading_whose_error_overflows() -> None:
    """A reference read as 1e200 mm (finite, so the reader takes it): every RMS of the diagnosis
    was inf and diagnosis.json held NaN (exit 0); now one error naming the row. Ordinary rows
    give the residual worked out by hand: the golden machine's X error at x = 100 mm (stylus
    and y, z at 0) is 1 µm, so a reference 3 µm long leaves 2 µm."""
    from cmm_comp.compensation.diagnosis.residuals import compute_residuals
    from cmm_comp.compensation.formats.measurements import measurements_from_columns

    machine = Machine.from_parts(
        model="MB1",
        volume=((0, 400), (0, 300), (0, 200)),
        errors=ParametricErrors.from_tables({"dx_x": ([0.0, 200.0, 400.0], [0.0, 2.0, 4.0])}),
    )
    cols = {
        "x": np.array([100.0, 200.0]),
        "y": np.zeros(2),
        "z": np.zeros(2),
        "ref_x": np.array([100.003, 1e200]),
        "ref_y": np.zeros(2),
        "ref_z": np.zeros(2),
    }
    with pytest.raises(ValueError, match="data row 2"):
        compute_residuals(machine, measurements_from_columns(cols))
    cols["ref_x"] = np.array([100.003, 200.002])
    res = compute_residuals(machine, measurements_from_columns(cols))
    assert res.residual_um[:, 0] == pytest.approx([2.0, 0.0], abs=1e-6)


def test_export_travel_too_short_for_the_points_is_named() -> None:
    """An X travel of 1.5 µm (15 steps of the 0.1 µm position resolution) and the default 11
    points: the step rounds up to 0.2 µm, the last points lie beyond the travel with nothing to
    fit, and the fit failed with 'Matrix is not positive definite' after a MatrixRankWarning (a
    travel of 1e-300 mm: 'array must not contain infs or NaNs'). Now one error with a count that
    fits, worked out by hand: 9 points 0.2 µm apart, the 8th at 1.4 µm < 1.5 µm."""

    def machine(x_mm: float) -> Machine:
        return Machine.from_parts(
            model="MB1", volume=((0, x_mm), (0, 300), (0, 200)), probe=(0, 0, 0)
        )

    short = machine(0.0015)
    with pytest.raises(ExportError, match=r"X travel of 0.0015 mm .* e\.g\. 9$"):
        export_tables(short, "sinumerik-cec", None, ExportOptions(eval_steps=(5, 5, 3)))
    export_tables(short, "sinumerik-cec", None, ExportOptions(points=9, eval_steps=(5, 5, 3)))
    with pytest.raises(ExportError, match="shorter than that resolution"):
        export_tables(machine(1e-300), "linuxcnc", None, ExportOptions(points=2, **FAST_STEPS))


def test_machine_refuses_a_volume_beyond_any_machine() -> None:
    """x = [0, 1e300] mm loaded; its diagonals and map then failed on 'the error tables' (the
    squareness times 1e300 mm), not on the volume. Now the volume is named at load."""
    with pytest.raises(
        ValueError, match=r"volume\.x\[1\] = 1e\+300; allowed: -1e\+06 \.\. 1e\+06 mm"
    ):
        Machine.from_parts(model="MB1", volume=((0, 1e300), (0, 300), (0, 200)))
    Machine.from_parts(model="MB1", volume=((-1e6, 1e6), (0, 300), (0, 200)))  # 2 km: loads


def test_uncertainty_input_beyond_any_machine_is_refused_at_load(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """[uncertainty] probe_um = 1e300 (finite, ≥ 0: accepted) squared to inf in the covariance:
    `cmm-comp uncertainty` ended in a traceback (OverflowError). Now refused at load."""
    from cmm_comp.cli.main import main

    src = tmp_path / "u.toml"
    src.write_text(
        GOLDEN.read_text(encoding="utf-8") + "\n[uncertainty]\nprobe_um = 1e300\n", encoding="utf-8"
    )
    with pytest.raises(
        ValueError, match=r"uncertainty\.probe_um = 1e\+300; allowed: 0 \.\. 1e\+09"
    ):
        Machine.from_toml(src)
    points = tmp_path / "p.csv"
    points.write_text("x,y,z\n100,100,100\n", encoding="utf-8")
    out = tmp_path / "u.json"
    argv = ["uncertainty", str(src), "--points", str(points), "--trials", "50", "--json", str(out)]
    assert main(argv) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith("cmm-comp: error: ") and "probe_um" in err[0]
    assert not out.exists()


@pytest.mark.parametrize(
    ("old", "new", "message"),
    [
        # a 2σ probing band of 1e300 µm: report and uncertainty ended in an OverflowError
        (
            "offset = [0.0, 0.0, -100.0]",
            "offset = [0.0, 0.0, -100.0]\nrandom_um = 1e300",
            "probe.random_um",
        ),
        # a stylus of 1e300 mm: grid build wrote corrections of 1e297 µm without a word
        ("offset = [0.0, 0.0, -100.0]", "offset = [0.0, 0.0, -1e300]", "probe.offset"),
        ("[squareness]", "[thermal]\nreference_C = 1e300\n\n[squareness]", "thermal.reference_C"),
        (
            "[squareness]",
            "[thermal]\nexpansion = { x = 1e300 }\n\n[squareness]",
            "thermal.expansion.x",
        ),
    ],
)
def test_machine_refuses_probe_and_thermal_values_beyond_any_machine(
    tmp_path: Path, old: str, new: str, message: str
) -> None:
    text = GOLDEN.read_text(encoding="utf-8")
    assert old in text
    src = tmp_path / "m.toml"
    src.write_text(text.replace(old, new, 1), encoding="utf-8")
    with pytest.raises(ValueError, match=message.replace(".", r"\.")):
        Machine.from_toml(src)


def test_cli_grid_build_of_an_absurd_stylus_writes_nothing(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    from cmm_comp.cli.main import main

    src = tmp_path / "m.toml"
    src.write_text(
        GOLDEN.read_text(encoding="utf-8").replace("-100.0]", "-1e300]", 1), encoding="utf-8"
    )
    out = tmp_path / "m.grid"
    assert main(["grid", "build", str(src), "-o", str(out), "--steps", "4", "4", "4"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "probe.offset" in err[0]
    assert not out.exists()


def test_grid_refuses_node_values_beyond_any_machine(tmp_path: Path) -> None:
    """An effect of 1e300 µm (effects are not bounded at load: they need run-time signals) made
    `grid build` write a grid whose `correct` answered coordinates of 1e297 mm; a grid file with
    such values loaded too. Now the grid itself refuses them (build and load)."""
    from cmm_comp.compensation.grid.correction_grid import CorrectionGrid

    src = tmp_path / "m.toml"
    src.write_text(
        GOLDEN.read_text(encoding="utf-8")
        + '\n[[effects]]\ncause = "periodic"\naxis = "x"\nperiod_mm = 50.0\n'
        + "a_cos_um = 1e300\nb_sin_um = 0.0\n",
        encoding="utf-8",
    )
    with pytest.raises(ValueError, match=r"node translations reach .* beyond ±1e\+09 µm"):
        CorrectionGrid.build(Machine.from_toml(src), (4, 4, 4))
    q = np.zeros((4, 4, 4, 4))
    q[..., 0] = 1.0
    t = np.zeros((4, 4, 4, 3))
    CorrectionGrid((0, 0, 0), (1, 1, 1), q, t + 1e9)  # 1 km: the limit itself is a grid
    t[1, 2, 3, 0] = -2e9
    with pytest.raises(ValueError, match="beyond"):
        CorrectionGrid((0, 0, 0), (1, 1, 1), q, t)


def test_export_report_with_a_non_finite_figure_is_refused_and_nothing_written(
    tmp_path: Path,
) -> None:
    """export.json wrote a non-finite figure as null (a number silently missing), and
    write_export wrote the controller files before the PNG/HTML/JSON were made, so a failure
    there left a half-written directory. Now: one error naming the figure, no directory."""
    from cmm_comp.compensation.export.report import write_export

    machine = Machine.from_toml(GOLDEN)
    result = export_tables(machine, "linuxcnc", None, ExportOptions(**FAST))
    result.report["residual_um"]["per_axis"]["x"]["rms"] = float("nan")
    out = tmp_path / "out"
    with pytest.raises(ExportError, match=r"report\.residual_um\.per_axis\.x\.rms is nan"):
        write_export(result, machine, out)
    assert not out.exists()


def test_measurements_refuse_a_temperature_no_machine_has(tmp_path: Path) -> None:
    """T_x = 1e5 °C was read as a measurement (finite): a 10.5 µm/(m·°C) scale 1 m out gave a
    modelled error of ~1e6 µm, below the residual bound, fed to the diagnosis as data. Now the
    reader names the cell, as the --temp-* flags do."""
    from cmm_comp.compensation.formats.measurements import read_measurements

    src = tmp_path / "m.csv"
    src.write_text("x,y,z,ref_x,ref_y,ref_z,T_x\n1,2,3,1,2,3,20.5\n1,2,3,1,2,3,1e5\n", "utf-8")
    with pytest.raises(ValueError, match=r"m\.csv: line 3, column .T_x.: not a temperature"):
        read_measurements(src)
    src.write_text("x,y,z,ref_x,ref_y,ref_z,T_x\n1,2,3,1,2,3,20.5\n1,2,3,1,2,3,-20\n", "utf-8")
    assert read_measurements(src).temps_C["T_x"].tolist() == [20.5, -20.0]


def test_line_refuses_more_samples_than_memory_holds(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """`line --samples 1000000000` allocated 7.45 GiB per array and ended in a MemoryError
    traceback (or the kernel's kill); now one error naming the range."""
    from cmm_comp.cli.main import main

    argv = ["line", str(GOLDEN), "--axis", "x", "--through", "0", "0", "0"]
    assert main([*argv, "--samples", "1000000000"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "samples must be 2…1000000" in err[0]
    for bad in ("1", "0", "-5"):
        assert main([*argv, "--samples", bad]) == 2
        capsys.readouterr()


def test_monte_carlo_plan_of_many_trials_allocates_nothing_of_that_size() -> None:
    """--trials 1000000000 built its plan from np.arange(1e9): 7.45 GiB before the first
    trial (a MemoryError traceback, or the kernel's kill). The plan is now arithmetic: the
    first run is drawn at once (peak memory measured with tracemalloc, an independent probe)."""
    import tracemalloc

    from cmm_comp.compensation.uncertainty.adaptive import MonteCarloSettings, run_monte_carlo

    class Drawn(Exception):
        pass

    sizes: list[int] = []

    def draw(m: int, rng: np.random.Generator) -> np.ndarray:
        sizes.append(m)
        raise Drawn

    tracemalloc.start()
    try:
        with pytest.raises(Drawn):
            run_monte_carlo(
                draw, np.random.default_rng(0), MonteCarloSettings(trials=10**9, batch=10**4)
            )
        peak = tracemalloc.get_traced_memory()[1]
    finally:
        tracemalloc.stop()
    assert sizes == [10**4]  # 1e9 trials in 1e5 runs of 1e4, worked out by hand
    assert peak < 50e6, peak


def test_monte_carlo_run_size_is_bounded() -> None:
    """--batch 1e9 (or p = 0.9999999, whose J = 100/(1 − p) is 1e9 trials a run) tried to hold
    a run of 1e9 trials in memory: a MemoryError traceback or the kernel's kill."""
    from cmm_comp.compensation.uncertainty.adaptive import MonteCarloSettings

    with pytest.raises(ValueError, match="batch"):
        MonteCarloSettings(batch=10**9)
    with pytest.raises(ValueError, match=r"J = 100/\(1 − p\)"):
        MonteCarloSettings(probability=0.9999999)
    assert MonteCarloSettings(probability=0.999).j_min == 100_000  # 100/0.001, by hand


def test_uncertainty_single_run_warning_prints_no_nan(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """A single run cannot be judged stable: it was reported as 'worst 2s/δ = nan'."""
    from cmm_comp.cli.main import main

    points = tmp_path / "p.csv"
    points.write_text("x,y,z\n100,100,100\n", encoding="utf-8")
    argv = ["uncertainty", str(GOLDEN), "--points", str(points), "--max-trials", "3000"]
    assert main([*argv, "--batch", "5000"]) == 0
    err = capsys.readouterr().err
    assert "did not stabilise" in err and "nan" not in err.lower()
