"""``cmm-comp fleet replay``: every session log re-corrected on Dask equals ``cmm-comp replay``
run on its own, with the session's grid or the new one a grid map names.

Oracles: the one-by-one ``cmm-comp replay`` (its JSON report), the machine totals
recomputed here from those reports, and physics: a grid built with a 5 µrad larger squareness
alpha moves the answers by up to alpha × the travel, the session's own grid by nothing.
"""

from __future__ import annotations

import json
import math
import shutil
from pathlib import Path
from typing import Any

import pytest
from test_fleet import cmm, cmm_here

pytestmark = pytest.mark.timeout(900)


@pytest.fixture(scope="module")
def plant(tmp_path_factory: pytest.TempPathFactory) -> dict[str, Any]:
    """3 machines × 4 dates with one daemon log each; a new grid (with U) for cmm-02."""
    work = tmp_path_factory.mktemp("fleet-replay")
    cmm_here("fleet", "generate", "plant", "--machines", "3", "--dates", "4", "--points", "100",
        "--logs", "--readings", "20", cwd=work)  # fmt: skip
    text = (work / "plant" / "cmm-02" / "2026-01-05" / "machine.toml").read_text()
    new = work / "new"
    new.mkdir()
    assert "alpha = 12.0" in text
    (new / "cmm-02.toml").write_text(text.replace("alpha = 12.0", "alpha = 17.0"))
    cmm_here("grid", "build", "new/cmm-02.toml", "-o", "new/cmm-02.grid", "--steps", "7", "8", "5",
        "--uncertainty", "--uncertainty-trials", "8", cwd=work)  # fmt: skip
    (work / "map.toml").write_text('[grids]\n"cmm-02" = "new/cmm-02.grid"\n')
    rolled = work / "plant" / "cmm-01" / "rolled"
    rolled.mkdir()
    log = work / "plant" / "cmm-01" / "2026-01-05" / "shift-1.mcap"
    for k in range(2):  # a daemon's rolled files of one session (here: one log twice)
        shutil.copy(log, rolled / f"session-20260105T060000-{k:03d}.mcap")
    cmm("fleet", "replay", "plant", "--grid-map", "map.toml", "--json", "replay.json",
        "--workers", "2", cwd=work)  # fmt: skip
    return {"work": work, "out": json.loads((work / "replay.json").read_text())}


def _alone(work: Path, source: str, grid: str | None = None) -> dict[str, Any]:
    argv = ["replay", source, "--json", str(work / "one.json")]
    if grid:
        argv += ["--grid", grid]
    cmm_here(*argv, cwd=work)
    return json.loads((work / "one.json").read_text())


def test_sessions_equal_replay_run_one_by_one(plant: dict[str, Any]) -> None:
    work, out = plant["work"], plant["out"]
    assert out["failed"] == []
    by_path = {s["path"]: s for s in out["sessions"]}
    assert len(by_path) == 3 * 4 + 1
    grid = str((work / "new" / "cmm-02.grid").resolve())
    reports = []
    for path in sorted(p for p in by_path if p.startswith("cmm-02/")):
        alone = _alone(work, str(work / "plant" / path), grid)
        assert by_path[path]["replay"] == alone, path
        reports.append(alone)
    for path in ("cmm-01/2026-01-12/shift-1.mcap", "cmm-03/2026-01-26/shift-1.mcap"):
        assert by_path[path]["replay"] == _alone(work, str(work / "plant" / path)), path
    # the machine's totals, recomputed from the one-by-one reports
    totals = out["machines"]["cmm-02"]
    n = sum(r["compared"] for r in reports)
    rms = math.sqrt(sum(r["compared"] * r["rms_diff_um"] ** 2 for r in reports) / n)
    assert totals["compared"] == n and totals["sessions"] == 4
    assert totals["rms_diff_um"] == pytest.approx(rms, rel=1e-12)
    assert totals["max_abs_diff_um"] == max(r["max_abs_diff_um"] for r in reports)
    assert totals["readings"] == sum(r["readings"] for r in reports)


