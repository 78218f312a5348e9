"""The README's real-data lines (the dense ESS X record: ``import camonitor`` + ``diagnose``
with its report), run once per test run and shared.

The diagnosis of that record costs ~30 s of CPU, and three tests read it: the README's lines run
as printed (tests/test_readme.py), the plots of a one-axis record (tests/test_reading_outputs.py)
and what the diagnosis names in it (tests/test_camonitor_import.py can use it too: the same two
commands on the same file). :func:`ess_x` runs the two README lines once per test run
(tests/README.md rule 3: under a file lock in the run's common temporary folder; the first
pytest-xdist worker runs them, the others reuse the folder) in the layout of the public
repository's clone (``ess-data/b02/x/rawdata/x_230_2.log``, a link to ``../shared/realdata``),
through the CLI's own ``main()``. While they run, every figure the plotting writes through
``save_png`` is described in ``figures.json`` (file name, each visible panel's title and whether
it shows data): a matplotlib figure cannot cross a process, its description can.
"""

from __future__ import annotations

import fcntl
import json
import os
import re
import shutil
from pathlib import Path
from typing import Any

import numpy as np
from doc_commands import bash_blocks, run_cli

__all__ = ["ess_x", "panel_shows_data", "readme_lines"]

ROOT = Path(__file__).resolve().parents[1]
LOG = Path("ess-target-b02") / "x_230_2.log"
"""The record, under the real-data folder."""
_DONE = "runs.json"


def readme_lines() -> list[str]:
    """The README block with the ``git clone`` line (the real-data lines), as printed."""
    (block,) = [
        b for b in bash_blocks(ROOT / "README.md") if any(x.startswith("git clone") for x in b)
    ]
    return block


def panel_shows_data(ax: Any) -> bool:
    """A panel shows something when a line varies or a filled area / bar / image is drawn."""
    for line in ax.get_lines():
        y = np.asarray(line.get_ydata(), dtype=float)
        if y.size and np.ptp(y[np.isfinite(y)]) > 0:
            return True
    return bool(ax.collections or ax.patches or ax.images)


def _describe(fig: Any, path: Any) -> dict[str, Any]:
    panels = [ax for ax in fig.axes if ax.get_visible()]
    return {
        "file": Path(path).name,
        "first_title": fig.axes[0].get_title() if fig.axes else "",
        "panels": [{"title": ax.get_title(), "shows_data": panel_shows_data(ax)} for ax in panels],
    }


def _run_lines(work: Path, realdata: Path, lines: list[str]) -> dict[str, Any]:
    from cmm_comp.compensation.reports import plots

    clone, folder = re.match(r"git clone (\S+) (\S+)", lines[0]).groups()  # type: ignore[union-attr]
    layout = work / folder / "b02" / "x" / "rawdata"
    layout.mkdir(parents=True)
    (layout / LOG.name).symlink_to(realdata / LOG)
    described: list[dict[str, Any]] = []
    real = plots.save_png

    def keep(fig: Any, path: Any) -> Path:
        described.append(_describe(fig, path))
        return real(fig, path)

    runs: dict[str, Any] = {"clone": clone, "lines": {}}
    plots.save_png = keep  # restored below (tests/README.md rule 5)
    try:
        for line in lines[2:]:
            described.clear()
            run = run_cli(line, work)
            runs["lines"][line] = {
                "code": run.code, "out": run.out, "err": run.err, "cpu_s": run.cpu_s,
                "figures": list(described),
            }  # fmt: skip
    finally:
        plots.save_png = real
    return runs


def ess_x(tmp_path_factory: Any, realdata: Path) -> tuple[Path, dict[str, Any]]:
    """The folder where the README's real-data lines ran (the clone's layout inside it), and
    their record: per line its exit code, stdout, stderr, CPU seconds and the figures it
    wrote."""
    base = tmp_path_factory.getbasetemp()
    shared = base.parent if os.environ.get("PYTEST_XDIST_WORKER") else base
    work = shared / "ess-x-record"
    with open(shared / "ess-x-record.lock", "w") as lock:
        fcntl.flock(lock, fcntl.LOCK_EX)
        if not (work / _DONE).is_file():
            shutil.rmtree(work, ignore_errors=True)  # a half-built one (a killed worker)
            work.mkdir()
            runs = _run_lines(work, realdata, readme_lines())
            (work / _DONE).write_text(json.dumps(runs, indent=1))
    return work, json.loads((work / _DONE).read_text())
