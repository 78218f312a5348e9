"""Held-out benchmark of ``cmm-comp diagnose``: sessions it was never tuned to, scored as a user would.

Each case comes from ``tests/heldout_generator`` (written apart from the diagnosis, see its README):
a random machine of one of the ten models, a session design (the outside check's by default:
moving bridge, 700 random points over 4 h, one stylus, 0.25 µm; else a random variant), hidden
effects with their own physics sized to 0.5×, 1× or 3× the noise's 3-D RMS. The case is written as
``machine.toml`` + ``measurements.csv`` into a temporary folder and the installed CLI runs on it
(``cmm-comp diagnose machine.toml measurements.csv --json out.json``) in a subprocess, ``--jobs``
cases at a time. Scores (tests/heldout_generator/scoring.py):

* named: the named effects are the hidden ones, one to one, a hidden identity also counting when
  it is among the ``alternatives`` of a named entry; strict: the same without alternatives;
* clean sessions: verdict ``none`` (anything else is a false alarm);
* held-out OK: ``heldout_rms_um.after ≤ 1.5 ×`` the noise's 3-D RMS.

Prints tables per cause × size, pairs, clean sessions, model, design, time per case, and every
miss with what was named instead; writes ``benchmarks/results/discovery_heldout.json``.

    .venv/bin/python benchmarks/bench_discovery_heldout.py            # full (≈ 184 cases)
    .venv/bin/python benchmarks/bench_discovery_heldout.py --quick    # 16 cases
"""

from __future__ import annotations

import os

# The generator's own linear algebra runs in this process: one BLAS thread, so the cases running
# beside it keep their cores (must be set before numpy loads). The user's own settings are kept
# for the diagnoses (--blas-threads inherit).
BLAS_VARS = ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS")
USER_BLAS = {var: os.environ.get(var) for var in BLAS_VARS}
for _var in BLAS_VARS:
    os.environ.setdefault(_var, "1")

import argparse  # noqa: E402
import json  # noqa: E402
import shutil  # noqa: E402
import subprocess  # noqa: E402
import sys  # noqa: E402
import tempfile  # noqa: E402
import threading  # noqa: E402
import time  # noqa: E402
import zlib  # noqa: E402
from collections.abc import Callable, Iterable  # noqa: E402
from concurrent.futures import ThreadPoolExecutor, as_completed  # noqa: E402
from dataclasses import dataclass  # noqa: E402
from datetime import UTC, datetime  # noqa: E402
from pathlib import Path  # noqa: E402
from typing import Any  # noqa: E402

import numpy as np  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "tests"))
sys.path.insert(0, str(ROOT / "benchmarks"))

from discovery_heldout_report import Outcome, report  # noqa: E402
from heldout_generator import (  # noqa: E402
    CAUSES,
    DESIGN_REDRAWS,
    SIZES,
    UnreachableCase,
    draw_case,
    score_diagnosis,
    write_case,
)

PAIRS: tuple[tuple[str, str], ...] = (
    ("coupling", "periodic"),
    ("thermal_gradient", "scale_expansion"),
    ("thermal_lag", "reversal"),
    ("parametric", "coupling"),
    ("probe_lobing", "squareness_drift"),
    ("workpiece_expansion", "periodic"),
    ("drift", "reversal"),
    ("thermal_gradient", "parametric"),
    ("scale_expansion", "probe_lobing"),
    ("unexplained", "reversal"),
)
RESULTS = ROOT / "benchmarks" / "results" / "discovery_heldout.json"


@dataclass
class Plan:
    """One case to run: what is hidden, at which sizes, on which design."""

    kind: str  # single | pair | clean
    causes: tuple[str, ...]
    sizes: tuple[float, ...]
    seed: int
    design_rule: str  # default | variant
    case_id: str


def _key(*parts: object) -> int:
    return zlib.crc32("|".join(map(str, parts)).encode())


def build_plans(args: argparse.Namespace) -> list[Plan]:
    causes = list(args.causes)
    plans: list[Plan] = []
    for cause in causes:
        for size in args.sizes:
            for seed in range(args.seeds):
                plans.append(
                    Plan(
                        "single",
                        (cause,),
                        (size,),
                        seed,
                        "default" if seed == 0 else "variant",
                        f"{cause}-{size:g}x-s{seed}",
                    )
                )
    pairs = [p for p in PAIRS if p[0] in causes and p[1] in causes][: args.pairs]
    for a, b in pairs:
        for seed in range(args.pair_seeds):
            rng = np.random.default_rng([seed, _key(a, b)])
            sizes = tuple(float(s) for s in rng.choice(args.sizes, 2))
            plans.append(
                Plan(
                    "pair",
                    (a, b),
                    sizes,
                    seed,
                    "default" if seed == 0 else "variant",
                    f"{a}+{b}-{sizes[0]:g}x{sizes[1]:g}x-s{seed}",
                )
            )
    for seed in range(args.clean):
        plans.append(
            Plan("clean", (), (), seed, "default" if seed % 2 == 0 else "variant", f"clean-s{seed}")
        )
    return plans


