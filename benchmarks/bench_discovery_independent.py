"""Identification rates of the diagnosis on the independent generator (issue 11, item 3).

Cases: every cause × sizes (0.5, 1, 3 × the noise 3-D RMS) × seeds, pairs of causes, and clean
sessions; each seed draws its own machine (one of the ten models, random volume, reference,
nominal polynomial tables) and session design (random points or ISO 10360-2 lines, 1 or 5 styli,
1 h or 8 h, 200…2000 points, noise 0.25–1 µm). The generator (tests/independent_generator/) shares
no code with the diagnosis' candidates.

A case is *named* when the set of identities named equals the hidden set (a hidden identity also
matches an entry listing it among its ``alternatives``); *strict* ignores alternatives. Held-out OK:
``heldout_rms_um.after ≤ 1.5 × noise 3-D RMS``. Prints the table and the misses, writes
``benchmarks/results/discovery_independent.json``.

    .venv/bin/python benchmarks/bench_discovery_independent.py [--quick] [--seeds 5] [--jobs 2]
"""

from __future__ import annotations

import os

for _var in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS", "NUMBA_NUM_THREADS"):
    os.environ.setdefault(_var, "1")  # one process per core

import argparse  # noqa: E402
import json  # noqa: E402
import sys  # noqa: E402
import time  # noqa: E402
import traceback  # noqa: E402
from collections import defaultdict  # noqa: E402
from concurrent.futures import ProcessPoolExecutor, as_completed  # noqa: E402
from pathlib import Path  # noqa: E402
from typing import Any  # noqa: E402

import numpy as np  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "tests"))

from independent_generator.chains import MODELS  # noqa: E402
from independent_generator.scoring import PAIRS, SINGLE_CAUSES, run_case  # noqa: E402
from independent_generator.sessions import Design  # noqa: E402

OUT = ROOT / "benchmarks" / "results" / "discovery_independent.json"


def parse_design(text: str) -> Design:
    """``LAYOUT/POINTS/STYLI/HOURS/NOISE_UM``, e.g. ``random/700/1/4/0.25`` (the outside
    check's design: a moving bridge, ~700 points over 4 h, one stylus straight down, 0.25 µm)."""
    try:
        layout, n, styli, hours, noise = text.split("/")
        return Design(layout, int(n), int(styli), float(hours) * 3600.0, float(noise))
    except ValueError:
        raise argparse.ArgumentTypeError(
            f"design {text!r}: expected LAYOUT/POINTS/STYLI/HOURS/NOISE_UM, e.g. random/700/1/4/0.25"
        ) from None


def _run(case: tuple[str, float, int], fixed: dict[str, Any] | None = None) -> dict[str, Any]:
    label, size, seed = case
    try:
        return run_case(label, size, seed, **(fixed or {}))
    except Exception as exc:  # a crash is a result too: keep going, report it
        return {
            "case": label,
            "size": size,
            "seed": seed,
            "named": False,
            "strict": False,
            "equivalent": False,
            "heldout_ok": False,
            "error": f"{type(exc).__name__}: {exc}",
            "traceback": traceback.format_exc(limit=4),
            "seconds": float("nan"),
        }


def make_cases(args: argparse.Namespace) -> list[tuple[str, float, int]]:
    causes = args.causes or list(SINGLE_CAUSES)
    cases: list[tuple[str, float, int]] = []
    for cause in causes:
        for size in args.sizes:
            for seed in range(args.seed0, args.seed0 + args.seeds):
                cases.append((cause, size, seed))
    if not args.no_pairs:
        for a, b in PAIRS:
            if args.causes and not (a in args.causes or b in args.causes):
                continue
            for size in args.pair_sizes:
                for seed in range(args.seed0, args.seed0 + args.pair_seeds):
                    cases.append((f"{a}+{b}", size, 1000 + seed))
    for seed in range(args.clean):
        cases.append(("none", 0.0, 5000 + seed))
    return cases


def _rate(rows: list[dict[str, Any]], key: str) -> str:
    if not rows:
        return "   -   "
    k = sum(bool(r.get(key)) for r in rows)
    return f"{k:>3}/{len(rows):<3}"


