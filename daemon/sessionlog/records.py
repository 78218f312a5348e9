"""Compact log records: the hot path hands the logger tuples, the writer builds the JSON objects.

Building a JSON-ready dict per CAN frame (hex string, nested stamp, nine keys) costs the
daemon's receive thread several µs per frame; a tuple of the frame's fields costs a fraction of
that. :meth:`.logger.HotPathQueue.log` therefore accepts, for the topics in
:data:`RECORD_BUILDERS`, a tuple in the layout documented below instead of a dict, and the
writer (the writer thread, or the child process of :class:`.process_writer.McapProcessLogger`)
turns it into exactly the payload the topic's schema describes. Tuples of ints, floats, str and
bytes also pickle several times faster than dicts, which is what the process writer's forwarder
pays per message.

This module imports only :mod:`.schemas` and :mod:`cmm_comp.protocol.codes` (the nm → mm
scaling), which is all the process writer's child needs of them.
"""

from __future__ import annotations

import math
import numbers
from collections.abc import Callable
from typing import Any

from cmm_comp.protocol.codes import mm3_from_nm

from .schemas import FRAME_DIRECTIONS, ns_from_can_timestamp, stamp_from_ns

FrameRecord = tuple[int, bool, int, bytes, float, str, bool, bool, bool, str]
"""``(arbitration_id, is_extended, dlc, data, timestamp_s, channel, is_fd, is_remote,
is_error, direction)``; ``timestamp_s`` is python-can's float seconds (0.0 when unknown),
``direction`` one of :data:`FRAME_DIRECTIONS` (a 9-field record without it is taken too and
writes no ``direction`` key). The CAN endpoint builds it from a ``can.Message``
(:func:`cmm_comp.daemon.can_endpoint.frame_record`)."""


RawRecord = tuple[
    int,
    float,
    float,
    float,
    tuple[int, int, int],
    tuple[bool, bool, bool],
    str,
    tuple[float, float, float],
    "tuple[float, float, float] | None",
]
"""``(seq, x_mm, y_mm, z_mm, travel_dir, valid, source, stylus_mm, probe_dir or None)``."""

CorrectedRecord = tuple[Any, ...]
"""``(seq, x_nm, y_nm, z_nm, status, correction_um, latency_us, applied, source, detail)``,
optionally followed by ``u_um``: ``(Ux, Uy, Uz)`` µm (finite, ≥ 0) or None (unknown) — given
for every answer made with a grid that carries U, written as ``ux_um``/``uy_um``/``uz_um``
(numbers, or ``null`` when unknown: never NaN); a 10-field record writes no U keys."""


_INT_MIN, _INT_MAX = -(2**63), 2**64 - 1


def _int(value: Any, what: str, lo: int = _INT_MIN, hi: int = _INT_MAX) -> int:
    """``value`` as an int in ``[lo, hi]``: ints (and numpy ints) only, never a float or bool
    turned into a plausible int. ValueError/TypeError naming ``what`` otherwise."""
    if type(value) is not int:
        if isinstance(value, bool | float) or not hasattr(value, "__index__"):
            raise TypeError(f"{what}: {type(value).__name__} {value!r:.40} is not an integer")
        value = value.__index__()
    if not lo <= value <= hi:
        raise ValueError(f"{what}: {value!r:.40} is outside [{lo}, {hi}]")
    return value


def _real(value: Any, what: str) -> float:
    """``value`` as a float: floats and ints within 64 bits (numpy too), not bool/None/str.
    Non-finite values pass here and are refused by the encoder (``allow_nan=False``)."""
    if type(value) is float:
        return value
    if isinstance(value, bool) or not isinstance(value, numbers.Real):
        raise TypeError(f"{what}: {type(value).__name__} {value!r:.40} is not a number")
    if isinstance(value, int) and not _INT_MIN <= value <= _INT_MAX:
        raise ValueError(f"{what}: integer out of the 64-bit range")
    return float(value)


def _str(value: Any, what: str) -> str:
    if type(value) is str:
        return value
    raise TypeError(f"{what}: {type(value).__name__} {value!r:.40} is not a string")


def _bool(value: Any, what: str) -> bool:
    """``value`` if a bool (numpy bools too), never the truth value of something else."""
    if type(value) is bool:
        return value
    if getattr(getattr(value, "dtype", None), "kind", "") == "b":
        return bool(value)
    raise TypeError(f"{what}: {type(value).__name__} {value!r:.40} is not a boolean")


def _three(value: Any, what: str) -> tuple[Any, Any, Any] | list[Any]:
    """``value`` if a tuple or list of three items (x, y, z)."""
    if type(value) in (tuple, list) and len(value) == 3:
        return value  # type: ignore[no-any-return]
    raise TypeError(f"{what}: {type(value).__name__} {value!r:.40} is not three values (x, y, z)")


def _channel(value: Any) -> str:
    """python-can's channel: a name or a number."""
    if type(value) is str:
        return value
    if type(value) is int:
        return str(_int(value, "channel"))
    raise TypeError(f"channel: {type(value).__name__} {value!r:.40} is not a str or int")