def _run_cli(
    cmd: list[str], cwd: Path, timeout_s: float, env: dict[str, str]
) -> tuple[int | None, float, float, str]:
    """Run ``cmd``; (exit code or None on timeout, wall s, CPU s of the child, stderr tail)."""
    err_path = cwd / "stderr.txt"
    with (cwd / "stdout.txt").open("wb") as out, err_path.open("wb") as err:
        t0 = time.perf_counter()
        proc = subprocess.Popen(cmd, cwd=cwd, stdout=out, stderr=err, env=env)
    timed_out = threading.Event()

    def kill() -> None:
        timed_out.set()
        proc.kill()

    timer = threading.Timer(timeout_s, kill)
    timer.start()
    try:
        _, status, usage = os.wait4(proc.pid, 0)
    finally:
        timer.cancel()
    wall = time.perf_counter() - t0
    proc.returncode = os.waitstatus_to_exitcode(status)
    tail = err_path.read_text(errors="replace")[-600:]
    cpu = usage.ru_utime + usage.ru_stime
    return (None if timed_out.is_set() else proc.returncode), wall, cpu, tail


def run_one(plan: Plan, args: argparse.Namespace, cli: str, env: dict[str, str]) -> Outcome:
    outcome = Outcome(plan)
    outcome.started_utc = datetime.now(UTC).isoformat(timespec="seconds")
    outcome.code = code_fingerprint()
    try:
        case, outcome.design_redraws = draw_case(
            plan.causes,
            plan.sizes,
            plan.seed,
            plan.case_id,
            default_first=plan.design_rule == "default",
            redraws=DESIGN_REDRAWS,
        )
    except UnreachableCase:
        outcome.error = "no design shows this cause beyond a static table change"
        return outcome
    outcome.summary = case.summary()
    outcome.summary["design_redraws"] = outcome.design_redraws
    with tempfile.TemporaryDirectory(prefix="heldout-") as tmp:
        folder = Path(tmp)
        write_case(case, folder)
        cmd = [cli, "diagnose", "machine.toml", "measurements.csv", "--json", "out.json"]
        code, wall, cpu, tail = _run_cli(cmd, folder, args.timeout_s, env)
        outcome.exit_code, outcome.wall_s, outcome.cpu_s, outcome.stderr_tail = (
            code,
            wall,
            cpu,
            tail,
        )
        result = None
        out_json = folder / "out.json"
        if code is None:
            outcome.error = f"timeout after {args.timeout_s:g} s"
        elif out_json.exists():
            try:
                result = json.loads(out_json.read_text())
            except json.JSONDecodeError as exc:
                outcome.error = f"unreadable JSON: {exc}"
        else:
            outcome.error = f"exit {code}, no JSON"
        if args.keep is not None:
            dest = args.keep / plan.case_id
            shutil.rmtree(dest, ignore_errors=True)
            shutil.copytree(folder, dest)
    if isinstance(result, dict) and isinstance(result.get("elapsed_s"), int | float):
        outcome.elapsed_s = float(result["elapsed_s"])
    score = score_diagnosis(case.hidden, result, case.noise_rms_3d_um)
    outcome.score = score.as_dict()
    if result is not None:
        outcome.score["heldout_rms_um"] = result.get("heldout_rms_um")
        outcome.score["effects"] = [
            {
                k: e.get(k)
                for k in (
                    "cause",
                    "component",
                    "axis",
                    "varies_with",
                    "explained_fraction",
                    "alternatives",
                )
            }
            for e in result.get("effects", [])
            if isinstance(e, dict)
        ]
    return outcome


# ------------------------------------------------------------------------------------ main
def _tree_state() -> list[str]:
    """Uncommitted changes under the code the CLI runs (the install is editable)."""
    try:
        out = subprocess.run(
            ["git", "status", "--porcelain", "--", "compensation", "cli"],
            cwd=ROOT,
            capture_output=True,
            text=True,
            check=True,
        ).stdout
    except (OSError, subprocess.CalledProcessError):
        return ["unknown"]
    return [line.strip() for line in out.splitlines() if line.strip()]


def code_fingerprint() -> str:
    """HEAD plus the uncommitted files under compensation/ and cli/ with their modification times:
    changes when the code the CLI runs changes (git metadata and mtimes only, no content)."""
    state = [_git_commit()]
    for line in _tree_state():
        path = ROOT / line.split()[-1]
        state.append(f"{line}@{path.stat().st_mtime_ns if path.exists() else 0}")
    return f"{state[0][:12]}+{zlib.crc32('|'.join(state).encode()):08x}"


