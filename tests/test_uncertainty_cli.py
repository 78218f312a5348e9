"""``cmm-comp uncertainty`` and the U columns of ``cmm-comp correct`` (docs/formats.md §3):
what each mode writes, and bad input as one line with exit 2 and nothing written.

Outputs are read with ``csv``/``json``/PNG magic bytes; numbers are checked against the first
order (GUM) values the same run reports (the Monte Carlo itself has its oracles in
test_uncertainty_mc.py) and against the documented column layout.
"""

from __future__ import annotations

import csv
import json
import math
from pathlib import Path

import pytest

from cmm_comp.cli.main import main as cli_main

ROOT = Path(__file__).resolve().parents[1]
NPL = str(ROOT / "examples" / "machines" / "npl-bridge.toml")
PNG = b"\x89PNG\r\n\x1a\n"


def _rows(path: Path) -> list[dict[str, str]]:
    with open(path, newline="") as fh:
        return list(csv.DictReader(fh))


def test_points_mode_writes_csv_json_png(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    pts = tmp_path / "p.csv"
    pts.write_text("x,y,z,T_x,note\n100,100,100,20.5,a\n450,575,200,,b\n2000,0,0,20,c\n")
    out, js, png = tmp_path / "o.csv", tmp_path / "o.json", tmp_path / "o.png"
    code = cli_main(
        ["uncertainty", NPL, "--points", str(pts), "--trials", "3000", "--out", str(out),
         "--json", str(js), "--plot", str(png)]
    )  # fmt: skip
    assert code == 0
    rows = _rows(out)
    assert [r["status"] for r in rows] == ["ok", "no_temperature", "outside_volume"]
    assert rows[0]["note"] == "a"  # input columns carried through
    ux, gum = float(rows[0]["Ux_um"]), float(rows[0]["gum_ux_um"])
    assert abs(ux / (2 * gum) - 1) < 4 / math.sqrt(2 * 2999)  # U (k = 2) vs first order
    assert float(rows[0]["lowy_um"]) < 0 < float(rows[0]["highy_um"])
    assert rows[1]["Ux_um"] == "" and rows[2]["Uz_um"] == ""
    summary = json.loads(js.read_text())
    assert summary["ok"] == 1 and summary["monte_carlo"]["trials"] == 3000
    assert "uncertainty.squareness.alpha" in summary["uncertainty_model"]["defaulted"]
    assert png.read_bytes()[:8] == PNG
    assert "defaulted" in capsys.readouterr().err


def test_volume_mode(tmp_path: Path) -> None:
    out, png = tmp_path / "v.csv", tmp_path / "v.png"
    code = cli_main(
        ["uncertainty", NPL, "--volume", "3", "3", "2", "--trials", "500", "--quiet",
         "--out", str(out), "--plot", str(png)]
    )  # fmt: skip
    assert code == 0
    rows = _rows(out)
    assert len(rows) == 18 and all(r["status"] == "ok" for r in rows)
    assert png.read_bytes()[:8] == PNG


def test_length_and_e0_modes(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    js, png = tmp_path / "l.json", tmp_path / "l.png"
    code = cli_main(
        ["uncertainty", NPL, "--length", "100", "100", "100", "800", "1000", "350", "--trials",
         "4000", "--json", str(js), "--plot", str(png), "--quiet"]
    )  # fmt: skip
    assert code == 0
    s = json.loads(js.read_text())
    out = s["outputs"]["length_error_um"]
    assert out["U_k2"] == pytest.approx(2 * out["u"])
    gum_u = s["gum_first_order"]["u"][0]
    assert abs(out["u"] / gum_u - 1) < 4 / math.sqrt(2 * 3999)
    assert s["nominal"]["length_mm"] == pytest.approx(math.dist([100, 100, 100], [800, 1000, 350]))
    assert png.read_bytes()[:8] == PNG
    js2 = tmp_path / "e.json"
    code = cli_main(
        ["uncertainty", NPL, "--e0-test", "--mpe", "20", "100", "--trials", "300", "--json",
         str(js2), "--quiet"]
    )  # fmt: skip
    assert code == 0
    e0 = json.loads(js2.read_text())
    assert len(e0["length_errors"]) == 105
    assert 0.0 <= e0["nominal"]["p_pass"] <= 1.0
    assert "probability of passing" in capsys.readouterr().out


def test_sphere_and_plane_modes(tmp_path: Path) -> None:
    js = tmp_path / "s.json"
    sphere = ["--sphere", "450", "575", "200", "12.5"]
    code = cli_main(["uncertainty", NPL, *sphere, "--trials", "500", "--json", str(js), "--quiet"])
    assert code == 0
    names = set(json.loads(js.read_text())["outputs"])
    assert names == {"centre_x_um", "centre_y_um", "centre_z_um", "radius_um"}
    js = tmp_path / "f.json"
    plane = ["--plane", "100", "100", "50", "600", "0", "0", "0", "800", "0"]
    code = cli_main(["uncertainty", NPL, *plane, "--trials", "500", "--json", str(js), "--quiet"])
    assert code == 0
    assert json.loads(js.read_text())["outputs"]["flatness_um"]["mean"] > 0


@pytest.mark.parametrize(
    ("args", "match"),
    [
        (["--length", "0", "0", "0", "1", "1", "1", "--e0-test"], "exactly one of"),
        ([], "exactly one of"),
        (["--length", "0", "0", "0", "nan", "1", "1"], "--length must be finite"),
        (["--length", "0", "0", "0", "5000", "1", "1"], "outside the working volume"),
        (["--length", "1", "1", "1", "2", "2", "2", "--trials", "1"], "trials must be ≥ 2"),
        (
            ["--length", "1", "1", "1", "2", "2", "2", "--probability", "1.5"],
            "coverage probability",
        ),
        (["--points", "absent.csv"], "cannot read"),
        (["--volume", "1", "3", "3"], "2…200 nodes"),
        (["--sphere", "450", "575", "200", "-1"], "radius must be finite and > 0"),
        (["--e0-test", "--mpe", "-1", "100"], "MPE A \\+ L/K needs A ≥ 0"),
        (
            ["--length", "1", "1", "1", "2", "2", "2", "--probe", "0", "inf", "0"],
            "--probe must be finite",
        ),
    ],
)
def test_bad_input_is_one_line_and_writes_nothing(
    args: list[str], match: str, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    js = tmp_path / "o.json"
    code = cli_main(["uncertainty", NPL, *args, "--json", str(js), "--quiet"])
    err = capsys.readouterr().err.strip().splitlines()
    assert code == 2
    assert len(err) == 1 and err[0].startswith("cmm-comp: error:")
    assert pytest.importorskip("re").search(match, err[0]), err[0]
    assert not js.exists()


def test_bad_uncertainty_section_is_one_line(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    machine = tmp_path / "m.toml"
    machine.write_text(Path(NPL).read_text() + "\n[uncertainty]\nprobe_um = -1\n")
    code = cli_main(["uncertainty", str(machine), "--length", "1", "1", "1", "2", "2", "2"])
    err = capsys.readouterr().err.strip().splitlines()
    assert code == 2 and len(err) == 1
    assert "m.toml: uncertainty.probe_um = -1; allowed: 0 .. 1e+09 µm" in err[0]


def test_grid_build_with_uncertainty_and_correct_columns(tmp_path: Path) -> None:
    grid, plain = tmp_path / "u.grid", tmp_path / "p.grid"
    assert cli_main(
        ["grid", "build", NPL, "-o", str(grid), "--steps", "5", "5", "4", "--uncertainty",
         "--uncertainty-trials", "400"]
    ) == 0  # fmt: skip
    assert cli_main(["grid", "build", NPL, "-o", str(plain), "--steps", "5", "5", "4"]) == 0
    pts = tmp_path / "c.csv"
    pts.write_text(
        "x,y,z,T_x,T_y,T_z,T_wp\n100,100,100,20.5,20.4,20.6,20.3\n450,575,200,,20.4,20.6,20.3\n"
    )
    for g, has_u in ((grid, True), (plain, False)):
        out = tmp_path / f"{g.stem}.csv"
        assert cli_main(["correct", str(g), "--in", str(pts), "--out", str(out)]) == 0
        rows = _rows(out)
        assert list(rows[0])[-7:] == ["cx", "cy", "cz", "Ux_um", "Uy_um", "Uz_um", "status"]
        assert (rows[0]["Uy_um"] != "") is has_u
        assert rows[1]["status"] == "no_temperature" and rows[1]["Ux_um"] == ""
    assert cli_main(["grid", "build", NPL, "-o", str(tmp_path / "x.grid"), "--uncertainty",
                     "--uncertainty-trials", "1"]) == 2  # fmt: skip
    assert not (tmp_path / "x.grid").exists()
