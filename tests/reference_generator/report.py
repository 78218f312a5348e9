"""Rates from scored runs (``Run.as_dict()`` records, so a saved JSON can be re-read).

* per hidden effect: **named exactly** (the identity named, with the truth's source) and
  **named** (the identity, any source), by session kind (single family / mixed) × family ×
  direction mode × expected source;
* sessions whose truth names nothing (clean ones, and those where naming nothing is right):
  **false alarms** (verdict not ``none`` or any effect listed);
* **spurious** entries (named but hidden nowhere) on every session;
* time per session: wall and CPU of the whole CLI (the child's own CPU time: less sensitive to
  a shared machine's load than its wall time) and the diagnosis' own ``elapsed_s``.
"""

from __future__ import annotations

from collections import defaultdict
from collections.abc import Iterable, Mapping, Sequence
from typing import Any

import numpy as np

Record = Mapping[str, Any]


def kind_of(record: Record) -> str:
    family = str(record["case"]).split("/")[0]
    return family if family in ("mixed", "clean") else "single"


def hidden_outcomes(records: Iterable[Record]) -> list[dict[str, Any]]:
    """One row per hidden effect: kind, family, mode, source, named, exact, why not."""
    out = []
    for r in records:
        score = r.get("score")
        per = {h["hidden"]: h for h in (score or {}).get("per_hidden", [])}
        for h in r["hidden"]:
            if not h.get("required", True):  # the session cannot show it as itself
                continue
            label = h["label"]
            got = per.get(label, {})
            out.append(
                {
                    "case": r["case"],
                    "kind": kind_of(r),
                    "family": h["family"],
                    "mode": r["design"]["mode"],
                    "source": h["source"],
                    "label": label,
                    "named": bool(got.get("named")),
                    "exact": bool(got.get("exact")),
                    "why_not": got.get("why_not") or ("diagnosis failed" if not score else ""),
                    "rule": h.get("rule", ""),
                }
            )
    return out


def expects_nothing(record: Record) -> bool:
    return not record["hidden"]


def summary(records: Sequence[Record]) -> dict[str, Any]:
    rows = hidden_outcomes(records)
    n = len(rows)
    quiet = [r for r in records if expects_nothing(r)]
    false_alarms = [r["case"] for r in quiet if r.get("score") is None or r["score"]["false_alarm"]]
    spurious = [(r["case"], s) for r in records for s in (r.get("score") or {}).get("spurious", [])]
    failed = [r["case"] for r in records if r.get("exit_code") != 0]
    wall = np.array([r["wall_s"] for r in records], dtype=float)
    elapsed = np.array([r.get("elapsed_s") or np.nan for r in records], dtype=float)
    cpu = np.array([r.get("cpu_s", np.nan) for r in records], dtype=float)
    rows_n = np.array([r["rows"] for r in records])
    return {
        "sessions": len(records),
        "hidden_effects": n,
        "named_exactly": sum(r["exact"] for r in rows),
        "named": sum(r["named"] for r in rows),
        "rate_named_exactly": (sum(r["exact"] for r in rows) / n) if n else None,
        "rate_named": (sum(r["named"] for r in rows) / n) if n else None,
        "sessions_expecting_nothing": len(quiet),
        "clean_sessions": sum(1 for r in quiet if kind_of(r) == "clean"),
        "false_alarms": false_alarms,
        "spurious_entries": len(spurious),
        "sessions_with_spurious": len({c for c, _ in spurious}),
        "diagnosis_failed": failed,
        "wall_s": _stats(wall),
        "elapsed_s": _stats(elapsed),
        "cpu_s": _stats(cpu),
        "cpu_s_by_rows": {
            f"{lo}-{hi}": _stats(cpu[(rows_n >= lo) & (rows_n < hi)])
            for lo, hi in ((0, 1000), (1000, 2000), (2000, 4000))
        },
    }


def _stats(x: np.ndarray) -> dict[str, float | None]:
    x = x[np.isfinite(x)]
    if not x.size:
        return {"median": None, "p90": None, "max": None}
    return {
        "median": round(float(np.median(x)), 3),
        "p90": round(float(np.percentile(x, 90)), 3),
        "max": round(float(np.max(x)), 3),
    }


def rate_table(records: Sequence[Record]) -> str:
    """Rates by kind × family × direction mode × expected source, then the quiet sessions."""
    groups: dict[tuple[str, str, str, str], list[dict[str, Any]]] = defaultdict(list)
    for r in hidden_outcomes(records):
        groups[r["kind"], r["family"], r["mode"], r["source"]].append(r)
    lines = [
        f"{'kind':<7} {'family':<21} {'mode':<16} {'source':<10} {'exactly':>12} {'named':>12}",
        "-" * 83,
    ]
    for key in sorted(groups):
        g = groups[key]
        ex, nm = sum(r["exact"] for r in g), sum(r["named"] for r in g)
        lines.append(
            f"{key[0]:<7} {key[1]:<21} {key[2]:<16} {key[3]:<10} "
            f"{_frac(ex, len(g)):>12} {_frac(nm, len(g)):>12}"
        )
    quiet: dict[tuple[str, str], list[Record]] = defaultdict(list)
    for r in records:
        if expects_nothing(r):
            quiet[str(r["case"]).split("/")[0], str(r["case"]).split("/")[1]].append(r)
    if quiet:
        lines += ["", f"{'sessions where naming nothing is right':<52} {'false alarms':>14}"]
        for (fam, var), rs in sorted(quiet.items()):
            fa = sum(1 for r in rs if r.get("score") is None or r["score"]["false_alarm"])
            lines.append(f"{fam + '/' + var:<52} {_frac(fa, len(rs)):>14}")
    spur: dict[str, list[int]] = defaultdict(lambda: [0, 0])
    for r in records:
        fam = str(r["case"]).split("/")[0]
        spur[fam][0] += len((r.get("score") or {}).get("spurious", []))
        spur[fam][1] += 1
    lines += ["", "spurious entries per family (entries / sessions):"]
    lines.append(", ".join(f"{f} {a}/{b}" for f, (a, b) in sorted(spur.items())))
    return "\n".join(lines)


def _frac(k: int, n: int) -> str:
    return f"{k}/{n} ({100 * k / n:.0f} %)" if n else "-"


def misses_text(records: Sequence[Record], limit: int = 60) -> str:
    """Each hidden effect not named exactly, each false alarm and spurious entry, one line each."""
    lines = []
    for r in hidden_outcomes(records):
        if not r["exact"]:
            lines.append(f"MISS  {r['case']}: {r['label']} — {r['why_not']} [{r['rule']}]")
    for rec in records:
        score = rec.get("score") or {}
        if expects_nothing(rec) and (not score or score.get("false_alarm")):
            lines.append(f"ALARM {rec['case']}: named {score.get('spurious')}")
        elif score.get("spurious"):
            lines.append(f"EXTRA {rec['case']}: {', '.join(score['spurious'])}")
        if rec.get("exit_code") != 0:
            lines.append(
                f"FAIL  {rec['case']}: exit {rec.get('exit_code')} {rec.get('stderr_tail')}"
            )
    more = len(lines) - limit
    return "\n".join(lines[:limit] + ([f"… and {more} more"] if more > 0 else []))
