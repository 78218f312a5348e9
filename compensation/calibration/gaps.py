"""Stretches of an axis' travel the plan's data do not see (docs/calibration.md §11).

**Reach** (:func:`dataset_reach`, :func:`reach_summary`): per data set and axis the range of its
measurement positions, and the stretches of the travel that no data set reaches — there every
error is the smoothness prior's extrapolation.

**Gaps between plate placements** (:func:`plate_gaps`): a ball plate's placements each have an
unknown translation, so a plate sees the shape of ``dA_A`` inside each placement's reach but not the rise
between two placements that do not overlap along axis A. A laser linear run along A, or a
multilateration (one dead path per station for all its points), spans such a gap; without
either, only the smoothness prior bridges it. Units: mm.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from ..parametric_errors import AXES

__all__ = ["dataset_reach", "gap_warning", "plate_gaps", "reach_summary", "reach_warning"]

GAP_FRACTION = 0.1  # a gap is reported when it exceeds this fraction of the axis' travel


def _reach(datasets: list[Any], axis: int) -> list[tuple[float, float]]:
    """The [min, max] along ``axis`` of every plate placement that lies along it (its extent
    along the axis at least half its largest: a plate standing across the axis sees none of
    the rise along it) (mm)."""
    out = []
    for ds in datasets:
        d = ds.data
        if ds.kind != "plate":
            continue
        for k in range(len(d.placements)):
            q = d.q_mm[d.placement == k]
            if not q.size:
                continue
            extent = q.max(axis=0) - q.min(axis=0)
            if extent[axis] >= 0.5 * extent.max():
                out.append((float(q[:, axis].min()), float(q[:, axis].max())))
    return out


def _spans(datasets: list[Any], axis: int) -> bool:
    """Whether a data set other than a plate ties the whole travel of ``axis`` together."""
    for ds in datasets:
        if ds.kind == "multilateration":
            return True
        if ds.kind == "laser":
            runs = getattr(ds.data, "runs", ())
            if any(r.kind == "linear" and r.axis == axis for r in runs):
                return True
    return False


def plate_gaps(datasets: list[Any], lower_mm: Any, upper_mm: Any) -> list[dict[str, Any]]:
    """Per axis, the stretches (mm) between the plates' placements, longer than
    :data:`GAP_FRACTION` of the travel, that no other data set spans."""
    out = []
    for axis, name in enumerate(AXES):
        reach = sorted(_reach(datasets, axis))
        if not reach or _spans(datasets, axis):
            continue
        travel = float(upper_mm[axis] - lower_mm[axis])
        end = reach[0][1]
        for lo, hi in reach[1:]:
            if lo - end > GAP_FRACTION * travel:
                out.append({"axis": name, "error": f"d{name}_{name}", "from_mm": end, "to_mm": lo})
            end = max(end, hi)
    return out


def gap_warning(gaps: list[dict[str, Any]]) -> str | None:
    """One warning line naming the gaps, or None."""
    if not gaps:
        return None
    where = "; ".join(
        f"{g['error']} between {g['axis']} = {g['from_mm']:.0f} and {g['to_mm']:.0f} mm"
        for g in gaps
    )
    return (
        "the plate placements leave gaps along an axis that no laser linear run or "
        f"multilateration spans: {where}. Each placement's translation is unknown, so how far "
        "the positional error rises across a gap is not seen — only the smoothness prior "
        "bridges it (its U says so); cover the axis end to end"
    )


# --------------------------------------------------------------------------- the data's reach
REACH_WARN_FRACTION = 0.05  # a stretch reached by no data set is warned of beyond this fraction


def _positions(ds: Any, axis: int) -> Any:
    """The measurement positions along ``axis`` (mm) of one data set: a laser set's run
    positions along the axis it moves (a run at a fixed line samples the other axes' errors at
    one point only: no reach along them), a plate's ball centres, multilateration's points."""
    if ds.kind == "laser":
        runs = getattr(ds.data, "runs", ())
        parts = [r.position_mm for r in runs if r.kind != "squareness" and r.axis == axis]
        return np.concatenate(parts) if parts else np.zeros(0)
    return np.asarray(ds.data.q_mm, dtype=float)[:, axis]


def dataset_reach(ds: Any, lower_mm: Any, upper_mm: Any) -> dict[str, dict[str, float] | None]:
    """Per axis, the range of one data set's measurement positions: ``from_mm``, ``to_mm``,
    ``percent_of_travel`` (the range's length over the ``[volume]`` travel, %); None for an axis
    the set has no position along (a laser set without a run along it)."""
    out: dict[str, dict[str, float] | None] = {}
    for axis, name in enumerate(AXES):
        p = _positions(ds, axis)
        p = p[np.isfinite(p)]
        if not p.size:
            out[name] = None
            continue
        travel = float(upper_mm[axis] - lower_mm[axis])
        lo, hi = float(p.min()), float(p.max())
        out[name] = {
            "from_mm": lo,
            "to_mm": hi,
            "percent_of_travel": 100.0 * (hi - lo) / travel if travel > 0 else 100.0,
        }
    return out


def _merged(spans: list[tuple[float, float]]) -> list[tuple[float, float]]:
    out: list[tuple[float, float]] = []
    for lo, hi in sorted(spans):
        if out and lo <= out[-1][1]:
            out[-1] = (out[-1][0], max(out[-1][1], hi))
        else:
            out.append((lo, hi))
    return out


def reach_summary(datasets: list[Any], lower_mm: Any, upper_mm: Any) -> dict[str, Any]:
    """What the plan's data reach: per axis the union of the data sets' ranges (``covered``
    stretches, mm, and ``percent_of_travel`` covered) and ``unreached``: every stretch of an
    axis' travel, longer than :data:`REACH_WARN_FRACTION` of it, inside no data set's range —
    there the errors are the smoothness prior's extrapolation, not a measurement."""
    reaches = [dataset_reach(ds, lower_mm, upper_mm) for ds in datasets]
    per_axis: dict[str, Any] = {}
    unreached: list[dict[str, Any]] = []
    for axis, name in enumerate(AXES):
        lo_v, hi_v = float(lower_mm[axis]), float(upper_mm[axis])
        travel = hi_v - lo_v
        ranges = [span for r in reaches if (span := r[name]) is not None]
        spans = _merged([(max(r["from_mm"], lo_v), min(r["to_mm"], hi_v)) for r in ranges])
        covered = sum(hi - lo for lo, hi in spans)
        per_axis[name] = {
            "travel_mm": [lo_v, hi_v],
            "covered_mm": [[lo, hi] for lo, hi in spans],
            "percent_of_travel": 100.0 * covered / travel if travel > 0 else 100.0,
        }
        edges = [lo_v, *(v for s in spans for v in s), hi_v]
        for a, b in zip(edges[0::2], edges[1::2], strict=True):
            if b - a > REACH_WARN_FRACTION * travel:
                unreached.append(
                    {
                        "axis": name,
                        "from_mm": a,
                        "to_mm": b,
                        "percent_of_travel": 100.0 * (b - a) / travel,
                    }
                )
    return {
        "per_axis": per_axis,
        "unreached": unreached,
        "warn_above_percent_of_travel": 100.0 * REACH_WARN_FRACTION,
    }


def reach_warning(unreached: list[dict[str, Any]]) -> str | None:
    """One warning line naming every axis stretch no data set reaches, or None."""
    if not unreached:
        return None
    where = "; ".join(
        f"{u['axis']} = {u['from_mm']:.0f} … {u['to_mm']:.0f} mm "
        f"({u['percent_of_travel']:.0f} % of its travel)"
        for u in unreached
    )
    return (
        f"part of the volume is reached by no data set: {where}. The errors there are the "
        "smoothness prior's extrapolation of what was measured, not a measurement (their U is "
        "the prior's); extend the plate placements, laser runs or multilateration points to "
        "the ends of the travel"
    )
