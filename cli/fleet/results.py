"""OUT of ``fleet diagnose`` and ``fleet replay``: the per-machine sections and the final write.

``fleet diagnose``: per machine :func:`cmm_comp.compensation.trend.machine_trend` of its
sessions' ``effects``; ``--report DIR`` adds the plots (:mod:`.report`). ``fleet replay``: per
machine the totals of its sessions' replay reports (readings, status changes, the largest
difference and the RMS over every compared reading, U where known). docs/formats.md §11.
"""

from __future__ import annotations

import argparse
import json
import math
from collections.abc import Callable
from pathlib import Path
from typing import Any

from .discover import Job
from .engine import FleetRun
from .store import ResultStore, write_out
from .tasks import file_sha256

__all__ = ["diagnose_finish", "grid_still_valid", "replay_finish", "replay_totals"]


def diagnose_finish(
    args: argparse.Namespace, jobs: list[Job], run: FleetRun, store: ResultStore, settings: Any
) -> None:
    """Write OUT (and the report) of ``fleet diagnose``."""
    from cmm_comp.compensation.trend import SessionEffects, machine_trend

    def section(machine: str, group: list[tuple[Job, dict[str, Any]]]) -> dict[str, Any]:
        sessions = [
            SessionEffects(job.day, job.path, diagnosis.get("effects", []))
            for job, diagnosis in group
            if job.day is not None
        ]
        return machine_trend(machine, sessions, settings)

    extra = {"failed": run.failed, "run": run.stats()}
    write_out(args.json, "diagnosis", jobs, run.keys, store, section, extra)
    if args.report:
        from .report import write_fleet_report

        with open(args.json, encoding="utf-8") as fh:
            machines = json.load(fh)["machines"]
        write_fleet_report(machines, Path(args.report))


def replay_totals(reports: list[dict[str, Any]]) -> dict[str, Any]:
    """One machine's totals over its sessions' replay reports (``cmm-comp replay --json``)."""
    compared = sum(int(r["compared"]) for r in reports)
    squares = sum(
        int(r["compared"]) * float(r["rms_diff_um"]) ** 2
        for r in reports
        if r["compared"] and r["rms_diff_um"] is not None
    )
    maxima = [r["max_abs_diff_um"] for r in reports if r["max_abs_diff_um"] is not None]
    u_maxima = [r["max_abs_u_diff_um"] for r in reports if r["max_abs_u_diff_um"] is not None]
    status: dict[str, int] = {}
    for r in reports:
        for k, v in r["status_differ"].items():
            status[k] = status.get(k, 0) + int(v)
    return {
        "sessions": len(reports),
        "truncated_sessions": sum(bool(r["truncated"]) for r in reports),
        "readings": sum(int(r["readings"]) for r in reports),
        "compared": compared,
        "max_abs_diff_um": max(maxima) if maxima else None,
        "rms_diff_um": math.sqrt(squares / compared) if compared else None,
        "status_agree": sum(int(r["status_agree"]) for r in reports),
        "status_differ": dict(sorted(status.items())),
        "uncertainty_compared": sum(int(r["uncertainty_compared"]) for r in reports),
        "max_abs_u_diff_um": max(u_maxima) if u_maxima else None,
        "uncertainty_mismatch": sum(int(r["uncertainty_mismatch"]) for r in reports),
        "grids": sorted({str(r["grid_sha256"]) for r in reports}),
    }


def replay_finish(
    args: argparse.Namespace, jobs: list[Job], run: FleetRun, store: ResultStore
) -> None:
    """Write OUT of ``fleet replay``."""

    def section(_machine: str, group: list[tuple[Job, dict[str, Any]]]) -> dict[str, Any]:
        return replay_totals([report for _job, report in group])

    extra = {"failed": run.failed, "run": run.stats()}
    write_out(args.json, "replay", jobs, run.keys, store, section, extra)


def grid_still_valid() -> Callable[[dict[str, Any]], bool]:
    """A stored replay stays valid while the grid file it used is unchanged (a session
    replayed with its own grid names the grid by path in the log: its bytes are not in the
    key). File hashes are computed once per path per run."""
    seen: dict[str, str | None] = {}

    def check(entry: dict[str, Any]) -> bool:
        report = json.loads(entry["json"])
        path = str(report["grid_path"])
        if path not in seen:
            try:
                seen[path] = file_sha256(path)
            except OSError:
                seen[path] = None
        return seen[path] is not None and seen[path] == entry.get("grid_file_sha256")

    return check
