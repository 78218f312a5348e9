"""What each format can hold, where that limit comes from, and the error raised when a model or an
option does not fit (never a silently limited or wrong table)."""

from __future__ import annotations

from ..errors import ExportError

__all__ = ["LINUXCNC_MAX_POINTS", "POINT_LIMITS", "SGN32", "ExportError"]

#: LinuxCNC's motion module holds this many triplets per joint (EMCMOT_COMP_SIZE).
LINUXCNC_MAX_POINTS = 256
#: TwinCAT list values (positions and compensation values, 0.1 µm) are signed 32-bit integers.
SGN32 = (-(2**31), 2**31 - 1)

#: format → (default points per table, hard limit or None, where it comes from)
POINT_LIMITS: dict[str, tuple[int, int | None, str]] = {
    "sinumerik-cec": (200, None, "MD18342 $MN_MM_CEC_MAX_POINTS (828D: 200, fixed)"),
    "twincat-cnc": (1001, None, "kw.crosscomp.max_points default 1001 (P-COMP-00060)"),
    "linuxcnc": (LINUXCNC_MAX_POINTS, LINUXCNC_MAX_POINTS, "EMCMOT_COMP_SIZE = 256 triplets"),
}
