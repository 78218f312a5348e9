"""The README as a newcomer uses it (issue 25, item 9).

* The main job's install is ``pip install -e .`` (no test extras) and the demo then runs: the
  demo is run in a process where every module the test extras install cannot be imported (the
  names come from pyproject's ``test`` extra, mapped to import names by the installed
  distributions' own records).
* ``.ci/run`` runs the README's test command (the same install target and pytest invocation).
* "Your own machine" runs exactly as printed (read from README.md), its outputs read back with
  independent readers; the daemon's ``init`` line when this build has it, never the start line
  (it runs until stopped on a real bus). Its two ``calibrate`` lines are the calibration worked
  example's, character for character: they run once per test run for both pages
  (tests/worked_example.py) and their outputs are copied here.
* The real-data lines run as printed against the public repository's layout (the clone is laid
  out from the project's checkout, ``../shared/realdata``; skipped without it).
* The tables of what is where name files that exist; LICENSE is the Apache-2.0 text pyproject
  declares (checked against the canonical file's MD5, an outside fact); the CHANGELOG's
  released version is pyproject's, under an Unreleased section.
"""

from __future__ import annotations

import csv
import hashlib
import importlib.metadata as md
import json
import re
import subprocess
import sys
import tomllib
from pathlib import Path

import pytest
from doc_commands import bash_blocks, run_cli
from ess_record import ess_x, readme_lines
from matplotlib.image import imread
from worked_example import LINES, calibrated_example, take

from cmm_comp.compensation import CorrectionGrid

ROOT = Path(__file__).resolve().parents[1]
README = ROOT / "README.md"
#: MD5 of https://www.apache.org/licenses/LICENSE-2.0.txt (11,358 bytes)
APACHE_2_MD5 = "3b83ef96387f14655fc854ddc3c6bd57"


def _pyproject() -> dict:
    return tomllib.loads((ROOT / "pyproject.toml").read_text(encoding="utf-8"))


def _first_block() -> list[str]:
    return bash_blocks(README)[0]


def _block_with(start: str) -> list[str]:
    """The one README block with a line starting ``start``."""
    (block,) = [b for b in bash_blocks(README) if any(line.startswith(start) for line in b)]
    return block


# ------------------------------------------------------------------ the two commands


def test_the_two_commands_come_first_main_job_without_test_extras() -> None:
    main_job, tests = _first_block()
    assert "pip install -e . " in main_job + " " and "[test]" not in main_job
    assert main_job.endswith("cmm-comp demo")
    assert "pip install -e '.[test]'" in tests and "bin/python -m pytest -q" in tests
    text = README.read_text(encoding="utf-8")
    assert text.index("```bash") < text.index("## Your own machine") < text.index("## What is")
    assert "Python ≥ 3.11" in text
    assert _pyproject()["project"]["requires-python"] == ">=3.11"


def test_ci_runs_the_readme_test_command() -> None:
    ci = (ROOT / ".ci" / "run").read_text(encoding="utf-8")
    _, tests = _first_block()
    install = re.search(r"pip install (-e '\.\[test\]')", tests)
    assert install is not None and f"install --quiet {install[1]}" in ci
    pytest = re.search(r"(python -m pytest .*)$", tests)
    assert pytest is not None, tests
    assert re.search(rf"^{re.escape(pytest[1])}\b", ci, flags=re.M), f"CI must run {pytest[1]}"


def _test_extra_imports() -> list[str]:
    """Top-level import names installed by the ``test`` extra's distributions."""
    extras = _pyproject()["project"]["optional-dependencies"]["test"]
    wanted = {re.split(r"[<>=!~\[ ;]", e)[0].lower().replace("_", "-") for e in extras}
    names = [
        top
        for top, dists in md.packages_distributions().items()
        if any(d.lower().replace("_", "-") in wanted for d in dists)
    ]
    assert {"pytest", "hypothesis", "cantools", "foxglove"} <= set(names)  # the map works
    return sorted(names)


@pytest.mark.timeout(300)
def test_demo_imports_nothing_from_the_test_extras(tmp_path: Path) -> None:
    blocked = _test_extra_imports()
    code = f"""
import importlib.abc, sys
BLOCKED = {blocked!r}
class Block(importlib.abc.MetaPathFinder):
    def find_spec(self, name, path=None, target=None):
        if name.split(".")[0] in BLOCKED and name not in sys.modules:
            raise ImportError(f"{{name}} is a test extra: the main job must not need it")
sys.meta_path.insert(0, Block())
from cmm_comp.cli.main import main
sys.exit(main(["demo", "--json", sys.argv[1]]))
"""
    out = tmp_path / "demo.json"
    run = subprocess.run(
        [sys.executable, "-c", code, str(out)], cwd=tmp_path, capture_output=True, text=True,
        timeout=280,
    )  # fmt: skip
    assert run.returncode == 0, run.stderr[-2000:]
    summary = json.loads(out.read_text())
    assert summary["e0_after_um"] * 10 <= summary["e0_before_um"]


# ------------------------------------------------------------------ your own machine


