"""The calibration worked example's two ``cmm-comp calibrate`` lines, run once per test run.

README.md ("Your own machine") and docs/calibration.md (§1, the worked example) print the same
two lines on the shipped ``examples/calibration/`` files: ``calibrate`` (~45 s of CPU) and
``calibrate plan`` (~30 s). Both pages are run as printed by their tests
(tests/test_readme.py, tests/test_calibration_example.py); running the same deterministic
commands on the same inputs twice per run checks nothing more. :func:`calibrated_example` runs
them once per test run (tests/README.md rule 3: the first pytest-xdist worker, under a file lock
in the run's common temporary folder; the others reuse the folder) through the CLI's own
``main()`` (:func:`doc_commands.run_cli`), from a folder laid out like the repository's root
(``examples/`` as shipped), and :func:`take` copies a line's outputs into a test's folder. A
page whose line differs from :data:`LINES` by a character runs its own line instead (the caller
checks ``line in LINES``), so a page can never be "tested" with a command it does not print.
"""

from __future__ import annotations

import fcntl
import json
import os
import shutil
from pathlib import Path
from typing import Any

from doc_commands import run_cli

__all__ = ["LINES", "calibrated_example", "take"]

ROOT = Path(__file__).resolve().parents[1]

LINES: dict[str, tuple[str, ...]] = {
    "cmm-comp calibrate examples/calibration/calibration.toml -o machine.toml "
    "--report calibration-report": ("machine.toml", "calibration-report"),
    "cmm-comp calibrate plan examples/calibration/calibration.toml "
    "--machine examples/calibration/truth.toml --json plan.json": ("plan.json",),
}
"""Each shared line, exactly as the pages print it, and what it writes (files or folders)."""

_DONE = "runs.json"


def calibrated_example(tmp_path_factory: Any) -> Path:
    """The folder where every line of :data:`LINES` ran (with ``runs.json``: each line's exit
    code, stderr, wall and CPU seconds); built by the first caller of the test run."""
    base = tmp_path_factory.getbasetemp()
    shared = base.parent if os.environ.get("PYTEST_XDIST_WORKER") else base
    work = shared / "calibration-worked-example"
    with open(shared / "calibration-worked-example.lock", "w") as lock:
        fcntl.flock(lock, fcntl.LOCK_EX)
        if not (work / _DONE).is_file():
            shutil.rmtree(work, ignore_errors=True)  # a half-built one (a killed worker)
            work.mkdir()
            (work / "examples").symlink_to(ROOT / "examples", target_is_directory=True)
            runs = {}
            for line in LINES:
                run = run_cli(line, work)
                runs[line] = {
                    "code": run.code, "err": run.err, "wall_s": run.wall_s, "cpu_s": run.cpu_s,
                }  # fmt: skip
            (work / _DONE).write_text(json.dumps(runs, indent=1))
    return work


def take(line: str, work: Path, dst: Path) -> dict[str, Any]:
    """Copy what ``line`` (one of :data:`LINES`) wrote in ``work`` into ``dst``; its run record
    (``code``, ``err``, ``wall_s``, ``cpu_s``)."""
    for name in LINES[line]:
        src = work / name
        if src.is_dir():
            shutil.copytree(src, dst / name)
        elif src.exists():
            shutil.copy2(src, dst / name)
    record: dict[str, Any] = json.loads((work / _DONE).read_text())[line]
    return record
