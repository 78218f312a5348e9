"""Tables of benchmarks/bench_discovery_heldout.py: per cause × size, pairs, clean sessions,
model, design, time per case, and every miss with what was named instead."""

from __future__ import annotations

import argparse
from collections import defaultdict
from collections.abc import Callable, Iterable
from dataclasses import dataclass, field
from typing import Any

import numpy as np


@dataclass
class Outcome:
    plan: Any  # the benchmark's Plan: kind, causes, sizes, seed, design_rule, case_id
    summary: dict[str, Any] = field(default_factory=dict)
    score: dict[str, Any] = field(default_factory=dict)
    wall_s: float = float("nan")
    cpu_s: float = float("nan")
    elapsed_s: float | None = None
    exit_code: int | None = None
    error: str | None = None
    stderr_tail: str = ""
    design_redraws: int = 0
    started_utc: str | None = None
    code: str | None = None  # fingerprint of the code the CLI ran (HEAD + uncommitted files)


def _pct(k: int, n: int) -> str:
    return f"{k}/{n} ({100 * k / n:.0f} %)" if n else "—"


def _rate(outs: Iterable[Outcome], key: str) -> tuple[int, int]:
    outs = list(outs)
    return sum(1 for o in outs if o.score.get(key)), len(outs)


def _quantiles(values: list[float]) -> str:
    v = np.array([x for x in values if x is not None and np.isfinite(x)])
    if v.size == 0:
        return "—"
    return f"median {np.median(v):.1f}  p90 {np.percentile(v, 90):.1f}  worst {v.max():.1f}"


def _table(title: str, header: list[str], rows: list[list[str]]) -> list[str]:
    widths = [max(len(str(r[i])) for r in [header, *rows]) for i in range(len(header))]
    line = "  ".join("-" * w for w in widths)
    out = [f"\n{title}", "  ".join(h.ljust(w) for h, w in zip(header, widths, strict=True)), line]
    out += ["  ".join(str(c).ljust(w) for c, w in zip(r, widths, strict=True)) for r in rows]
    return out


def _grouped(
    title: str, outs: list[Outcome], key: Callable[[Outcome], str], order: list[str] | None = None
) -> list[str]:
    groups: dict[str, list[Outcome]] = defaultdict(list)
    for o in outs:
        groups[key(o)].append(o)
    names = order or sorted(groups)
    rows = []
    for name in names:
        g = groups.get(name, [])
        if not g:
            continue
        rows.append(
            [
                name,
                _pct(*_rate(g, "named")),
                _pct(*_rate(g, "strict")),
                _pct(*_rate(g, "heldout_ok")),
            ]
        )
    return _table(title, ["", "named", "strict", "held-out OK"], rows)


def variant_family(cause: str, variant: str) -> str:
    """A readable family of a generator variant: the coupling's relation and shape along its own
    axis, the beam's support and calibration state, otherwise the variant's first part."""
    parts = variant.split("/")
    if cause == "coupling" and len(parts) == 2:
        return f"{cause}: {parts[0]}, {parts[1].split('x')[-1]} along its axis"
    if cause == "thermal_gradient":
        return f"{cause}: {parts[0]}, {parts[-1]}" if len(parts) > 1 else f"{cause}: {parts[0]}"
    if cause == "squareness_drift":
        return f"{cause}: {variant}"
    return f"{cause}: {parts[0]}"


def _noise_band(o: Outcome) -> str:
    s = o.summary.get("design", {}).get("noise_um", 0.0)
    return "σ 0.25" if s <= 0.25 else ("σ 0.26–0.5" if s <= 0.5 else "σ 0.51–1.0")