def frame_payload(rec: FrameRecord | tuple[Any, ...]) -> dict[str, Any]:
    """The ``/cmm/can_rx`` / ``/cmm/can_tx`` payload of a :data:`FrameRecord`."""
    if len(rec) not in (9, 10):
        raise ValueError(f"a CAN frame record has 9 or 10 fields, not {len(rec)}")
    can_id, ext, dlc, data, ts, channel, fd, remote, error = rec[:9]
    if not isinstance(data, bytes | bytearray | memoryview):
        raise TypeError(f"data: {type(data).__name__} is not bytes")
    ts = _real(ts, "timestamp_s") if ts is not None else 0.0
    ts = ts if ts and ts == ts else 0.0  # None, 0 or NaN: unknown (inf: refused below)
    out = {
        "arbitration_id": _int(can_id, "arbitration_id", 0, 2**29 - 1),
        "is_extended": _bool(ext, "is_extended"),
        "dlc": _int(dlc, "dlc", 0, 64),
        "data": bytes(data).hex(),
        "bus_stamp": stamp_from_ns(_int(ns_from_can_timestamp(ts), "timestamp_s", 0)),
        "channel": _channel(channel),
        "is_fd": _bool(fd, "is_fd"),
        "is_remote_frame": _bool(remote, "is_remote_frame"),
        "is_error_frame": _bool(error, "is_error_frame"),
    }
    if len(rec) == 10:
        direction = rec[9]
        if direction not in FRAME_DIRECTIONS or type(direction) is not str:
            raise ValueError(f"direction: {direction!r:.40} is not one of {FRAME_DIRECTIONS}")
        out["direction"] = direction
    return out


def raw_payload(rec: RawRecord) -> dict[str, Any]:
    """The ``/cmm/raw`` payload of a :data:`RawRecord`."""
    seq, x, y, z, travel, valid, source, stylus_mm, probe = rec
    stylus = _three(stylus_mm, "stylus_mm")
    out: dict[str, Any] = {
        "seq": _int(seq, "seq", 0),
        "x_mm": _real(x, "x_mm"),
        "y_mm": _real(y, "y_mm"),
        "z_mm": _real(z, "z_mm"),
        "travel_dir": [_int(v, "travel_dir", -1, 1) for v in _three(travel, "travel_dir")],
        "valid": [_bool(v, "valid") for v in _three(valid, "valid")],
        "source": _str(source, "source"),
        "stylus_x_mm": _real(stylus[0], "stylus_x_mm"),
        "stylus_y_mm": _real(stylus[1], "stylus_y_mm"),
        "stylus_z_mm": _real(stylus[2], "stylus_z_mm"),
    }
    if probe is not None:
        dirs = _three(probe, "probe direction")
        out["dir_x"], out["dir_y"], out["dir_z"] = (_real(v, "probe direction") for v in dirs)
    return out


def _u_component(value: Any, what: str) -> float:
    """One U component: a finite number ≥ 0 (NaN, inf, negative: an error, never written)."""
    u = _real(value, what)
    if not 0.0 <= u < math.inf:
        raise ValueError(f"{what}: {u!r} is not a finite uncertainty ≥ 0 (unknown is None)")
    return u


def corrected_payload(rec: CorrectedRecord) -> dict[str, Any]:
    """The ``/cmm/corrected`` payload of a :data:`CorrectedRecord` (positions nm → mm)."""
    if len(rec) not in (10, 11):
        raise ValueError(f"a /cmm/corrected record has 10 or 11 fields, not {len(rec)}")
    seq, x_nm, y_nm, z_nm, status, corr_um, latency_us, applied, source, detail = rec[:10]
    x_mm, y_mm, z_mm = mm3_from_nm((_int(x_nm, "x_nm"), _int(y_nm, "y_nm"), _int(z_nm, "z_nm")))
    dx, dy, dz = _three(corr_um, "correction_um")
    out: dict[str, Any] = {
        "seq": _int(seq, "seq", 0),
        "x_mm": x_mm,
        "y_mm": y_mm,
        "z_mm": z_mm,
        "status": _str(status, "status"),
        "dx_um": _real(dx, "dx_um"),
        "dy_um": _real(dy, "dy_um"),
        "dz_um": _real(dz, "dz_um"),
        "latency_us": _real(latency_us, "latency_us"),
        "applied": _int(applied, "applied", 0),
        "source": _str(source, "source"),
    }
    if len(rec) == 11:
        u_um = rec[10]
        if u_um is None:
            out["ux_um"] = out["uy_um"] = out["uz_um"] = None
        else:
            ux, uy, uz = _three(u_um, "u_um")
            out["ux_um"] = _u_component(ux, "ux_um")
            out["uy_um"] = _u_component(uy, "uy_um")
            out["uz_um"] = _u_component(uz, "uz_um")
    if detail:
        out["detail"] = _str(detail, "detail")
    return out


RECORD_BUILDERS: dict[str, Callable[[Any], dict[str, Any]]] = {
    "/cmm/can_rx": frame_payload,
    "/cmm/can_tx": frame_payload,
    "/cmm/raw": raw_payload,
    "/cmm/corrected": corrected_payload,
}
"""Topics that accept a compact tuple record, and the function that builds the payload."""


def expand(topic: str, payload: dict[str, Any] | tuple[Any, ...]) -> dict[str, Any]:
    """The JSON object for a logged payload: a dict as is, a record built by its topic's
    builder (KeyError for a topic without one, ValueError/TypeError for a malformed record)."""
    if type(payload) is tuple:
        return RECORD_BUILDERS[topic](payload)
    return payload  # type: ignore[return-value]
