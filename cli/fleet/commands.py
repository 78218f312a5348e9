"""``cmm-comp fleet diagnose|replay|generate``: argument parsing and the three handlers.

Exit codes: 0 every session done; 1 some sessions failed (each named on stderr and in OUT's
``failed``; the others are in OUT); 2 bad input to the command itself (ROOT, the grid map, a
flag) or Dask missing (the message says how to install it). docs/fleet.md, docs/formats.md §11.
"""

from __future__ import annotations

import argparse
import sys
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from ..common import fail

__all__ = ["add_parsers"]


def _cluster_flags(p: argparse.ArgumentParser) -> None:
    g = p.add_mutually_exclusive_group()
    g.add_argument(
        "--workers",
        type=int,
        metavar="N",
        help="worker processes of the embedded Dask LocalCluster, one thread each (default 2)",
    )
    g.add_argument(
        "--scheduler", metavar="ADDRESS", help="use the Dask scheduler at ADDRESS (tcp://host:port)"
    )
    p.add_argument(
        "--window",
        type=int,
        metavar="K",
        help="tasks submitted at a time (default 2 × worker threads + 1): bounds memory",
    )
    p.add_argument("--quiet", action="store_true", help="no progress lines")


def add_parsers(subparsers: Any) -> None:
    """Register ``fleet`` and its subcommands on an argparse subparsers object."""
    p = subparsers.add_parser(
        "fleet",
        help="diagnose or replay every session of a fleet of machines on Dask; trends",
        description="Run `diagnose` or `replay` on every session under ROOT/<machine>/ on a "
        "Dask cluster (an embedded LocalCluster, or --scheduler), store each result keyed by "
        "the content of its inputs (a re-run skips finished sessions), and summarise per "
        "machine. docs/fleet.md",
    )
    sub = p.add_subparsers(dest="fleet_command", required=True, metavar="FLEET_COMMAND")
    d = sub.add_parser(
        "diagnose",
        help="diagnose every ROOT/<machine>/<date>/ session; trends and changes per machine",
    )
    d.add_argument("root", metavar="ROOT", help="fleet directory: ROOT/<machine>/<date>/")
    d.add_argument("--json", required=True, metavar="OUT", help="output JSON (formats.md §11)")
    d.add_argument("--report", metavar="DIR", help="PNG plots of the trends and index.html")
    d.add_argument(
        "--alpha",
        type=float,
        default=0.01,
        help="false-alarm rate per effect of the change tests (default 0.01)",
    )
    _cluster_flags(d)
    d.set_defaults(handler=cmd_diagnose)
    r = sub.add_parser(
        "replay", help="re-correct every session log under ROOT/<machine>/ (offline replay)"
    )
    r.add_argument("root", metavar="ROOT", help="fleet directory: *.mcap under ROOT/<machine>/")
    r.add_argument("--grid-map", metavar="MAP.toml", help="[grids] machine = GRID (new grids)")
    r.add_argument("--json", required=True, metavar="OUT", help="output JSON (formats.md §11)")
    _cluster_flags(r)
    r.set_defaults(handler=cmd_replay)
    from .generate import add_generate_parser

    add_generate_parser(sub)


def _check_root(root: str) -> Path | None:
    """ROOT resolved, or None after saying what is wrong (Dask missing is said first)."""
    from .engine import DaskMissing, import_distributed

    try:
        import_distributed()
    except DaskMissing as exc:
        fail(str(exc))
        return None
    path = Path(root)
    if not path.is_dir():
        fail(f"fleet: {root}: no such directory (ROOT holds one directory per machine)")
        return None
    return path.resolve()


def _check_flags(args: argparse.Namespace) -> str | None:
    if args.workers is not None and args.workers < 1:
        return f"--workers {args.workers}: at least 1"
    if args.window is not None and args.window < 1:
        return f"--window {args.window}: at least 1"
    return None


def _say(command: str, quiet: bool = False) -> Any:
    def say(line: str) -> None:
        if not quiet:
            print(f"cmm-comp fleet {command}: {line}", file=sys.stderr, flush=True)

    return say