def summarise(results: list[dict[str, Any]], sizes: list[float]) -> dict[str, Any]:
    singles = [r for r in results if r["case"] != "none" and "+" not in r["case"]]
    pairs = [r for r in results if "+" in r["case"]]
    clean = [r for r in results if r["case"] == "none"]
    by_cause: dict[str, dict[str, list[dict[str, Any]]]] = defaultdict(lambda: defaultdict(list))
    for r in singles:
        by_cause[r["case"]][str(r["size"])].append(r)
    by_pair: dict[str, list[dict[str, Any]]] = defaultdict(list)
    for r in pairs:
        by_pair[r["case"]].append(r)
    secs = np.array([r["seconds"] for r in results if np.isfinite(r.get("seconds", np.nan))])
    worst = max(
        results,
        key=lambda r: r.get("seconds", 0.0) if np.isfinite(r.get("seconds", np.nan)) else 0.0,
    )
    in_range = [r for r in singles + pairs if 0.5 <= r["size"] <= 3.0]

    def frac(rows: list[dict[str, Any]], key: str) -> float | None:
        return None if not rows else sum(bool(r.get(key)) for r in rows) / len(rows)

    return {
        "per_cause": {
            c: {
                s: {
                    "n": len(rows),
                    "named": frac(rows, "named"),
                    "strict": frac(rows, "strict"),
                    "equivalent": frac(rows, "equivalent"),
                    "heldout_ok": frac(rows, "heldout_ok"),
                }
                for s, rows in sorted(v.items())
            }
            for c, v in sorted(by_cause.items())
        },
        "pairs": {
            p: {
                "n": len(rows),
                "named": frac(rows, "named"),
                "strict": frac(rows, "strict"),
                "equivalent": frac(rows, "equivalent"),
                "heldout_ok": frac(rows, "heldout_ok"),
            }
            for p, rows in sorted(by_pair.items())
        },
        "clean": {
            "n": len(clean),
            "false_alarms": sum(not r["named"] for r in clean),
            "heldout_ok": frac(clean, "heldout_ok"),
        },
        "overall_0.5_to_3": {
            "n": len(in_range),
            "named": frac(in_range, "named"),
            "strict": frac(in_range, "strict"),
            "equivalent": frac(in_range, "equivalent"),
            "heldout_ok": frac(in_range, "heldout_ok"),
        },
        "seconds": {
            "median": float(np.median(secs)) if secs.size else None,
            "p90": float(np.percentile(secs, 90)) if secs.size else None,
            "worst": float(secs.max()) if secs.size else None,
            "worst_case": f"{worst['case']} size={worst['size']} seed={worst['seed']}",
            # the target is per ~700-point session: times by session size
            "by_points": {
                str(n): {
                    "n": len(ts),
                    "median": float(np.median(ts)),
                    "worst": float(np.max(ts)),
                }
                for n in sorted({int(r.get("n_points", 0)) for r in results})
                if (
                    ts := [
                        r["seconds"]
                        for r in results
                        if int(r.get("n_points", 0)) == n and np.isfinite(r.get("seconds", np.nan))
                    ]
                )
            },
        },
        "errors": sum("error" in r for r in results),
        "per_variant": _breakdown(singles, lambda r: f"{r['case']}/{_variants(r)}"),
        "per_model": _breakdown(singles + pairs, lambda r: str(r.get("model"))),
        "per_layout": _breakdown(singles + pairs, lambda r: str(r.get("design", "")).split("/")[0]),
        "per_styli": _breakdown(
            singles + pairs, lambda r: str(r.get("design", "?/?/?")).split("/")[2]
        ),
    }


def _variants(r: dict[str, Any]) -> str:
    return ",".join(h.get("variant", "") for h in r.get("hidden_detail", []))


def _breakdown(rows: list[dict[str, Any]], key: Any) -> dict[str, dict[str, Any]]:
    """Named rate by a grouping key (variant, model, layout, styli)."""
    groups: dict[str, list[dict[str, Any]]] = defaultdict(list)
    for r in rows:
        groups[key(r)].append(r)
    return {
        k: {"n": len(v), "named": sum(bool(r["named"]) for r in v) / len(v)}
        for k, v in sorted(groups.items())
    }


