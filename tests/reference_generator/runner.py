"""Running the public CLI on a case, as a user: ``cmm-comp diagnose MACHINE MEASUREMENTS --json OUT``.

The diagnosis runs in a child process (the installed ``cmm-comp`` next to this interpreter, else
the one on PATH); its wall time and its own CPU time are measured.
"""

from __future__ import annotations

import json
import os
import shutil
import subprocess
import sys
import threading
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from .case import Case, draw_case
from .files import write_case
from .scoring import Score, score_diagnosis


def find_cli() -> str:
    """The ``cmm-comp`` executable of this interpreter's environment, else PATH's."""
    beside = Path(sys.executable).with_name("cmm-comp")
    found = str(beside) if beside.exists() else shutil.which("cmm-comp")
    if not found:
        raise FileNotFoundError("cmm-comp not found beside the interpreter or on PATH")
    return found


@dataclass
class Run:
    """One diagnosis of one case."""

    case: Case
    output: dict[str, Any] | None
    exit_code: int | None  # None: killed at the timeout
    wall_s: float
    cpu_s: float
    stderr_tail: str
    score: Score | None

    def as_dict(self) -> dict[str, Any]:
        out = self.output or {}
        return {
            **self.case.describe(),
            "exit_code": self.exit_code,
            "wall_s": round(self.wall_s, 3),
            "cpu_s": round(self.cpu_s, 3),
            "elapsed_s": out.get("elapsed_s"),
            "heldout_rms_um": out.get("heldout_rms_um"),
            "noise_sigma_um": out.get("noise_sigma_um"),
            "found": [
                {k: e.get(k) for k in ("cause", "axis", "component", "period_mm", "law", "source")}
                for e in out.get("effects") or []
            ],
            "score": None if self.score is None else self.score.as_dict(),
            "stderr_tail": self.stderr_tail if self.exit_code != 0 else "",
        }


def diagnose_files(
    cli: str, machine: Path, measurements: Path, out: Path, timeout_s: float, env: dict[str, str]
) -> tuple[int | None, float, float, str]:
    """(exit code or None on timeout, wall s, child CPU s, stderr tail)."""
    cmd = [cli, "diagnose", str(machine), str(measurements), "--json", str(out)]
    err = out.with_suffix(".stderr.txt")
    killed = threading.Event()
    start = time.perf_counter()
    with err.open("wb") as fh:
        proc = subprocess.Popen(cmd, stdout=subprocess.DEVNULL, stderr=fh, env=env)

    def stop() -> None:
        killed.set()
        proc.kill()

    watchdog = threading.Timer(timeout_s, stop)
    watchdog.start()
    try:
        _, status, usage = os.wait4(proc.pid, 0)  # reaps the child and gives its own CPU time
    finally:
        watchdog.cancel()
    wall = time.perf_counter() - start
    proc.returncode = os.waitstatus_to_exitcode(status)
    code = None if killed.is_set() else proc.returncode
    cpu = usage.ru_utime + usage.ru_stime
    return code, wall, cpu, err.read_text(errors="replace")[-800:]


def run_case(
    family: str,
    variant: str,
    seed: int,
    workdir: Path,
    cli: str | None = None,
    timeout_s: float = 300.0,
    env: dict[str, str] | None = None,
) -> Run:
    """Draw the case, write it into ``workdir``, diagnose it and score the JSON."""
    case = draw_case(family, variant, seed)
    machine, meas = write_case(case, workdir)
    out = workdir / "diagnosis.json"
    code, wall, cpu, tail = diagnose_files(
        cli or find_cli(), machine, meas, out, timeout_s, dict(env or os.environ)
    )
    output: dict[str, Any] | None = None
    score: Score | None = None
    if code == 0 and out.exists():
        output = json.loads(out.read_text(encoding="utf-8"))
        score = score_diagnosis(case.hidden, output)
    return Run(case, output, code, wall, cpu, tail, score)