def test_new_grid_moves_answers_by_the_squareness_change(plant: dict[str, Any]) -> None:
    machines = plant["out"]["machines"]
    # 5 µrad of alpha over a y travel of 1150 mm: at most 5.75 µm, well above replay noise
    assert 0.5 < machines["cmm-02"]["max_abs_diff_um"] < 5.0 * 1.15 + 0.5
    for m in ("cmm-01", "cmm-03"):  # the session's own grid: the same answers
        assert machines[m]["max_abs_diff_um"] < 0.01
        assert machines[m]["status_differ"] == {}
    # U: the new grid carries it, the sessions' grids did not
    assert machines["cmm-02"]["uncertainty_mismatch"] == machines["cmm-02"]["readings"]
    assert machines["cmm-01"]["uncertainty_mismatch"] == 0


def test_rolled_files_are_one_session(plant: dict[str, Any]) -> None:
    work, out = plant["work"], plant["out"]
    path = "cmm-01/rolled/session-20260105T060000-*.mcap"
    (session,) = [s for s in out["sessions"] if s["path"] == path]
    alone = _alone(work, str(work / "plant" / path))
    assert session["replay"] == alone
    single = next(s for s in out["sessions"] if s["path"] == "cmm-01/2026-01-05/shift-1.mcap")
    assert alone["readings"] == 2 * single["replay"]["readings"]


def test_rerun_keys_on_grid_content_and_reports_a_bad_log(plant: dict[str, Any]) -> None:
    work = plant["work"]
    again = cmm_here("fleet", "replay", "plant", "--grid-map", "map.toml", "--json", "replay.json",
                "--workers", "2", cwd=work)  # fmt: skip
    assert "0 run, 13 stored before, 0 failed" in again.stdout
    # cmm-01's own grid rebuilt differently: its 5 sessions run again, the rest stay stored
    grid = work / "plant" / "cmm-01" / "grid" / "cmm-01.grid"
    cmm_here("grid", "build", "plant/cmm-01/2026-01-05/machine.toml", "-o", str(grid),
        "--steps", "6", "7", "4", cwd=work)  # fmt: skip
    bad = work / "plant" / "cmm-03" / "2026-01-05" / "shift-2.mcap"
    bad.write_bytes(b"\x89MCAP0\r\n" + b"not a log" * 10)
    proc = cmm("fleet", "replay", "plant", "--grid-map", "map.toml", "--json", "replay.json",
               "--workers", "2", cwd=work, check=False)  # fmt: skip
    assert proc.returncode == 1
    assert "5 run, 8 stored before, 1 failed" in proc.stdout, proc.stdout
    out = json.loads((work / "replay.json").read_text())
    (failed,) = out["failed"]
    assert failed["path"] == "cmm-03/2026-01-05/shift-2.mcap"
    alone = cmm_here("replay", str(bad), "--json", str(work / "x.json"), check=False)
    assert alone.returncode == 2 and failed["error"] in alone.stderr
    assert len(out["sessions"]) == 13
    bad.unlink()


def test_grid_map_errors_name_the_key(plant: dict[str, Any], tmp_path: Path) -> None:
    work = plant["work"]
    bad = tmp_path / "map.toml"
    bad.write_text('[grids]\n"cmm-99" = "x.grid"\n')
    proc = cmm_here("fleet", "replay", "plant", "--grid-map", str(bad), "--json", str(tmp_path / "o.json"),
               cwd=work, check=False)  # fmt: skip
    assert proc.returncode == 2 and "grids.cmm-99: no such machine" in proc.stderr
    bad.write_text('[grids]\n"cmm-01" = "missing.grid"\n')
    proc = cmm_here("fleet", "replay", "plant", "--grid-map", str(bad), "--json", str(tmp_path / "o.json"),
               cwd=work, check=False)  # fmt: skip
    assert (
        proc.returncode == 2
        and "grids.cmm-01" in proc.stderr
        and "no such grid file" in proc.stderr
    )
    assert not (tmp_path / "o.json").exists()