@pytest.mark.timeout(1800)
def test_your_own_machine_runs_as_printed(
    tmp_path: Path, tmp_path_factory: pytest.TempPathFactory
) -> None:
    (tmp_path / "examples").symlink_to(ROOT / "examples", target_is_directory=True)
    lines = _block_with("cmm-comp calibrate examples/")
    ran = []
    for line in lines:
        if line.startswith("cmm-comp daemon --config"):
            continue  # starts the daemon on the user's bus: runs until stopped
        if line.startswith("cmm-comp daemon init") and _lacks("daemon", "init"):
            continue  # comes with issue 25 item 5 (daemon init): run once it is merged
        if line in LINES:  # the worked example's line: run once per test run, outputs copied
            shared = take(line, calibrated_example(tmp_path_factory), tmp_path)
            code, err = shared["code"], shared["err"]
        else:
            run = run_cli(line, tmp_path)
            print(f"{run.wall_s:7.1f} s wall {run.cpu_s:7.1f} s CPU  {line}")
            code, err = run.code, run.err
        assert code == 0, f"{line}\n{err}"
        ran.append(line)
    assert len(ran) >= 8
    calibration = json.loads((tmp_path / "calibration-report" / "calibration.json").read_text())
    assert calibration["model"] and calibration["errors"] and calibration["gauge"]
    assert json.loads((tmp_path / "plan.json").read_text())  # the planner's prediction
    summary = json.loads((tmp_path / "report" / "summary.json").read_text())
    assert len(summary["diagonals_um"]) == 4
    for png in ("report/map.png", "report/parametric_errors.png", "e0.png"):
        assert imread(tmp_path / png).shape[0] > 100, png
    assert json.loads((tmp_path / "e0.json").read_text())["monte_carlo"]["stable"] is True
    grid = CorrectionGrid.load(tmp_path / "machine.grid")
    assert grid.has_uncertainty
    with open(tmp_path / "corrected.csv", newline="") as fh:
        rows = list(csv.DictReader(fh))
    assert len(rows) == 5 and all(r["status"] == "ok" and r["Ux_um"] for r in rows)
    export = json.loads((tmp_path / "export" / "export.json").read_text())
    assert export  # the controller's tables and what they leave
    assert any(p.suffix != ".json" for p in (tmp_path / "export").iterdir())


def _lacks(command: str, sub: str) -> bool:
    """Whether this build's ``cmm-comp COMMAND`` has no subcommand ``sub``."""
    import argparse

    from cmm_comp.cli.main import build_parser

    def subcommands(parser: argparse.ArgumentParser) -> dict[str, argparse.ArgumentParser]:
        for action in parser._actions:  # argparse keeps subparsers only here
            if isinstance(action, argparse._SubParsersAction):
                return dict(action.choices)
        return {}

    parent = subcommands(build_parser()).get(command)
    return parent is None or sub not in subcommands(parent)


# ------------------------------------------------------------------ real data


@pytest.mark.realdata
@pytest.mark.timeout(900)
def test_real_data_lines_run_as_printed(
    realdata_dir: Path, tmp_path_factory: pytest.TempPathFactory
) -> None:
    """The public repository's layout at the named commit, laid out from the project's own
    checkout of the same files; the git lines are the user's, the cmm-comp lines run here (once
    per test run, shared with the other tests of this record: tests/ess_record.py)."""
    lines = _block_with("git clone")
    assert lines == readme_lines()
    clone, folder = re.match(r"git clone (\S+) (\S+)", lines[0]).groups()  # type: ignore[union-attr]
    assert clone == "https://github.com/anderssandstrom/ecmc_target_muts_logger"
    assert lines[1] == f"git -C {folder} checkout ee350e4c813139fde4608dd0edd331f8d3546028"
    work, runs = ess_x(tmp_path_factory, realdata_dir)
    assert list(runs["lines"]) == lines[2:]
    for line, run in runs["lines"].items():
        assert run["code"] == 0, f"{line}\n{run['err']}"
    d = json.loads((work / "ess-x" / "diagnosis.json").read_text())
    causes = {(e["cause"], e.get("component") or e.get("axis")) for e in d["effects"]}
    assert {("parametric", "dx_x"), ("reversal", "x")} <= causes
    assert (work / "ess-x" / "report" / "index.html").is_file()


# ------------------------------------------------------------------ tables, licence, changelog


def test_what_is_where_names_files_that_exist() -> None:
    text = README.read_text(encoding="utf-8")
    section = text[text.index("## What is here") : text.index("## Command line")]
    paths = set(
        re.findall(r"`((?:compensation|protocol|daemon|sim_controller|cli)/[^`\s]*)`", section)
    )
    assert len(paths) > 30
    missing = sorted(p for p in paths if not (ROOT / p.rstrip("/")).exists())
    assert not missing, missing
    for doc in re.findall(r"\]\((docs/[^)#]+)", text):
        assert (ROOT / doc).is_file(), doc
    for bench in re.findall(r"`benchmarks/(bench_\w+\.py)`", text):
        assert (ROOT / "benchmarks" / bench).is_file(), bench


def test_license_is_the_apache_2_text_pyproject_declares() -> None:
    assert _pyproject()["project"]["license"] == {"text": "Apache-2.0"}
    data = (ROOT / "LICENSE").read_bytes()
    assert hashlib.md5(data).hexdigest() == APACHE_2_MD5


def test_changelog_releases_the_version_pyproject_declares() -> None:
    text = (ROOT / "CHANGELOG.md").read_text(encoding="utf-8")
    headings = re.findall(r"^## \[([^\]]+)\]", text, flags=re.M)
    assert headings[0] == "Unreleased"
    assert headings[1] == _pyproject()["project"]["version"]
    assert re.search(r"^## \[" + re.escape(headings[1]) + r"\] - \d{4}-\d{2}-\d{2}$", text, re.M)
