"""Reading the outputs (issue 25, item 8): what a user sees on the terminal and in the plots.

* ``cmm-comp correct --help`` lists the input columns: the runtime signals the model knows,
  the set docs/formats.md §3 documents; and the stylus, a temperature and a direction given
  in those columns change the answer by what the physics says;
* ``cmm-comp grid info`` prints a grid's header: checked against the file read with numpy
  alone (its ``header`` member) and U at the nodes recomputed from the raw covariance member
  with the formula of docs/formats.md §7; its signature verified with the public key, refused
  with another;
* the uncertainty's defaulted inputs and the components taken as exactly zero are on the
  terminal, named as the machine file names its errors (ISO 230-1 names here), and the zero
  ones are exactly the components the file gives nothing for;
* plots: the names the user wrote, a legend for nominal vs distorted, and no empty panel (every
  visible panel of every figure the commands draw shows data that varies) — on a machine with
  X tables only, and on the real one-axis ESS record (skipped without ../shared/realdata).
"""

from __future__ import annotations

import csv
import json
import re
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from doc_commands import run_cli
from ess_record import ess_x, panel_shows_data

from cmm_comp.cli.main import main as cli_main
from cmm_comp.compensation import Machine, ParametricErrors
from cmm_comp.compensation.parametric_errors import TABLE_COMPONENTS, iso_name

ROOT = Path(__file__).resolve().parents[1]
FORMATS = ROOT / "docs" / "formats.md"

# X tables only, in ISO 230-1 names: positional EXX, straightness EYX, pitch EBX
ISO_X = {"EXX": [0.0, 4e-3, -3e-6], "EYX": [0.0, 0.0, 2e-6], "EBX": [1.5, 0.0, -4e-6]}


@pytest.fixture
def iso_machine(tmp_path: Path) -> Path:
    errors = ParametricErrors.from_polynomials(ISO_X, random_band={"EXX": 0.6})
    machine = Machine.from_parts(
        model="MB1", volume=((0, 600), (0, 500), (0, 300)), errors=errors,
        probe=(0.0, 0.0, -80.0), name="iso-x",
    )  # fmt: skip
    path = tmp_path / "iso-x.toml"
    machine.to_toml(path)
    return path


@pytest.fixture
def figures(monkeypatch: pytest.MonkeyPatch) -> Iterator[list[Any]]:
    """Every figure the project's plotting writes through ``save_png``, kept for inspection."""
    from cmm_comp.compensation.reports import plots

    kept: list[Any] = []
    real = plots.save_png

    def keep(fig: Any, path: Any) -> Path:
        kept.append(fig)
        return real(fig, path)

    monkeypatch.setattr(plots, "save_png", keep)
    yield kept


_panel_shows_data = panel_shows_data  # one definition (tests/ess_record.py)


def _visible_panels(fig: Any) -> list[Any]:
    return [ax for ax in fig.axes if ax.get_visible()]


# ------------------------------------------------------------------ correct --help


def _help_columns(section: str, text: str) -> set[str]:
    block = text.split(section, 1)[1].split("\n\n", 1)[0]
    names: set[str] = set()
    for line in block.splitlines()[1:]:
        m = re.match(r"^  (\S.*?)\s{2,}", line)
        if m:
            names |= {n.strip() for n in m[1].split(",")}
    return names


def test_correct_help_lists_the_columns_it_reads(capsys: pytest.CaptureFixture[str]) -> None:
    with pytest.raises(SystemExit):
        cli_main(["correct", "--help"])
    text = capsys.readouterr().out
    listed = _help_columns("input columns", text)
    from cmm_comp.compensation.thermal.roles import TEMPERATURE_ROLES

    assert listed == {
        "x",
        "y",
        "z",
        "px",
        "py",
        "pz",
        *TEMPERATURE_ROLES,
        "dir_x",
        "dir_y",
        "dir_z",
    }
    documented = re.search(r"\| `cmm-comp correct GRID.*", FORMATS.read_text(encoding="utf-8"))
    assert documented is not None
    for name in listed:  # formats.md §3 names every one of them
        assert f"{name}" in documented[0], name
    assert {"cx", "cy", "cz", "Ux_um", "Uy_um", "Uz_um", "status"} <= _help_columns(
        "output columns", text
    )


