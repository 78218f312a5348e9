"""Reference-instrument benchmark of ``cmm-comp diagnose`` (issue 24, "Must show", second bullet).

Sessions from ``tests/reference_generator`` (written apart from the diagnosis; README there): one
axis of a machine measured by a reference instrument, with machine effects (a smooth positioning
curve, a screw or scale periodic error, backlash, thermal expansion about a point) and reference
effects (a triangulation-chirped or constant-period ripple locked to the reading, a latency, a
cosine or gain error, a drift in time, a smooth linearity error), bidirectional and
one-directional, each with the truth of which instrument carries it (the lead's contract). Every
family × variant is drawn on ``--seeds`` fresh seeds, plus ``--clean`` clean sessions per
direction mode; each is written as ``machine.toml`` + ``measurements.csv`` and the installed CLI
runs on it in a subprocess (``cmm-comp diagnose MACHINE MEASUREMENTS --json OUT``), ``--jobs``
at a time.

Scores (tests/reference_generator/scoring.py): a hidden effect is *named exactly* when its
identity is an entry's cause or one of its ``alternatives`` and the entry's ``source`` is the
truth's; sessions where naming nothing is right are *false alarms* when anything is named;
*spurious* entries are named but hidden nowhere. Prints the rates by kind × family × direction
mode × source, the quiet sessions, times, every miss; writes
``benchmarks/results/discovery_reference.json``.

Seeds: the test (tests/test_discovery_reference.py) and development use seeds 0–999; this
benchmark's seeds start at 1000 (``--first-seed``) and are the held-out figures. Seeds already
run (no longer held out): 1000–1003 (their misses guided the changes of 2026-12-05),
3000–3002 and 4000–4002 (guided the round of 2026-12-06), 5000–5002 (held out once, then their
misses guided the second round of 2026-12-06) and 6000–6002 (run once, at the end of that round,
for its held-out figure); the next fresh range starts at 7000.

    .venv/bin/python benchmarks/bench_discovery_reference.py --jobs 2          # 144 sessions
    .venv/bin/python benchmarks/bench_discovery_reference.py --quick           # 1 seed, 33
    .venv/bin/python benchmarks/bench_discovery_reference.py --from-json FILE  # reprint a run
    .venv/bin/python benchmarks/bench_discovery_reference.py --from-json FILE --rescore DIR
        # re-score a run kept with --keep DIR under the generator's current truth rules
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
import time
from concurrent.futures import ThreadPoolExecutor, as_completed
from datetime import UTC, datetime
from pathlib import Path
from typing import Any

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "tests"))

from reference_generator import (  # noqa: E402
    VARIANTS,
    draw_case,
    find_cli,
    run_case,
    score_diagnosis,
)
from reference_generator.report import misses_text, rate_table, summary  # noqa: E402

RESULTS = ROOT / "benchmarks" / "results" / "discovery_reference.json"
HELD_OUT_FROM = 1000  # seeds below are development seeds (the test's and the author's)
BLAS_VARS = ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS")


def parse_args(argv: list[str]) -> argparse.Namespace:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--seeds", type=int, default=4, help="seeds per family × variant (4)")
    p.add_argument("--first-seed", type=int, default=HELD_OUT_FROM, help="first seed (1000)")
    p.add_argument("--clean", type=int, default=10, help="clean sessions per direction mode (10)")
    p.add_argument("--families", default=",".join(f for f in VARIANTS if f != "clean"))
    p.add_argument("--jobs", type=int, default=2)
    p.add_argument("--timeout-s", type=float, default=300.0)
    p.add_argument("--quick", action="store_true", help="1 seed per variant, 1 clean per mode")
    p.add_argument("--dev", action="store_true", help="allow seeds below 1000 (development)")
    p.add_argument("--keep", type=Path, help="keep every session's files under this folder")
    p.add_argument("--out", type=Path, default=RESULTS)
    p.add_argument("--from-json", type=Path, help="reprint the tables of a saved run")
    p.add_argument(
        "--rescore", type=Path, help="with --from-json: re-score its diagnoses kept in this folder"
    )
    args = p.parse_args(argv)
    if args.quick:
        args.seeds, args.clean = 1, 1
    unknown = set(args.families.split(",")) - set(VARIANTS)
    if unknown:
        p.error(f"--families: unknown {sorted(unknown)}; known: {', '.join(VARIANTS)}")
    if args.first_seed < HELD_OUT_FROM and not args.dev:
        p.error(
            f"--first-seed {args.first_seed}: seeds below {HELD_OUT_FROM} are development seeds"
        )
    return args


def plans(args: argparse.Namespace) -> list[tuple[str, str, int]]:
    out = []
    for family in args.families.split(","):
        for variant in VARIANTS[family]:
            out += [(family, variant, args.first_seed + i) for i in range(args.seeds)]
    for variant in VARIANTS["clean"]:
        out += [("clean", variant, args.first_seed + i) for i in range(args.clean)]
    return out


def _git(*cmd: str) -> str:
    try:
        return subprocess.run(
            ["git", *cmd], cwd=ROOT, capture_output=True, text=True, check=True
        ).stdout.strip()
    except (OSError, subprocess.CalledProcessError):
        return "unknown"


def run_all(args: argparse.Namespace, work: Path) -> list[dict[str, Any]]:
    cli = find_cli()
    env = {**os.environ, **dict.fromkeys(BLAS_VARS, "1")}  # the cases share the cores
    todo = plans(args)
    print(f"bench_discovery_reference: {len(todo)} sessions, --jobs {args.jobs}", file=sys.stderr)
    records: list[dict[str, Any]] = []

    def one(plan: tuple[str, str, int]) -> dict[str, Any]:
        family, variant, seed = plan
        folder = work / f"{family}-{variant}-s{seed}"
        return run_case(family, variant, seed, folder, cli, args.timeout_s, env).as_dict()

    with ThreadPoolExecutor(max_workers=args.jobs) as pool:
        futures = {pool.submit(one, plan): plan for plan in todo}
        for i, fut in enumerate(as_completed(futures), 1):
            rec = fut.result()
            records.append(rec)
            score = rec.get("score") or {}
            per = score.get("per_hidden", [])
            mark = f"{sum(h['exact'] for h in per)}/{len(per)} exactly"
            if not per:
                mark = "FALSE ALARM" if score.get("false_alarm", True) else "quiet"
            print(
                f"[{i}/{len(todo)}] {rec['case']} ({rec['rows']} rows): {mark}, "
                f"{len(score.get('spurious', []))} extra, {rec['wall_s']:.1f} s",
                file=sys.stderr,
                flush=True,
            )
    return sorted(records, key=lambda r: r["case"])


def print_report(records: list[dict[str, Any]], meta: dict[str, Any]) -> dict[str, Any]:
    s = summary(records)
    print(f"reference-instrument benchmark: {meta.get('commit')} ({meta.get('started')})")
    print(f"seeds {meta.get('seeds')}; machine: {meta.get('machine')}\n")
    print(rate_table(records))
    ex, nm = s["rate_named_exactly"], s["rate_named"]
    print(
        f"\nhidden effects: {s['hidden_effects']} in {s['sessions']} sessions; named exactly "
        f"{s['named_exactly']} ({100 * (ex or 0):.1f} %), named with any source {s['named']} "
        f"({100 * (nm or 0):.1f} %)  [bar: ≥ 95 % exactly]"
    )
    print(
        f"sessions where naming nothing is right: {s['sessions_expecting_nothing']} "
        f"({s['clean_sessions']} clean); false alarms {len(s['false_alarms'])}  [bar: 0]"
    )
    print(
        f"spurious entries: {s['spurious_entries']} in {s['sessions_with_spurious']} sessions; "
        f"diagnosis failed: {len(s['diagnosis_failed'])}"
    )
    for name, key in (("wall (whole CLI)", "wall_s"), ("CPU (whole CLI)", "cpu_s")):
        st = s[key]
        print(
            f"time per session, {name}: median {st['median']} s, p90 {st['p90']}, max {st['max']}"
        )
    by = ", ".join(
        f"{k} rows {v['median']} s (max {v['max']})" for k, v in s["cpu_s_by_rows"].items()
    )
    print(f"CPU per session by size: {by}")
    e = s["elapsed_s"]
    print(f"the diagnosis' own elapsed_s: median {e['median']} s, p90 {e['p90']}, max {e['max']}")
    print("\n" + misses_text(records, limit=400))
    return s


def rescore(records: list[dict[str, Any]], kept: Path) -> None:
    """Each record's truth and score again, from the session redrawn by its seed (the generator's
    current truth rules) and its ``diagnosis.json`` kept under ``kept`` (``--keep``)."""
    for rec in records:
        family, variant, seed = str(rec["case"]).split("/")
        case = draw_case(family, variant, int(seed.lstrip("s")))
        out = kept / f"{family}-{variant}-{seed}" / "diagnosis.json"
        rec["hidden"] = [h.as_dict() for h in case.hidden]
        if rec.get("score") is not None and out.is_file():
            rec["score"] = score_diagnosis(
                case.hidden, json.loads(out.read_text(encoding="utf-8"))
            ).as_dict()


def main(argv: list[str]) -> int:
    args = parse_args(argv)
    if args.from_json:
        saved = json.loads(args.from_json.read_text(encoding="utf-8"))
        if args.rescore:
            rescore(saved["sessions"], args.rescore)
        print_report(saved["sessions"], saved["meta"])
        return 0
    meta: dict[str, Any] = {
        "commit": _git("rev-parse", "--short", "HEAD"),
        "uncommitted": bool(_git("status", "--porcelain")),
        "started": datetime.now(UTC).isoformat(timespec="seconds"),
        "argv": argv,
        "seeds": f"{args.first_seed}…{args.first_seed + max(args.seeds, args.clean) - 1}",
        "jobs": args.jobs,
        "machine": f"{os.cpu_count()} cores, load average at start {os.getloadavg()[0]:.1f}",
    }
    t0 = time.perf_counter()
    if args.keep:
        args.keep.mkdir(parents=True, exist_ok=True)
        records = run_all(args, args.keep)
    else:
        with tempfile.TemporaryDirectory(prefix="bench-reference-") as tmp:
            records = run_all(args, Path(tmp))
    meta["wall_s_total"] = round(time.perf_counter() - t0, 1)
    meta["load_average_end"] = round(os.getloadavg()[0], 2)
    s = print_report(records, meta)
    args.out.parent.mkdir(parents=True, exist_ok=True)
    tmp_out = args.out.with_suffix(".json.tmp")
    tmp_out.write_text(
        json.dumps({"meta": meta, "summary": s, "sessions": records}, indent=1, default=str),
        encoding="utf-8",
    )
    tmp_out.replace(args.out)
    print(f"\nwrote {args.out} ({meta['wall_s_total']} s)", file=sys.stderr)
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