def provenance() -> dict[str, Any]:
    """Which diagnosis was measured: git HEAD, dirty flag and a hash of its source files."""
    import hashlib
    import subprocess

    def git(*cmd: str) -> str:
        try:
            return subprocess.run(
                ["git", *cmd], cwd=ROOT, capture_output=True, text=True, timeout=10
            ).stdout.strip()
        except (OSError, subprocess.SubprocessError):
            return ""

    digest = hashlib.sha256()
    for folder in ("compensation/diagnosis", "compensation/effects"):
        for path in sorted((ROOT / folder).glob("*.py")):
            digest.update(path.name.encode())
            digest.update(path.read_bytes())
    return {
        "git_head": git("rev-parse", "HEAD"),
        "git_dirty": bool(git("status", "--porcelain", "--", "compensation")),
        "diagnosis_sources_sha256": digest.hexdigest(),
    }


COLS = ("named", "strict", "equivalent", "heldout_ok")


def print_table(summary: dict[str, Any], results: list[dict[str, Any]], sizes: list[float]) -> None:
    """Per cause and size: named / strict / named-or-exact-equivalent / held-out OK."""
    print("columns per size: named  strict  equivalent  held-out-OK  (k/n)")
    head = "cause".ljust(20) + "".join(f" | size {s:<4}".ljust(38) for s in sizes)
    print(head)
    print("-" * len(head))
    singles = [r for r in results if r["case"] != "none" and "+" not in r["case"]]
    for c in sorted({r["case"] for r in singles}):
        line = c.ljust(20)
        for s in sizes:
            rows = [r for r in singles if r["case"] == c and r["size"] == s]
            line += " | " + " ".join(_rate(rows, k) for k in COLS)
        print(line)
    pairs = sorted({r["case"] for r in results if "+" in r["case"]})
    if pairs:
        print("\n" + "pair".ljust(40) + "  named    strict   equiv    held")
        for p in pairs:
            rows = [r for r in results if r["case"] == p]
            print(p.ljust(40) + "  " + " ".join(_rate(rows, k) for k in COLS))
    cl = summary["clean"]
    print(f"\nclean sessions: {cl['n']}, false alarms: {cl['false_alarms']}")
    o = summary["overall_0.5_to_3"]
    if o["n"]:
        print(
            f"overall 0.5–3× (singles + pairs, n={o['n']}): named {o['named']:.1%}  strict {o['strict']:.1%}"
            f"  named-or-equivalent {o['equivalent']:.1%}  held-out OK {o['heldout_ok']:.1%}"
        )
    sec = summary["seconds"]
    if sec["median"] is not None:
        print(
            f"diagnosis seconds: median {sec['median']:.2f}, p90 {sec['p90']:.2f}, worst {sec['worst']:.2f} ({sec['worst_case']})"
        )
        print(
            "  by session size: "
            + ", ".join(
                f"{n} points: median {v['median']:.2f} worst {v['worst']:.2f} (n={v['n']})"
                for n, v in sec["by_points"].items()
            )
        )
    for title in ("per_model", "per_layout", "per_styli"):
        parts = [f"{k} {v['named']:.0%} (n={v['n']})" for k, v in summary[title].items()]
        print(f"named {title.replace('_', ' ')}: " + ", ".join(parts))
    weak = {k: v for k, v in summary["per_variant"].items() if v["named"] < 1.0}
    if weak:
        print(
            "variants named < 100 %: "
            + ", ".join(f"{k} {v['named']:.0%}/{v['n']}" for k, v in weak.items())
        )
    misses = [r for r in results if not r["named"]]
    if misses:
        print(f"\nmisses ({len(misses)}):")
        for r in misses:
            if "error" in r:
                print(f"  {r['case']} size={r['size']} seed={r['seed']}: ERROR {r['error']}")
                continue
            alts = [a for a in r.get("alternatives", []) if a]
            eq = [h.get("equivalent") for h in r.get("hidden_detail", []) if h.get("equivalent")]
            print(
                f"  {r['case']} size={r['size']} seed={r['seed']} [{r.get('model')} {r.get('design')}]"
                f"\n      hidden {_fmt(r['hidden'])} ({', '.join(h.get('variant', '') for h in r.get('hidden_detail', []))})"
                + (f" exact equivalents {eq}" if eq else "")
                + f"\n      found  {_fmt(r['found'])}{'  alts ' + str(alts) if alts else ''}"
                f"  held-out {r['heldout_rms_um']:.3f}/{r['noise_rms_3d_um']:.3f} µm"
            )


