"""A pytest plugin: the CPU time each test spends, its own and its children's.

``PYTHONPATH=tests python -m pytest -p cpu_durations`` (the plugin is loaded before pytest puts
tests/ on ``sys.path``) prints the tests that used the most CPU, and writes every test's figures
to the JSON file named by ``CMM_COMP_CPU_DURATIONS`` when set. CPU time, unlike
``--durations``' wall time, barely moves with the machine's load, so figures from a shared
2-core machine compare across runs. Under pytest-xdist (``-n 2``) each worker writes
``<name>.<worker>.json`` beside that file when its session ends, and the controller (which runs
no test) merges them into the file and prints the same summary.

A test's CPU is this process's ``time.process_time()`` over setup + call + teardown, plus the
user + system time of the child processes it waited for (``RUSAGE_CHILDREN``: a child that is
never waited for is not counted). Session and module fixtures count in the first test that
needs them.
"""

from __future__ import annotations

import json
import os
import resource
import time
from collections.abc import Generator
from pathlib import Path
from typing import Any

import pytest

ENV = "CMM_COMP_CPU_DURATIONS"
SHOWN = 40

_figures: dict[str, dict[str, float]] = {}


def _children_s() -> float:
    usage = resource.getrusage(resource.RUSAGE_CHILDREN)
    return usage.ru_utime + usage.ru_stime


@pytest.hookimpl(hookwrapper=True)
def pytest_runtest_protocol(item: pytest.Item, nextitem: Any) -> Generator[None, None, None]:
    own0, kids0, wall0 = time.process_time(), _children_s(), time.perf_counter()
    yield
    _figures[item.nodeid] = {
        "own_s": time.process_time() - own0,
        "children_s": _children_s() - kids0,
        "wall_s": time.perf_counter() - wall0,
    }


def _worker_file(out: Path, worker: str) -> Path:
    return out.with_name(f"{out.stem}.{worker}{out.suffix}")


def pytest_sessionfinish(session: pytest.Session) -> None:
    out, worker = os.environ.get(ENV), os.environ.get("PYTEST_XDIST_WORKER")
    if out and worker:
        _worker_file(Path(out), worker).write_text(json.dumps(_figures))


def pytest_terminal_summary(terminalreporter: Any) -> None:
    out = os.environ.get(ENV)
    if not _figures and out:  # the xdist controller: its workers' files
        for part in sorted(Path(out).parent.glob(_worker_file(Path(out), "gw*").name)):
            _figures.update(json.loads(part.read_text()))
            part.unlink()
    if not _figures:
        return
    total = {k: sum(f[k] for f in _figures.values()) for k in ("own_s", "children_s", "wall_s")}
    rows = sorted(_figures.items(), key=lambda kv: -(kv[1]["own_s"] + kv[1]["children_s"]))
    tr = terminalreporter
    tr.write_sep("=", f"CPU time: {SHOWN} most expensive tests")
    tr.write_line(f"{'cpu_s':>8} {'own_s':>8} {'child_s':>8} {'wall_s':>8}  test")
    for nodeid, f in rows[:SHOWN]:
        cpu = f["own_s"] + f["children_s"]
        tr.write_line(
            f"{cpu:8.2f} {f['own_s']:8.2f} {f['children_s']:8.2f} {f['wall_s']:8.2f}  {nodeid}"
        )
    tr.write_line(
        f"total: own {total['own_s']:.1f} s + children {total['children_s']:.1f} s CPU, "
        f"{total['wall_s']:.1f} s wall over {len(_figures)} tests"
    )
    if out:
        Path(out).write_text(json.dumps(_figures, indent=1, sort_keys=True) + "\n")