def report(
    outs: list[Outcome], args: argparse.Namespace, meta: dict[str, Any]
) -> tuple[list[str], dict[str, Any]]:
    lines = [
        f"held-out discovery benchmark at {meta['commit'][:12]} ({meta['started']}), "
        f"{len(outs)} cases, --jobs {args.jobs}, child BLAS threads {meta['child_blas_threads']}"
    ]
    if meta.get("commit_end") and meta["commit_end"] != meta["commit"]:
        lines.append(f"NOTE: HEAD moved to {meta['commit_end'][:12]} during the run")
    dirty = sorted(set(meta.get("uncommitted_start", [])) | set(meta.get("uncommitted_end", [])))
    if dirty:
        lines.append(
            f"NOTE: uncommitted changes under compensation/ or cli/ during the run: {', '.join(dirty)}"
        )
    ran = [o for o in outs if o.summary]
    singles = [o for o in ran if o.plan.kind == "single"]
    pairs = [o for o in ran if o.plan.kind == "pair"]
    clean = [o for o in ran if o.plan.kind == "clean"]
    rows = []
    summary_rows: dict[str, Any] = {}
    for cause in args.causes:
        row = [cause]
        mine = [o for o in singles if o.plan.causes[0] == cause]
        for size in args.sizes:
            row.append(_pct(*_rate([o for o in mine if o.plan.sizes[0] == size], "named")))
        k, n = _rate(mine, "named")
        ks, _ = _rate(mine, "strict")
        kh, _ = _rate(mine, "heldout_ok")
        row += [_pct(k, n), _pct(ks, n), _pct(kh, n)]
        rows.append(row)
        summary_rows[cause] = {"named": k, "strict": ks, "heldout_ok": kh, "n": n}
    header = [
        "cause",
        *[f"{s:g}× named" for s in args.sizes],
        "all named",
        "all strict",
        "held-out OK",
    ]
    lines += _table("single causes (named = with alternatives)", header, rows)
    k, n = _rate(singles, "named")
    ks, _ = _rate(singles, "strict")
    kh, _ = _rate(singles, "heldout_ok")
    lines.append(
        "  ".join(
            ["all singles", _pct(k, n), "strict " + _pct(ks, n), "held-out OK " + _pct(kh, n)]
        )
    )

    lines += _grouped(
        "single causes per variant family (all sizes)",
        singles,
        lambda o: variant_family(o.plan.causes[0], o.summary["hidden"][0]["variant"]),
    )

    pair_rows = []
    for o in pairs:
        pair_rows.append(
            [
                o.plan.case_id,
                "yes" if o.score.get("named") else "no",
                "yes" if o.score.get("strict") else "no",
                "yes" if o.score.get("heldout_ok") else "no",
            ]
        )
    lines += _table("pairs", ["case", "named", "strict", "held-out OK"], pair_rows)
    kp, npairs = _rate(pairs, "named")
    kps, _ = _rate(pairs, "strict")
    lines.append(f"all pairs  named {_pct(kp, npairs)}  strict {_pct(kps, npairs)}")

    fa = [o for o in clean if not o.score.get("named")]
    kc, nc = _rate(clean, "heldout_ok")
    lines.append(
        f"\nclean sessions: false alarms {_pct(len(fa), len(clean))}, held-out OK {_pct(kc, nc)}"
    )

    lines += _grouped("per model (all cases)", ran, lambda o: o.summary["design"]["model"])
    design_keys: list[tuple[str, Callable[[Outcome], str]]] = [
        (
            "design rule",
            lambda o: (
                "default (outside check)"
                if o.plan.design_rule == "default" and o.design_redraws == 0
                else "variant"
            ),
        ),
        ("layout", lambda o: o.summary["design"]["layout"]),
        ("styli", lambda o: f"{o.summary['design']['styli']} styli"),
        ("duration", lambda o: f"{o.summary['design']['duration_h']:g} h"),
        ("points", lambda o: f"{o.summary['design']['n_points']} points"),
        ("noise", _noise_band),
    ]
    for name, fn in design_keys:
        lines += _grouped(f"per design: {name} (all cases)", ran, fn)

    walls = [o.wall_s for o in ran]
    cpus = [o.cpu_s for o in ran]
    els = [o.elapsed_s for o in ran if o.elapsed_s is not None]
    lines.append("\ntime per case, s")
    lines.append(f"  wall (subprocess)  {_quantiles(walls)}")
    lines.append(f"  CPU  (subprocess)  {_quantiles(cpus)}")
    lines.append(f"  elapsed_s (JSON)   {_quantiles(els)}")
    by_n: dict[int, list[float]] = defaultdict(list)
    for o in ran:
        by_n[o.summary["design"]["n_points"]].append(o.cpu_s)
    for npts in sorted(by_n):
        lines.append(f"  CPU, {npts} points: {_quantiles(by_n[npts])}")
    slow = sorted(ran, key=lambda o: -o.cpu_s)[:3]
    lines.append("  slowest (CPU): " + "; ".join(f"{o.plan.case_id} {o.cpu_s:.1f} s" for o in slow))

    redrawn = [o for o in outs if o.design_redraws]
    if redrawn:
        lines.append(
            "\ndesigns redrawn because the cause could not show beyond a static table change: "
            + ", ".join(f"{o.plan.case_id} ×{o.design_redraws}" for o in redrawn)
        )
    failed = [o for o in outs if o.error]
    misses = [o for o in ran if not o.score.get("named")]
    lines.append(f"\nmisses ({len(misses)}) and failures ({len(failed)}):")
    for o in failed:
        lines.append(f"  FAIL {o.plan.case_id}: {o.error} {o.stderr_tail.strip()[-200:]!r}")
    for o in misses:
        d = o.summary["design"]["label"]
        hidden = (
            "; ".join(
                f"{h['label']} <{h['variant']}> share {h['table_share']:.2f} χ²nt {h['nontable_chi2']:.0f}"
                for h in o.summary["hidden"]
            )
            or "nothing (clean)"
        )
        named = " | ".join(o.score.get("named_labels") or []) or f"verdict {o.score.get('verdict')}"
        ratio = o.score.get("heldout_ratio")
        ho = f"{ratio:.2f}×σ3d" if isinstance(ratio, float) else "—"
        lines.append(
            f"  {o.plan.case_id} [{d}]\n      hidden: {hidden}\n      named:  {named}  (held-out {ho})"
        )

    goal_outs = singles + pairs
    kg, ng = _rate(goal_outs, "named")
    lines.append(
        f"\nissue 11 goal (≥ 95 % named at 0.5–3×, pairs included; no false alarm; held-out ≤ 1.5×): "
        f"named {_pct(kg, ng)}, false alarms {len(fa)}/{len(clean)}, "
        f"held-out OK {_pct(*_rate(ran, 'heldout_ok'))}"
    )
    summary = {
        "singles": summary_rows,
        "singles_all": {"named": k, "strict": ks, "heldout_ok": kh, "n": n},
        "pairs": {"named": kp, "strict": kps, "n": npairs},
        "clean": {"false_alarms": len(fa), "n": len(clean), "heldout_ok": kc},
        "goal_named": {"k": kg, "n": ng},
        "cpu_s": {
            "median": float(np.median(cpus)) if cpus else None,
            "max": max(cpus) if cpus else None,
        },
        "wall_s": {
            "median": float(np.median(walls)) if walls else None,
            "max": max(walls) if walls else None,
        },
    }
    return lines, summary