def _fmt(idents: list[list[Any]]) -> str:
    return (
        "["
        + ", ".join("(" + ", ".join(str(v) for v in i if v is not None) + ")" for i in idents)
        + "]"
    )


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument(
        "--quick", action="store_true", help="1 seed per cause at size 1, 2 pairs, 3 clean"
    )
    ap.add_argument("--seeds", type=int, default=5, help="seeds per cause and size")
    ap.add_argument("--seed0", type=int, default=0)
    ap.add_argument("--sizes", type=float, nargs="+", default=[0.5, 1.0, 3.0])
    ap.add_argument("--pair-seeds", type=int, default=3)
    ap.add_argument("--pair-sizes", type=float, nargs="+", default=[1.0])
    ap.add_argument("--no-pairs", action="store_true")
    ap.add_argument("--clean", type=int, default=20, help="clean sessions")
    ap.add_argument("--causes", nargs="+", choices=SINGLE_CAUSES, help="only these causes")
    ap.add_argument("--jobs", type=int, default=2)
    ap.add_argument("--out", type=Path, default=OUT)
    ap.add_argument("--model", choices=sorted(MODELS), help="every case on this kinematic model")
    ap.add_argument(
        "--design",
        type=parse_design,
        help="every case with this session design, LAYOUT/POINTS/STYLI/HOURS/NOISE_UM "
        "(e.g. random/700/1/4/0.25)",
    )
    args = ap.parse_args(argv)
    if args.quick:
        args.seeds, args.sizes, args.pair_seeds, args.clean = 1, [1.0], 1, 3
    cases = make_cases(args)
    before = provenance()
    print(f"{len(cases)} cases on {args.jobs} process(es); diagnosis {before}", flush=True)
    t0 = time.perf_counter()
    results: list[dict[str, Any]] = []
    with ProcessPoolExecutor(max_workers=args.jobs) as pool:
        fixed = {k: v for k, v in (("model", args.model), ("design", args.design)) if v}
        futures = {pool.submit(_run, c, fixed): c for c in cases}
        for i, fut in enumerate(as_completed(futures), 1):
            r = fut.result()
            results.append(r)
            mark = "ok  " if r["named"] else ("ERR " if "error" in r else "MISS")
            print(
                f"[{i:>4}/{len(cases)} {time.perf_counter() - t0:7.0f}s] {mark} {r['case']} size={r['size']} seed={r['seed']}"
                f" {r.get('seconds', float('nan')):.1f}s",
                flush=True,
            )
    order = {c: k for k, c in enumerate(cases)}
    results.sort(key=lambda r: order[(r["case"], r["size"], r["seed"])])
    summary = summarise(results, args.sizes)
    print()
    print_table(summary, results, args.sizes)
    args.out.parent.mkdir(parents=True, exist_ok=True)
    payload = {
        "generator": "tests/independent_generator",
        "argv": sys.argv[1:] if argv is None else argv,
        "provenance": before,
        "diagnosis_changed_during_run": provenance() != before,
        "summary": summary,
        "cases": results,
        "wall_s": time.perf_counter() - t0,
    }
    args.out.write_text(json.dumps(payload, indent=1, default=_json_default))
    print(f"\nwrote {args.out}")
    return 0


def _json_default(obj: Any) -> Any:
    if isinstance(obj, np.generic):
        return obj.item()
    if isinstance(obj, np.ndarray):
        return obj.tolist()
    return str(obj)


if __name__ == "__main__":
    raise SystemExit(main())
