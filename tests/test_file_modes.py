"""Every file kind the commands write gets the mode a plain ``open()`` gives under the umask.

Atomic writes go through ``tempfile.mkstemp``, which creates 0600 whatever the umask: a grid or
a ``.comp`` table copied to a controller account, or an ``export.html`` served by a web server,
was then unreadable. The oracle is the kernel itself: a file created with ``open(path, "w")``
in the same folder under the same umask. The private signing key stays 0600 under any umask.
The commands run in process (``cmm_comp.cli.main``); the umask is set for the test and restored.
"""

from __future__ import annotations

import os
import stat
from collections.abc import Iterator
from pathlib import Path

import pytest
from test_camonitor_import import CMD, POS, REF, TEST, synthetic_log

from cmm_comp.cli.main import main
from cmm_comp.compensation.formats.atomic import current_umask

ROOT = Path(__file__).resolve().parents[1]
NPL = ROOT / "examples" / "machines" / "npl-bridge.toml"
GOLDEN = ROOT / "tests" / "data" / "export" / "golden-machine.toml"


@pytest.fixture(params=[0o022, 0o077], ids=["umask022", "umask077"])
def umask(request: pytest.FixtureRequest) -> Iterator[int]:
    old = os.umask(request.param)
    try:
        yield request.param
    finally:
        os.umask(old)


def _mode(path: Path) -> int:
    return stat.S_IMODE(path.stat().st_mode)


def _open_mode(folder: Path) -> int:
    """The mode ``open(…, "w")`` gives a new file in ``folder`` now (the oracle)."""
    probe = folder / ".open-oracle"
    with open(probe, "w") as fh:
        fh.write("x")
    mode = _mode(probe)
    probe.unlink()
    return mode


def _files(folder: Path) -> list[Path]:
    return sorted(p for p in folder.rglob("*") if p.is_file())


def test_current_umask_reads_without_changing(umask: int) -> None:
    assert current_umask() == umask
    assert current_umask() == umask  # unchanged by the read


def test_every_written_file_has_the_open_mode(umask: int, tmp_path: Path) -> None:
    expected = _open_mode(tmp_path)
    assert expected == 0o666 & ~umask
    grid = tmp_path / "npl.grid"
    assert main(["grid", "build", str(NPL), "-o", str(grid), "--steps", "5", "5", "4"]) == 0
    assert _mode(grid) == expected, "grid build"
    keys = tmp_path / "keys"
    assert main(["grid", "keygen", "--out", str(keys)]) == 0
    assert _mode(keys / "grid-signing-key.pem") == 0o600, "the private key stays 0600"
    assert _mode(keys / "grid-signing-key.pub.pem") == expected
    assert main(["grid", "sign", str(grid), "--key", str(keys / "grid-signing-key.pem")]) == 0
    assert _mode(grid) == expected, "grid sign rewrites the file"

    points = tmp_path / "points.csv"
    points.write_text("x,y,z\n450,575,200\n", encoding="utf-8")
    corrected = tmp_path / "corrected.csv"
    assert main(["correct", str(grid), "--in", str(points), "--out", str(corrected)]) == 0
    assert _mode(corrected) == expected, "correct --out"

    as_json = tmp_path / "diagonals.json"
    assert main(["diagonals", str(NPL), "--json", str(as_json)]) == 0
    assert _mode(as_json) == expected, "--json"
    report = tmp_path / "report"
    assert main(["report", str(NPL), "--out", str(report), "--steps", "4", "4", "3"]) == 0
    written = _files(report)
    assert {p.suffix for p in written} >= {".csv", ".png", ".json"}
    assert {p.name: _mode(p) for p in written} == {p.name: expected for p in written}

    for fmt in ("linuxcnc", "sinumerik-cec"):
        out = tmp_path / fmt
        argv = ["export", str(GOLDEN), "--format", fmt, "--points", "11", "-o", str(out)]
        assert main([*argv, "--eval-steps", "5", "5", "4"]) == 0
        written = _files(out)
        assert "export.html" in {p.name for p in written}
        assert {p.name: _mode(p) for p in written} == {p.name: expected for p in written}, fmt


def test_camonitor_import_files_have_the_open_mode(umask: int, tmp_path: Path) -> None:
    log = tmp_path / "sim.log"
    synthetic_log(log)
    out = tmp_path / "imported"
    argv = ["import", "camonitor", str(log), "--position", POS, "--reference", REF]
    assert main([*argv, "--test", TEST, "--command", CMD, "--out-dir", str(out), "--quiet"]) == 0
    written = _files(out)
    assert {p.suffix for p in written} >= {".toml", ".csv", ".json", ".png"}
    expected = _open_mode(tmp_path)
    assert {p.name: _mode(p) for p in written} == {p.name: expected for p in written}