def _git_commit() -> str:
    try:
        return subprocess.run(
            ["git", "rev-parse", "HEAD"], cwd=ROOT, capture_output=True, text=True, check=True
        ).stdout.strip()
    except (OSError, subprocess.CalledProcessError):
        return "unknown"


def _csv_list(
    kind: Callable[[str], Any], allowed: Iterable[Any] | None = None
) -> Callable[[str], list[Any]]:
    def parse(text: str) -> list[Any]:
        try:
            values = [kind(v.strip()) for v in text.split(",") if v.strip()]
        except ValueError:
            raise argparse.ArgumentTypeError(f"not a comma-separated list: {text!r}") from None
        if not values:
            raise argparse.ArgumentTypeError("empty list")
        if allowed is not None:
            bad = [v for v in values if v not in allowed]
            if bad:
                raise argparse.ArgumentTypeError(
                    f"{bad} not allowed; allowed: {', '.join(map(str, allowed))}"
                )
        return values

    return parse


def _count(text: str) -> int:
    try:
        value = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"not an integer: {text!r}") from None
    if value < 0:
        raise argparse.ArgumentTypeError(f"must be ≥ 0, got {value}")
    return value


def _positive_float(text: str) -> float:
    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"not a number: {text!r}") from None
    if not (np.isfinite(value) and value > 0):
        raise argparse.ArgumentTypeError(f"must be finite and > 0, got {text!r}")
    return value


def _size(text: str) -> float:
    value = _positive_float(text)
    if not 0.05 <= value <= 20:
        raise argparse.ArgumentTypeError(f"size must be in 0.05…20 × the noise, got {value:g}")
    return value


def parse_args(argv: list[str]) -> argparse.Namespace:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument(
        "--quick",
        action="store_true",
        help="12 causes at 1× on the default design, 2 pairs, 2 clean",
    )
    p.add_argument(
        "--seeds", type=_count, default=4, help="seeds per cause × size (seed 0: default design)"
    )
    p.add_argument(
        "--sizes", type=_csv_list(_size), default=list(SIZES), help="sizes, × noise 3-D RMS"
    )
    p.add_argument(
        "--causes", type=_csv_list(str, CAUSES), default=list(CAUSES), help="comma-separated causes"
    )
    p.add_argument(
        "--pairs", type=_count, default=len(PAIRS), help=f"how many of the {len(PAIRS)} pairs"
    )
    p.add_argument("--pair-seeds", type=_count, default=2, help="seeds per pair")
    p.add_argument("--clean", type=_count, default=20, help="clean sessions")
    p.add_argument("--jobs", type=_count, default=2, help="cases run at once (default 2)")
    p.add_argument("--timeout-s", type=_positive_float, default=900.0, help="per case")
    p.add_argument(
        "--blas-threads",
        default="auto",
        help="BLAS threads of each diagnosis: a number, 'inherit', or 'auto' (1 when --jobs > 1)",
    )
    p.add_argument("--keep", type=Path, default=None, help="keep every case's folder here")
    p.add_argument("--out", type=Path, default=RESULTS, help="results JSON")
    p.add_argument(
        "--from-json",
        type=Path,
        default=None,
        help="print the tables of an earlier run's results JSON (runs nothing)",
    )
    args = p.parse_args(argv)
    if args.jobs < 1:
        p.error("--jobs must be ≥ 1")
    if args.blas_threads not in ("auto", "inherit") and not args.blas_threads.isdigit():
        p.error(f"--blas-threads must be a number, 'auto' or 'inherit', got {args.blas_threads!r}")
    if args.quick:
        args.seeds, args.sizes, args.pairs, args.pair_seeds, args.clean = 1, [1.0], 2, 1, 2
    return args


def reprint(path: Path) -> int:
    """Print the tables of a results JSON written by an earlier run."""
    try:
        payload = json.loads(path.read_text())
        meta = payload["meta"]
        records = payload["cases"]
    except (OSError, json.JSONDecodeError, KeyError, TypeError) as exc:
        print(f"bench_discovery_heldout: cannot read results {path}: {exc}", file=sys.stderr)
        return 2
    args = parse_args([a for a in meta.get("argv", []) if a != "--from-json"])
    args.jobs = meta.get("jobs", args.jobs)
    outs = []
    for r in records:
        default_rule = r["seed"] % 2 == 0 if r["kind"] == "clean" else r["seed"] == 0
        rule = r.get("design_rule", "default" if default_rule else "variant")
        plan = Plan(r["kind"], tuple(r["causes"]), tuple(r["sizes"]), r["seed"], rule, r["case_id"])
        o = Outcome(plan, summary=r.get("case") or {}, score=r.get("score") or {})
        o.wall_s = r["wall_s"] if r.get("wall_s") is not None else float("nan")
        o.cpu_s = r["cpu_s"] if r.get("cpu_s") is not None else float("nan")
        o.elapsed_s, o.exit_code, o.error = r.get("elapsed_s"), r.get("exit_code"), r.get("error")
        o.design_redraws = int((r.get("case") or {}).get("design_redraws", 0))
        o.started_utc, o.code = r.get("started_utc"), r.get("code")
        outs.append(o)
    lines, _ = report(outs, args, meta)
    print("\n".join(lines))
    return 0


