"""The model layer's CLI commands end to end (the CLI's main() in this process, real files)."""

from __future__ import annotations

import json
import subprocess
from pathlib import Path

import numpy as np
from doc_commands import cli as run_cli_args

from cmm_comp.compensation import Machine

ROOT = Path(__file__).resolve().parents[1]
NPL = ROOT / "examples" / "machines" / "npl-bridge.toml"


def cli(*args: str) -> subprocess.CompletedProcess[str]:
    return run_cli_args(*args, cwd=ROOT)


def test_seed_export_import_round_trip(tmp_path: Path) -> None:
    r = cli("export-seed", str(NPL), str(tmp_path / "set"), "NPL1")
    assert r.returncode == 0, r.stderr
    r = cli("import-seed", str(tmp_path / "set"), "-o", str(tmp_path / "back.toml"))
    assert r.returncode == 0, r.stderr
    a, b = Machine.from_toml(NPL), Machine.from_toml(tmp_path / "back.toml")
    pts = np.random.default_rng(2).uniform(a.volume.lower_mm, a.volume.upper_mm, (50, 3))
    np.testing.assert_allclose(
        b.volumetric_error(pts, (5, 5, -100)), a.volumetric_error(pts, (5, 5, -100)), atol=1e-9
    )
    np.testing.assert_allclose(b.random_error(pts), a.random_error(pts), atol=1e-9)


def test_import_seed_reports_missing_directory(tmp_path: Path) -> None:
    r = cli("import-seed", str(tmp_path / "nowhere"), "-o", str(tmp_path / "m.toml"))
    assert r.returncode == 2 and "Traceback" not in r.stderr
    assert not (tmp_path / "m.toml").exists()


def test_report_writes_every_output(tmp_path: Path) -> None:
    r = cli("report", str(NPL), "--out", str(tmp_path), "--steps", "4", "4", "3")
    assert r.returncode == 0, r.stderr
    for name in (
        "map.csv",
        "map.png",
        "parametric_errors.png",
        "diagonals.png",
        "line_x.csv",
        "line_x.png",
    ):
        assert (tmp_path / name).stat().st_size > 0, name
    summary = json.loads((tmp_path / "summary.json").read_text())
    assert len(summary["diagonals_um"]) == 4
    assert (tmp_path / "map.png").read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"


def test_line_command(tmp_path: Path) -> None:
    r = cli(
        "line",
        str(NPL),
        "--axis",
        "y",
        "--through",
        "450",
        "0",
        "200",
        "--out",
        str(tmp_path / "l.csv"),
    )
    assert r.returncode == 0, r.stderr
    assert "bandwidth" in r.stdout
    assert len((tmp_path / "l.csv").read_text().splitlines()) == 102