def test_every_listed_column_is_read(tmp_path: Path) -> None:
    """A grid needing a temperature and a direction: the listed columns change the answer."""
    errors = ParametricErrors.from_tables({"dx_x": ([0, 300, 600], [0.0, 5.0, 2.0])})
    data = Machine.from_parts(model="MB1", volume=((0, 600), (0, 500), (0, 300)), errors=errors)
    desc = json.loads(json.dumps(data.description))
    desc["errors"]["dx_x"]["reversal"] = [1.0, 3.0, 2.0]
    desc["thermal"] = {"reference_C": 20.0, "expansion": {"x": 11.5, "y": 0.0, "z": 0.0}}
    path = tmp_path / "m.toml"
    Machine.from_dict(desc).to_toml(path)
    grid = tmp_path / "m.grid"
    assert cli_main(["grid", "build", str(path), "-o", str(grid), "--steps", "7", "5", "4"]) == 0
    pts = tmp_path / "p.csv"
    pts.write_text(
        "x,y,z,px,py,pz,T_x,dir_x,note\n"
        "300,250,150,0,0,0,20,1,a\n"
        "300,250,150,0,0,0,20,-1,b\n"
        "300,250,150,0,0,0,25,1,c\n"
        "300,250,150,0,0,-100,25,1,d\n"
    )
    out = tmp_path / "c.csv"
    assert cli_main(["correct", str(grid), "--in", str(pts), "--out", str(out)]) == 0
    with open(out, newline="") as fh:
        rows = list(csv.DictReader(fh))
    cx = [float(r["cx"]) for r in rows]
    assert [r["status"] for r in rows] == ["ok"] * 4 and rows[0]["note"] == "a"
    assert (cx[0] - cx[1]) * 1000 == pytest.approx(2 * 3.0, abs=0.05)  # ± reversal 3 µm at 300
    # the scale's expansion: 11.5 µm/(m·°C) × 5 °C × 300 mm from the reference = 17.25 µm
    assert abs(cx[2] - cx[0]) * 1000 == pytest.approx(11.5 * 5 * 0.3, abs=0.05)
    assert cx[3] == pytest.approx(cx[2], abs=1e-9)  # no angular error: the stylus changes nothing


# ------------------------------------------------------------------ grid info


def _u_at_nodes_from_file(path: Path, probe: np.ndarray) -> np.ndarray:
    """U (k = 2) per component at every node from the raw member, formats.md §7 (reference
    temperatures; this machine has no thermal terms): r = δt + 10⁻³·δω × p."""
    with np.load(path, allow_pickle=False) as npz:
        header = json.loads(bytes(npz["header"]).decode())
        c = npz["uncertainty_covariance"].reshape(-1, 15)
    names = header["uncertainty"]["covariance_components"]
    C = {n: c[:, i] for i, n in enumerate(names)}
    px, py, pz = probe
    var = np.stack([
        C["tx_tx"] + 2e-3 * (pz * C["tx_wy"] - py * C["tx_wz"])
        + 1e-6 * (pz**2 * C["wy_wy"] + py**2 * C["wz_wz"] - 2 * py * pz * C["wy_wz"]),
        C["ty_ty"] + 2e-3 * (px * C["ty_wz"] - pz * C["ty_wx"])
        + 1e-6 * (px**2 * C["wz_wz"] + pz**2 * C["wx_wx"] - 2 * px * pz * C["wx_wz"]),
        C["tz_tz"] + 2e-3 * (py * C["tz_wx"] - px * C["tz_wy"])
        + 1e-6 * (py**2 * C["wx_wx"] + px**2 * C["wy_wy"] - 2 * px * py * C["wx_wy"]),
    ], axis=1)  # fmt: skip
    var = np.maximum(var, 0.0) + header["uncertainty"]["probe_um"] ** 2
    return header["uncertainty"]["coverage_factor"] * np.sqrt(var)


