"""Stretches of an axis' travel where the plan's data cannot see how far the axis' positional
error rises (docs/calibration.md §11): a ball plate's placements each have an unknown
translation, so a plate sees the shape of ``dA_A`` inside each placement's reach but not the rise
between two placements that do not overlap along axis A. A laser linear run along A, or a
multilateration (one dead path per station for all its points), spans such a gap; without
either, only the smoothness prior bridges it. Units: mm.
"""

from __future__ import annotations

from typing import Any

from ..parametric_errors import AXES

__all__ = ["gap_warning", "plate_gaps"]

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