def main(argv: list[str]) -> int:
    args = parse_args(argv)
    if args.from_json is not None:
        return reprint(args.from_json)
    cli = str(ROOT / ".venv" / "bin" / "cmm-comp")
    if not Path(cli).exists():
        cli = shutil.which("cmm-comp") or ""
    if not cli:
        print(
            "bench_discovery_heldout: cmm-comp not found (.venv/bin/cmm-comp or PATH)",
            file=sys.stderr,
        )
        return 2
    env = dict(os.environ)
    blas = args.blas_threads
    if blas == "auto":
        blas = "1" if args.jobs > 1 else "inherit"
    for var in BLAS_VARS:
        if blas != "inherit":
            env[var] = blas
        elif (user := USER_BLAS[var]) is None:
            env.pop(var, None)  # this process set it for itself, not for the diagnoses
        else:
            env[var] = user
    meta = {
        "commit": _git_commit(),
        "started": datetime.now(UTC).isoformat(timespec="seconds"),
        "argv": argv,
        "jobs": args.jobs,
        "child_blas_threads": blas,
        "load_average_start": os.getloadavg(),
        "uncommitted_start": _tree_state(),
    }
    plans = build_plans(args)
    print(f"bench_discovery_heldout: {len(plans)} cases, --jobs {args.jobs}", file=sys.stderr)
    outs: list[Outcome] = []
    t0 = time.perf_counter()
    with ThreadPoolExecutor(max_workers=args.jobs) as pool:
        futures = {pool.submit(run_one, plan, args, cli, env): plan for plan in plans}
        for i, fut in enumerate(as_completed(futures), 1):
            try:
                o = fut.result()
            except Exception as exc:  # a generator bug must not lose the other cases
                o = Outcome(futures[fut], error=f"{type(exc).__name__}: {exc}")
            outs.append(o)
            mark = "named" if o.score.get("named") else ("ERROR" if o.error else "miss")
            print(
                f"[{i}/{len(plans)}] {o.plan.case_id}: {mark}"
                f"{' (strict)' if o.score.get('strict') else ''} {o.wall_s:.1f} s wall {o.cpu_s:.1f} s CPU",
                file=sys.stderr,
                flush=True,
            )
    order = {p.case_id: i for i, p in enumerate(plans)}
    outs.sort(key=lambda o: order[o.plan.case_id])
    meta["total_wall_s"] = time.perf_counter() - t0
    meta["load_average_end"] = os.getloadavg()
    meta["commit_end"] = _git_commit()
    meta["uncommitted_end"] = _tree_state()
    lines, summary = report(outs, args, meta)
    print("\n".join(lines))
    print(
        f"\ntotal {meta['total_wall_s']:.0f} s wall; load average {meta['load_average_start']} → {meta['load_average_end']}"
    )
    args.out.parent.mkdir(parents=True, exist_ok=True)
    payload = {
        "meta": meta,
        "summary": summary,
        "table": lines,
        "cases": [
            {
                "case_id": o.plan.case_id,
                "kind": o.plan.kind,
                "causes": list(o.plan.causes),
                "sizes": list(o.plan.sizes),
                "seed": o.plan.seed,
                "design_rule": o.plan.design_rule,
                "case": o.summary,
                "score": o.score,
                "wall_s": o.wall_s,
                "cpu_s": o.cpu_s,
                "elapsed_s": o.elapsed_s,
                "exit_code": o.exit_code,
                "error": o.error,
                "started_utc": o.started_utc,
                "code": o.code,
            }
            for o in outs
        ],
    }
    args.out.write_text(
        json.dumps(_finite(payload), indent=1, default=_json_default, allow_nan=False) + "\n"
    )
    print(f"wrote {args.out}")
    return 0


def _finite(value: Any) -> Any:
    """The payload with every non-finite float as null (JSON has no NaN)."""
    if isinstance(value, dict):
        return {k: _finite(v) for k, v in value.items()}
    if isinstance(value, list | tuple):
        return [_finite(v) for v in value]
    if isinstance(value, float | np.floating) and not np.isfinite(value):
        return None
    return value


def _json_default(value: Any) -> Any:
    if isinstance(value, np.generic):
        return value.item()
    if isinstance(value, np.ndarray):
        return value.tolist()
    raise TypeError(f"not JSON: {type(value).__name__}")


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