@dataclass
class _Plan:
    """What a fleet command runs: its jobs, the task, how a job is keyed and a stored result
    judged still valid, where results are stored, and what writes OUT at the end."""

    jobs: list[Any]
    task: Callable[..., dict[str, Any]]
    key_of: Callable[[Any], str]
    store: Any
    finish: Callable[[Any], None]
    still_valid: Callable[[dict[str, Any]], bool] = lambda _entry: True


def _run(args: argparse.Namespace, command: str, plan: _Plan) -> int:
    """Shared body: check flags, connect, run the plan's jobs, write OUT."""
    from .engine import DaskMissing, LazyClient, Progress, run_jobs

    problem = _check_flags(args)
    if problem:
        return fail(f"fleet {command}: {problem}")
    say = _say(command)
    try:
        with LazyClient(args.workers, args.scheduler) as client:
            progress = Progress(f"fleet {command}", len(plan.jobs), quiet=args.quiet)
            run = run_jobs(
                client,
                plan.jobs,
                plan.task,
                plan.key_of,
                plan.store,
                still_valid=plan.still_valid,
                window=args.window,
                progress=progress,
                say=say,
            )
    except DaskMissing as exc:
        return fail(str(exc))
    except (OSError, RuntimeError) as exc:
        return fail(f"fleet {command}: {exc}")
    plan.finish(run)
    for f in run.failed:
        say(f"FAILED {f['path']}: {f['error']}")
    s = run.stats()
    print(
        f"{len(plan.jobs)} sessions: {s['sessions_run'] - s['failed']} run, {s['stored_before']} "
        f"stored before, {s['failed']} failed; {s['wall_s']:.1f} s on {s['workers']} worker "
        f"thread(s); results in {args.json}"
    )
    return 1 if run.failed else 0


def cmd_diagnose(args: argparse.Namespace) -> int:
    """``fleet diagnose ROOT --json OUT [--report DIR]``."""
    from cmm_comp.compensation.trend import TrendSettings

    from .discover import diagnose_jobs, diagnose_key
    from .results import diagnose_finish
    from .store import ResultStore
    from .tasks import code_fingerprint, diagnose_task

    root = _check_root(args.root)
    if root is None:
        return 2
    try:
        settings = TrendSettings(alpha=args.alpha)
    except ValueError as exc:
        return fail(f"fleet diagnose: --alpha: {exc}")
    jobs = diagnose_jobs(root)
    if not jobs:
        return fail(f"fleet diagnose: {root}: no session (ROOT/<machine>/<date>/machine.toml)")
    fingerprint = code_fingerprint()
    store = ResultStore(args.json)

    def finish(run: Any) -> None:
        diagnose_finish(args, jobs, run, store, settings)

    plan = _Plan(jobs, diagnose_task, lambda j: diagnose_key(j, fingerprint), store, finish)
    return _run(args, "diagnose", plan)


def cmd_replay(args: argparse.Namespace) -> int:
    """``fleet replay ROOT [--grid-map MAP] --json OUT``."""
    from .discover import read_grid_map, replay_jobs, replay_key
    from .results import grid_still_valid, replay_finish
    from .store import ResultStore
    from .tasks import code_fingerprint, replay_task

    root = _check_root(args.root)
    if root is None:
        return 2
    machines = {p.name for p in root.iterdir() if p.is_dir() and not p.name.startswith(".")}
    try:
        grid_map = read_grid_map(args.grid_map, machines) if args.grid_map else {}
    except ValueError as exc:
        return fail(f"fleet replay: {exc}")
    jobs = replay_jobs(root, grid_map)
    if not jobs:
        return fail(f"fleet replay: {root}: no session log (*.mcap under ROOT/<machine>/)")
    fingerprint = code_fingerprint()
    store = ResultStore(args.json)

    def finish(run: Any) -> None:
        replay_finish(args, jobs, run, store)

    plan = _Plan(
        jobs, replay_task, lambda j: replay_key(j, fingerprint), store, finish, grid_still_valid()
    )
    return _run(args, "replay", plan)