def test_grid_info_prints_the_header_u_and_signature(
    iso_machine: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    grid = tmp_path / "iso.grid"
    build = ["grid", "build", str(iso_machine), "-o", str(grid), "--steps", "6", "5", "4"]
    assert cli_main([*build, "--uncertainty", "--uncertainty-trials", "300"]) == 0
    built = capsys.readouterr()
    assert "defaulted" in built.err and "taken as exactly zero" in built.err  # on the terminal
    assert cli_main(["grid", "keygen", "--out", str(tmp_path / "keys")]) == 0
    private = tmp_path / "keys" / "grid-signing-key.pem"
    assert cli_main(["grid", "sign", str(grid), "--key", str(private)]) == 0
    capsys.readouterr()
    public = tmp_path / "keys" / "grid-signing-key.pub.pem"
    assert cli_main(["grid", "info", str(grid), "--public-key", str(public)]) == 0
    text = capsys.readouterr().out
    with np.load(grid, allow_pickle=False) as npz:  # the file, read without the project
        header = json.loads(bytes(npz["header"]).decode())
        sha = bytes(npz["sha256"]).decode()
        sig = json.loads(bytes(npz["signature"]).decode())
    assert f"sha256 {sha}" in text
    assert f"steps {' × '.join(str(s) for s in header['steps'])}" in text
    assert f"{header['probe_offset_mm']} mm" in text
    needed = [s["name"] for s in header["signals"] if s["needed"]]
    assert ("signals the correction needs: none" in text) == (not needed)
    assert f"key id {sig['key_id']} (verified with {public}" in text
    u = _u_at_nodes_from_file(grid, np.asarray(header["probe_offset_mm"]))
    line = next(li for li in text.splitlines() if li.startswith("uncertainty: U (k = 2)"))
    for i, a in enumerate("xyz"):
        assert f"{a} {u[:, i].min():.3g}…{u[:, i].max():.3g}" in line, (line, a)
    assert f"{header['uncertainty']['trials']} virtual machines per node" in text
    zero = [c for c in TABLE_COMPONENTS if c not in {"dx_x", "dy_x", "ey_x"}]
    assert all(c in text for c in zero)  # what U assumed, listed
    # another key: refused, one line, exit 2
    assert cli_main(["grid", "keygen", "--out", str(tmp_path / "other")]) == 0
    capsys.readouterr()
    other = tmp_path / "other" / "grid-signing-key.pub.pem"
    assert cli_main(["grid", "info", str(grid), "--public-key", str(other)]) == 2
    err = capsys.readouterr().err
    assert err.startswith("cmm-comp: error:") and len(err.strip().splitlines()) == 1
    assert cli_main(["grid", "info", str(grid), "--json"]) == 0
    assert json.loads(capsys.readouterr().out)["header"] == header


# ------------------------------------------------------------------ uncertainty notes


def test_uncertainty_notes_name_defaults_and_zeros_as_the_file_does(
    iso_machine: Path, tmp_path: Path
) -> None:
    js = tmp_path / "l.json"
    run = run_cli(
        f"cmm-comp uncertainty {iso_machine} --length 50 50 50 550 450 250 --ndig 1 --json {js}",
        tmp_path,
    )
    assert run.code == 0, run.err
    notes = [li for li in run.err.splitlines() if li.startswith("cmm-comp: note:")]
    text = "\n".join(notes)
    given = {"dx_x", "dy_x", "ey_x"}  # EXX, EYX, EBX
    zero_line = next(li for li in notes if "taken as exactly zero" in li)
    zero_listed = set(re.findall(r"\bE[XYZABC][XYZ]\b", zero_line.split(":", 2)[2]))
    assert zero_listed == {iso_name(c) for c in TABLE_COMPONENTS if c not in given}
    for name in ("EXX", "EYX", "EBX"):  # their defaulted u, u_per_m … named as written
        assert re.search(rf"of 3 table\(s\):.*\b{name}\b", text), name
    assert "dx_x" not in text and "squareness: alpha, beta1, beta2" in text
    model = json.loads(js.read_text())["uncertainty_model"]
    assert len(model["defaulted"]) == int(re.search(r"(\d+) uncertainty input", text)[1])  # type: ignore[index]
    quiet = run_cli(f"cmm-comp uncertainty {iso_machine} --length 50 50 50 550 450 250 "
                    "--ndig 1 --quiet", tmp_path)  # fmt: skip
    assert "note:" not in quiet.err


# ------------------------------------------------------------------ plots


def test_report_plots_use_the_files_names_and_show_no_empty_panel(
    iso_machine: Path, tmp_path: Path, figures: list[Any]
) -> None:
    out = tmp_path / "report"
    run = run_cli(f"cmm-comp report {iso_machine} --out {out} --steps 5 5 4", tmp_path)
    assert run.code == 0, run.err
    by_title = {f.get_suptitle() or f.axes[0].get_title(): f for f in figures}
    param = next(f for t, f in by_title.items() if "parametric errors" in t)
    panels = _visible_panels(param)
    assert [ax.get_title() for ax in panels] == ["linear errors of X", "angular errors of X"]
    labels = [t.get_text().split(" (")[0] for ax in panels for t in ax.get_legend().get_texts()]
    assert sorted(labels) == sorted(ISO_X)  # the names the file used
    vmap = next(f for t, f in by_title.items() if "volumetric error map" in t)
    legend = [t.get_text() for t in vmap.axes[0].get_legend().get_texts()]
    assert legend[0].startswith("nominal") and legend[1].startswith("distorted")
    for fig in figures:
        for ax in _visible_panels(fig):
            assert _panel_shows_data(ax), (fig.get_suptitle(), ax.get_title())


def test_map_of_a_machine_without_errors_says_zero(tmp_path: Path, figures: list[Any]) -> None:
    flat = Machine.from_parts(model="MB1", volume=((0, 100), (0, 100), (0, 100)))
    flat.to_toml(tmp_path / "flat.toml")
    run = run_cli(f"cmm-comp report {tmp_path / 'flat.toml'} --out {tmp_path / 'r'}", tmp_path)
    assert run.code == 0, run.err
    titles = [ax.get_title() for f in figures for ax in f.axes]
    assert any("peak 0.0 µm" in t for t in titles), titles  # was 'peak 1000.0 µm'
    param = next(f for f in figures if "parametric errors" in f.get_suptitle())
    assert not _visible_panels(param)  # a sentence, not six empty panels
    assert "no parametric error tables" in param.texts[0].get_text()


@pytest.mark.realdata
@pytest.mark.timeout(900)
def test_real_one_axis_record_plots_only_the_measured_axis(
    realdata_dir: Path, tmp_path_factory: pytest.TempPathFactory
) -> None:
    """The dense ESS X record (one axis measured) imported and diagnosed with its report: the
    README's lines, run once per test run (tests/ess_record.py), which describes every figure
    the plotting wrote (visible panels, their titles, whether each shows data)."""
    work, runs = ess_x(tmp_path_factory, realdata_dir)
    (diagnose,) = [r for line, r in runs["lines"].items() if line.startswith("cmm-comp diagnose")]
    assert diagnose["code"] == 0, diagnose["err"]
    residual_figs = [f for f in diagnose["figures"] if f["first_title"].startswith("residual")]
    assert len(residual_figs) == len(list((work / "ess-x" / "report").glob("residual_vs_*.png")))
    assert residual_figs
    for fig in residual_figs:
        assert [p["title"] for p in fig["panels"]] == ["residual x"]
        assert all(p["shows_data"] for p in fig["panels"])
