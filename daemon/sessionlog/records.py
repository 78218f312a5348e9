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

from collections.abc import Callable
from typing import Any

from cmm_comp.protocol.codes import mm3_from_nm

from .schemas import ns_from_can_timestamp, stamp_from_ns

FrameRecord = tuple[int, bool, int, bytes, float, str, bool, bool, bool]
"""``(arbitration_id, is_extended, dlc, data, timestamp_s, channel, is_fd, is_remote,
is_error)``; ``timestamp_s`` is python-can's float seconds (0.0 when unknown). The CAN
endpoint builds it from a ``can.Message`` (:func:`cmm_comp.daemon.can_endpoint.frame_record`)."""

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

CorrectedRecord = tuple[int, int, int, int, str, tuple[float, float, float], float, int, str, str]
"""``(seq, x_nm, y_nm, z_nm, status, correction_um, latency_us, applied, source, detail)``."""


def frame_payload(rec: FrameRecord) -> dict[str, Any]:
    """The ``/cmm/can_rx`` / ``/cmm/can_tx`` payload of a :data:`FrameRecord`."""
    can_id, ext, dlc, data, ts, channel, fd, remote, error = rec
    ts = ts if ts and ts == ts else 0.0  # None or NaN: unknown
    return {
        "arbitration_id": int(can_id),
        "is_extended": bool(ext),
        "dlc": int(dlc),
        "data": bytes(data).hex(),
        "bus_stamp": stamp_from_ns(ns_from_can_timestamp(ts)),
        "channel": str(channel),
        "is_fd": bool(fd),
        "is_remote_frame": bool(remote),
        "is_error_frame": bool(error),
    }


def raw_payload(rec: RawRecord) -> dict[str, Any]:
    """The ``/cmm/raw`` payload of a :data:`RawRecord`."""
    seq, x, y, z, travel, valid, source, stylus, probe = rec
    out: dict[str, Any] = {
        "seq": seq,
        "x_mm": x,
        "y_mm": y,
        "z_mm": z,
        "travel_dir": list(travel),
        "valid": list(valid),
        "source": source,
        "stylus_x_mm": float(stylus[0]),
        "stylus_y_mm": float(stylus[1]),
        "stylus_z_mm": float(stylus[2]),
    }
    if probe is not None:
        out["dir_x"], out["dir_y"], out["dir_z"] = (float(v) for v in probe)
    return out


def corrected_payload(rec: CorrectedRecord) -> dict[str, Any]:
    """The ``/cmm/corrected`` payload of a :data:`CorrectedRecord` (positions nm → mm)."""
    seq, x_nm, y_nm, z_nm, status, corr_um, latency_us, applied, source, detail = rec
    x_mm, y_mm, z_mm = mm3_from_nm((x_nm, y_nm, z_nm))
    out: dict[str, Any] = {
        "seq": seq,
        "x_mm": x_mm,
        "y_mm": y_mm,
        "z_mm": z_mm,
        "status": status,
        "dx_um": corr_um[0],
        "dy_um": corr_um[1],
        "dz_um": corr_um[2],
        "latency_us": latency_us,
        "applied": int(applied),
        "source": source,
    }
    if detail:
        out["detail"] = detail
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
