"""One machine's trend over its diagnosed sessions: per effect the series of its parameters with
a line and its uncertainty, the changes shown at a stated false-alarm rate, and a plain summary.

**False-alarm rate.** Every effect named on a machine is tested at ``alpha`` (default 1 %),
family-wise over its tests by a weighted Bonferroni split fixed in advance: half of ``alpha`` for
the presence test (did the effect appear or vanish), the other half shared equally by the trend
and step tests of each of its numeric parameters. So, for an effect whose diagnoses do not
change over time (exchangeable sessions: the null of each test), the chance that any change is
reported for it is at most ``alpha``; a machine with E named effects is flagged falsely with
probability at most E·``alpha``. The tests: :mod:`.changepoint`.

**What is reported as a change.** ``appeared`` / ``disappeared`` (between the last session before
the split and the first after it), and per parameter ``creep`` (a significant line: rate per day
± u) or ``step`` (a significant jump: before/after ± u) — whichever of line and step fits the
values better when either test is significant. Figures are per day; u are standard (k = 1),
from the scatter between sessions.

**Summary.** A machine needs recalibration of every effect with a change whose latest state is
present; an effect named in at least :data:`PERSISTENT_SHARE` of the sessions without a change is
missing from the description but stable (extend the model once); otherwise nothing to do.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from .changepoint import (
    line_fit,
    presence_change,
    smallest_presence_p,
    step_change,
    trend_change,
)
from .series import EffectSeries, SessionEffects, effect_series

__all__ = ["PERSISTENT_SHARE", "TrendSettings", "machine_trend"]

PERSISTENT_SHARE = 0.75
"""An unchanged effect named in at least this share of the sessions is called persistent."""


@dataclass(frozen=True)
class TrendSettings:
    """``alpha``: the false-alarm rate per effect (module docstring)."""

    alpha: float = 0.01

    def __post_init__(self) -> None:
        if not 0.0 < self.alpha < 1.0:
            raise ValueError(f"alpha must be in (0, 1), got {self.alpha}")


def _fmt(x: float) -> str:
    return f"{x:.4g}"


def _parameter_trend(days: np.ndarray, dates: list[str], values: np.ndarray) -> dict[str, Any]:
    ok = np.isfinite(values)
    t, v = days[ok], values[ok]
    out: dict[str, Any] = {
        "dates": [d for d, keep in zip(dates, ok, strict=True) if keep],
        "values": [float(x) for x in v],
        "n": int(ok.sum()),
        "mean": float(v.mean()) if len(v) else None,
        "sd": float(v.std(ddof=1)) if len(v) > 1 else None,
        "u_mean": float(v.std(ddof=1) / np.sqrt(len(v))) if len(v) > 1 else None,
    }
    fit = line_fit(t, v)
    if fit is not None:
        last, u_last = fit.at(float(t[-1]))
        out.update(
            slope_per_day=fit.slope,
            u_slope_per_day=fit.u_slope,
            value_at_last=last,
            u_value_at_last=u_last,
            residual_sd=fit.residual_sd,
        )
    return out


def _presence(series: EffectSeries, dates: list[str], level: float) -> dict[str, Any] | None:
    test = presence_change(series.named)
    if test.p_value > level:
        return None
    n, s = test.n, test.split
    rate_before, rate_after = test.before / s, test.after / (n - s)
    kind = "appeared" if rate_after > rate_before else "disappeared"
    return {
        "kind": kind,
        "between": [dates[s - 1], dates[s]],
        "named_before": [test.before, s],
        "named_after": [test.after, n - s],
        "p_value": test.p_value,
        "level": level,
        "text": f"{series.name} {kind} between {dates[s - 1]} and {dates[s]} (named in "
        f"{test.before} of {s} sessions before, {test.after} of {n - s} from {dates[s]} on; "
        f"p = {test.p_value:.2g})",
    }


def _parameter_change(
    series: EffectSeries, pname: str, days: np.ndarray, dates: list[str], level: float
) -> dict[str, Any] | None:
    values = series.parameters[pname]
    ok = np.isfinite(values)
    t, v = days[ok], values[ok]
    d = [x for x, keep in zip(dates, ok, strict=True) if keep]
    p_line, fit = trend_change(t, v)
    step = step_change(v)
    p_step = step.p_value if step is not None else 1.0
    if min(p_line, p_step) > level or fit is None:
        return None
    rss_line = fit.residual_sd**2 * (fit.n - 2)
    if step is not None and p_step <= level and (p_line > level or step.rss < rss_line):
        k = step.split
        return {
            "kind": "step",
            "parameter": pname,
            "between": [d[k - 1], d[k]],
            "before": step.before,
            "u_before": step.u_before,
            "after": step.after,
            "u_after": step.u_after,
            "p_value": p_step,
            "level": level,
            "text": f"{series.name}: {pname} jumped between {d[k - 1]} and {d[k]} from "
            f"{_fmt(step.before)} ± {_fmt(step.u_before)} to {_fmt(step.after)} ± "
            f"{_fmt(step.u_after)} (p = {p_step:.2g})",
        }
    first, u_first = fit.at(float(t[0]))
    last, u_last = fit.at(float(t[-1]))
    return {
        "kind": "creep",
        "parameter": pname,
        "rate_per_day": fit.slope,
        "u_rate_per_day": fit.u_slope,
        "from": [d[0], first, u_first],
        "to": [d[-1], last, u_last],
        "p_value": p_line,
        "level": level,
        "text": f"{series.name}: {pname} creeping {fit.slope:+.3g} ± {fit.u_slope:.2g} per day "
        f"({_fmt(first)} on {d[0]} → {_fmt(last)} ± {_fmt(u_last)} on {d[-1]}; "
        f"p = {p_line:.2g})",
    }


def _effect_changes(
    series: EffectSeries, days: np.ndarray, dates: list[str], alpha: float
) -> list[dict[str, Any]]:
    found: list[dict[str, Any]] = []
    presence = _presence(series, dates, alpha / 2)
    if presence is not None:
        found.append(presence)
    n_param_tests = 2 * max(len(series.parameters), 1)
    for pname in series.parameters:
        change = _parameter_change(series, pname, days, dates, alpha / 2 / n_param_tests)
        if change is not None:
            found.append(change)
    for c in found:
        c.update(effect=series.name, cause=series.cause, keys=series.keys)
    return found


def _summary(
    machine: str,
    trend: dict[str, Any],
    changes: list[dict[str, Any]],
    n: int,
    alpha: float,
) -> tuple[str, list[str]]:
    recal: list[str] = []
    lines: list[str] = []
    for name, eff in trend.items():
        mine = [c for c in changes if c["effect"] == name]
        if mine:
            if eff["named"][-1] or any(c["kind"] != "disappeared" for c in mine):
                recal.append(name)
            lines.append("; ".join(c["text"] for c in mine))
    persistent = [
        name
        for name, eff in trend.items()
        if name not in recal
        and not any(c["effect"] == name for c in changes)
        and eff["named_in"] >= PERSISTENT_SHARE * n
    ]
    if recal:
        head = f"{machine} needs recalibration of {', '.join(recal)}."
    elif any(c["kind"] == "disappeared" for c in changes):
        head = f"{machine}: an effect no longer seen (check whether it was compensated)."
    else:
        head = f"{machine}: nothing to recalibrate (no change at α = {alpha:g} per effect)."
    for name in persistent:
        eff = trend[name]
        lines.append(
            f"{name} named in {eff['named_in']} of {n} sessions without change: the description "
            "lacks it; extend the model once (cmm-comp extend)"
        )
    if n >= 2 and smallest_presence_p(n) > alpha / 2:
        lines.append(
            f"only {n} sessions: an appearing or vanishing effect cannot be shown at this "
            "false-alarm rate yet"
        )
    return " ".join([head, *(f"{line}." for line in lines)]), recal


def machine_trend(
    machine: str, sessions: Sequence[SessionEffects], settings: TrendSettings | None = None
) -> dict[str, Any]:
    """``{"dates", "sessions", "trend", "changes", "summary", "recalibrate", "false_alarm"}`` of
    one machine (module docstring); ``sessions`` in any order (sorted by date, then path)."""
    cfg = settings or TrendSettings()
    ordered = sorted(sessions, key=lambda s: (s.day, s.path))
    dates = [s.day.isoformat() for s in ordered]
    n = len(ordered)
    days = np.array([(s.day - ordered[0].day).days for s in ordered], dtype=float) if n else None
    trend: dict[str, Any] = {}
    changes: list[dict[str, Any]] = []
    for name, series in effect_series(ordered).items():
        assert days is not None
        trend[name] = {
            "cause": series.cause,
            "keys": series.keys,
            "named": [bool(x) for x in series.named],
            "named_in": int(series.named.sum()),
            "parameters": {
                p: _parameter_trend(days, dates, v) for p, v in series.parameters.items()
            },
        }
        changes.extend(_effect_changes(series, days, dates, cfg.alpha))
    summary, recal = _summary(machine, trend, changes, n, cfg.alpha)
    return {
        "dates": dates,
        "paths": [s.path for s in ordered],
        "sessions": n,
        "trend": trend,
        "changes": changes,
        "summary": summary,
        "recalibrate": recal,
        "false_alarm": {
            "alpha_per_effect": cfg.alpha,
            "effects_tested": len(trend),
            "method": "per effect: presence test at alpha/2 (exact conditional), each numeric "
            "parameter's line and step tests at alpha/2/(2·parameters) (Bonferroni)",
        },
    }
