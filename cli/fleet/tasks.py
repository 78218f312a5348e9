"""What a Dask worker runs for one session, and the code fingerprint of this installation.

:func:`diagnose_task` and :func:`replay_task` call exactly what ``cmm-comp diagnose`` and
``cmm-comp replay`` call (:func:`cmm_comp.cli.diagnosis.run_diagnosis`,
:func:`cmm_comp.cli.sessionlog.replay.replay_offline`) and return a small dict: ``ok``, the
result as the JSON text the one-by-one command writes (``json``), or the one-line ``error`` it
would print; the machine's load ``warnings``; and the timings the benchmark and the overhead
figures use (``compute_s`` wall and ``cpu_s`` CPU time inside the task, ``pid``). A bad file is
an answer, not an exception: the fleet goes on.

:func:`code_fingerprint` is part of every result's key (a change of the code re-runs the
sessions) and is compared between the client and every worker before a run.
"""

from __future__ import annotations

import functools
import hashlib
import json
import os
import platform
import sys
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

__all__ = ["code_fingerprint", "diagnose_task", "file_sha256", "replay_task"]

#: Packages whose source makes a result: a change in any of them invalidates stored results.
_PACKAGES = ("compensation", "protocol", "daemon")
#: The CLI's own modules that a task runs (the rest of the CLI only orchestrates).
_CLI_FILES = ("common.py", "diagnosis.py", "fleet/tasks.py")
#: Libraries whose version can change the numbers.
_LIBRARIES = ("numpy", "scipy", "numba", "mcap", "pydantic", "msgspec")


@functools.cache
def code_fingerprint() -> str:
    """SHA-256 over the source that computes a result (every ``.py`` file of the packages of
    :data:`_PACKAGES` and the CLI files of :data:`_CLI_FILES`, path and bytes) and the versions
    of Python and :data:`_LIBRARIES`."""
    from importlib import import_module
    from importlib.metadata import PackageNotFoundError, version

    digest = hashlib.sha256()
    for name in _PACKAGES:
        root = Path(str(import_module(f"cmm_comp.{name}").__file__)).parent
        for path in sorted(root.rglob("*.py")):
            if name == "compensation" and path.parent.name == "trend":
                continue  # trends are computed when OUT is written, never stored
            digest.update(f"{name}/{path.relative_to(root).as_posix()}\0".encode())
            digest.update(path.read_bytes())
    cli = Path(__file__).resolve().parents[1]
    for rel in _CLI_FILES:
        digest.update(f"cli/{rel}\0".encode())
        digest.update((cli / rel).read_bytes())
    parts = [platform.python_version()]
    for lib in _LIBRARIES:
        try:
            parts.append(f"{lib}={version(lib)}")
        except PackageNotFoundError:
            parts.append(f"{lib}=-")
    digest.update("\0".join(parts).encode())
    return digest.hexdigest()


def file_sha256(path: str | Path) -> str:
    """SHA-256 of a file's bytes (read in 1 MiB blocks)."""
    digest = hashlib.sha256()
    with open(path, "rb") as fh:
        while block := fh.read(1 << 20):
            digest.update(block)
    return digest.hexdigest()


def _timed(work: Callable[[list[str]], dict[str, Any]]) -> dict[str, Any]:
    warnings: list[str] = []
    t0, c0 = time.perf_counter(), time.process_time()
    out = work(warnings)
    out.update(
        warnings=warnings,
        compute_s=time.perf_counter() - t0,
        cpu_s=time.process_time() - c0,
        pid=os.getpid(),
        fingerprint=code_fingerprint(),
    )
    return out


def diagnose_task(machine_toml: str, measurements_csv: str) -> dict[str, Any]:
    """``cmm-comp diagnose MACHINE MEASUREMENTS --json OUT`` on a worker (module docstring)."""
    from cmm_comp.compensation import CmmCompError

    from ..diagnosis import run_diagnosis

    def work(warnings: list[str]) -> dict[str, Any]:
        try:
            diagnosis = run_diagnosis(machine_toml, measurements_csv, warn=warnings.append)
        except (CmmCompError, OSError, ValueError) as exc:
            return {"ok": False, "error": str(exc)}
        try:  # the same refusal as write_json_atomic: standard JSON only
            text = json.dumps(diagnosis.to_json(), default=float, allow_nan=False)
        except ValueError:
            return {"ok": False, "error": "a figure to write is not a finite number"}
        return {"ok": True, "json": text}

    return _timed(work)


def replay_task(source: str, grid: str | None) -> dict[str, Any]:
    """``cmm-comp replay SOURCE [--grid GRID] --json OUT`` on a worker (module docstring); also
    returns ``grid_file_sha256``, the SHA-256 of the grid file used (a stored result of a
    session replayed with its own grid stays valid only while that file is unchanged)."""
    from cmm_comp.cli.sessionlog.replay import ReplayError, replay_offline

    def work(warnings: list[str]) -> dict[str, Any]:
        try:
            report = replay_offline(source, grid)
            grid_sha = file_sha256(report.grid_path)
        except (ReplayError, ValueError, OSError) as exc:
            return {"ok": False, "error": str(exc)}
        if report.warning:
            warnings.append(report.warning)
        return {"ok": True, "json": json.dumps(report.as_dict()), "grid_file_sha256": grid_sha}

    return _timed(work)


def worker_fingerprint() -> dict[str, str]:
    """Run on each worker before a fleet run: its code fingerprint and Python executable."""
    return {"fingerprint": code_fingerprint(), "python": sys.executable}
