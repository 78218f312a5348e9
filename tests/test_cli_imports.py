"""Each ``cmm-comp`` command imports only what it uses (whole processes, ``-X importtime``).

``cmm-comp --help`` must not load numpy; the model commands must not load the bus and logging
stack (python-can, pymodbus, mcap) nor numba (only the grid, the virtual CMM and the
diagnosis' period scans need it).
"""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
NPL = ROOT / "examples" / "machines" / "npl-bridge.toml"


def _imports_of(python_args: list[str], cwd: Path) -> set[str]:
    """Top-level names of every module a ``python -X importtime …`` process imported."""
    run = subprocess.run(
        [sys.executable, "-X", "importtime", *python_args],
        capture_output=True,
        text=True,
        cwd=cwd,
        timeout=120,
    )
    assert run.returncode == 0, run.stderr[-2000:]
    return {
        line.rsplit("|", 1)[1].strip().split(".")[0]
        for line in run.stderr.splitlines()
        if line.startswith("import time:") and "|" in line
    }


def _top_level_imports(args: list[str], cwd: Path) -> set[str]:
    return _imports_of(["-m", "cmm_comp.cli", *args], cwd)


def test_help_loads_no_numerical_library(tmp_path: Path) -> None:
    names = _top_level_imports(["--help"], tmp_path)
    assert "cmm_comp" in names  # the parser did run
    assert not names & {"numpy", "scipy", "can", "pymodbus", "mcap", "numba", "matplotlib"}


@pytest.mark.parametrize(
    "args",
    [
        ["map", str(NPL), "--out", "m.csv", "--steps", "4", "4", "4"],
        ["diagonals", str(NPL)],
    ],
    ids=["map", "diagonals"],
)
def test_model_commands_do_not_load_the_bus_stack(tmp_path: Path, args: list[str]) -> None:
    names = _top_level_imports(args, tmp_path)
    assert "numpy" in names  # the command did its work
    assert not names & {"can", "pymodbus", "mcap", "numba"}, sorted(names)


def test_the_import_parser_sees_a_heavy_import(tmp_path: Path) -> None:
    """The checks above can fail: an import of python-can is seen."""
    assert {"can", "numpy"} <= _imports_of(["-c", "import can, numpy"], tmp_path)


def test_help_lists_the_ten_models(tmp_path: Path) -> None:
    from cmm_comp.compensation import MODEL_ALIASES, MODEL_CHAINS

    run = subprocess.run(
        [sys.executable, "-m", "cmm_comp.cli", "--help"],
        capture_output=True,
        text=True,
        cwd=tmp_path,
        timeout=60,
    )
    assert run.returncode == 0, run.stderr
    for alias, code in MODEL_ALIASES.items():
        assert any(line.split()[:2] == [code, alias] for line in run.stdout.splitlines()), code
    assert len(MODEL_ALIASES) == len(MODEL_CHAINS) == 10
