"""The status rule of a corrected point: the one place that decides which status applies.

Both correction paths use it: the batch path (:meth:`CorrectionGrid.correct`, through the
vectorised :func:`statuses`) and the single-reading fast path
(:meth:`CorrectionGrid.correct_point`, through :data:`STATUS_BY_FLAGS`). Each path only works
out the per-point *flags*; the rule below turns them into the status.

Statuses (first applicable reason):

* ``"invalid_input"`` — NaN/inf coordinates or stylus (:data:`INVALID`); NaN coordinates out;
* ``"outside_volume"`` — outside the volume (:data:`OUTSIDE`, more than :data:`VOLUME_TOL_MM`
  mm) with policy ``outside="refuse"``: NaN coordinates out, never extrapolated;
* ``"clamped_outside_volume"`` — outside with policy ``outside="clamp"``: the correction of the
  nearest point of the volume is applied;
* ``"no_temperature"`` — a temperature the grid needs is missing or NaN
  (:data:`NO_TEMPERATURE`): corrected geometrically, *without* that temperature's terms;
* ``"missing_input"`` — the same for a non-temperature signal such as ``dir_x``
  (:data:`MISSING_INPUT`);
* ``"ok"``.

Whether the output is refused (NaN) depends on the geometric flags and the policy only
(:func:`refused`): a path may stop before it reads the signals when :func:`refused` says so.
"""

from __future__ import annotations

from typing import Any

import numpy as np
from numpy.typing import NDArray

__all__ = [
    "INVALID",
    "MISSING_INPUT",
    "NO_TEMPERATURE",
    "OUTSIDE",
    "OUTSIDE_POLICIES",
    "REFUSED_STATUSES",
    "STATUS_BY_FLAGS",
    "STATUS_DTYPE",
    "VOLUME_TOL_MM",
    "check_policy",
    "point_status",
    "refused",
    "statuses",
]

STATUS_DTYPE = "<U22"
VOLUME_TOL_MM = 1e-9  # points this far outside the volume still count as inside
OUTSIDE_POLICIES = ("refuse", "clamp")

#: Per-point flags (bits), combined with ``|``.
INVALID = 1  # NaN/inf coordinate or stylus component
OUTSIDE = 2  # farther than VOLUME_TOL_MM outside the volume
NO_TEMPERATURE = 4  # a needed temperature missing or not finite
MISSING_INPUT = 8  # a needed non-temperature signal missing or not finite
_ALL_FLAGS = 16

#: Statuses whose corrected coordinates are NaN.
REFUSED_STATUSES = frozenset({"invalid_input", "outside_volume"})


def point_status(flags: int, refuse: bool) -> str:
    """The status of a point with ``flags`` (bits above); ``refuse``: policy ``"refuse"``."""
    if flags & INVALID:
        return "invalid_input"
    if flags & OUTSIDE:
        return "outside_volume" if refuse else "clamped_outside_volume"
    if flags & NO_TEMPERATURE:
        return "no_temperature"
    if flags & MISSING_INPUT:
        return "missing_input"
    return "ok"


def refused(flags: int, refuse: bool) -> bool:
    """Whether a point with ``flags`` gets NaN coordinates (its status is a refusal)."""
    return point_status(flags, refuse) in REFUSED_STATUSES


#: ``STATUS_BY_FLAGS[refuse][flags]``: :func:`point_status` tabulated, for the fast path.
STATUS_BY_FLAGS: dict[bool, tuple[str, ...]] = {
    r: tuple(point_status(f, r) for f in range(_ALL_FLAGS)) for r in (False, True)
}
_STATUS_ARRAY = {r: np.array(STATUS_BY_FLAGS[r], dtype=STATUS_DTYPE) for r in (False, True)}
_REFUSED_ARRAY = {
    r: np.array([refused(f, r) for f in range(_ALL_FLAGS)], dtype=bool) for r in (False, True)
}


def statuses(flags: NDArray[Any], refuse: bool) -> tuple[NDArray[np.str_], NDArray[np.bool_]]:
    """:func:`point_status` and :func:`refused` of every point of ``flags`` (N,) (vectorised)."""
    return _STATUS_ARRAY[refuse][flags], _REFUSED_ARRAY[refuse][flags]


def check_policy(policy: str) -> str:
    """``policy`` if it is ``"refuse"`` or ``"clamp"``; ValueError otherwise."""
    if policy not in OUTSIDE_POLICIES:
        raise ValueError(f"outside must be 'refuse' or 'clamp', got {policy!r}")
    return policy
