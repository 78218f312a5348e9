"""JSON of the compact records in one string format each: the writer's per-message fast path.

At 10,000 readings/s the log gets ~90,000 messages/s (3 received frames, 4 sent frames, the
reading and its answer). Building each payload dict (:mod:`.records`) and running it through
``json`` costs ~5 µs a message in the writer; one ``%`` format of the record's fields costs
~1.5 µs. :data:`FAST_JSON` maps each record topic to a function ``(record, log_time_ns) ->
bytes | None`` that returns **exactly the bytes** the general path
(:func:`.encoding.encode_message`: builder, ``stamp`` added, compact ``json``) gives, or
``None`` when a field is not of the plain type the format assumes (an ``int`` subclass, a
numpy number, a non-finite float, an ``int`` where a float is expected, a time of 0 …): the
writer then takes the general path, which either encodes it the same way or turns it into an
error record. ``tests/test_mcap_fastjson.py`` checks byte equality against the general path
over generated records, valid and invalid.

``log_time_ns`` must already be checked (an int in [0, 2⁶⁴ − 1]): the writer does so first.
"""

from __future__ import annotations

import json
from collections.abc import Callable
from typing import Any

from .schemas import FRAME_DIRECTIONS, NS_PER_S

__all__ = ["FAST_JSON"]

_INT_MAX = 2**64 - 1
_INT_MIN = -(2**63)
_TS_MAX = 1.8e10
"""Largest python-can timestamp taken by the fast path, s (year ~2540; 2⁶⁴ ns is 1.84e10 s)."""
_JSON_STR: dict[str, str] = {}
"""JSON text of the few strings records carry (channel, source, status), cached."""
_JSON_STR_MAX = 256
_BOOL = {True: "true", False: "false"}


def _jstr(s: str) -> str:
    """``json.dumps(s)`` (ASCII, as the log's encoder), cached for short repeated strings."""
    out = _JSON_STR.get(s)
    if out is None:
        out = json.dumps(s)
        if len(_JSON_STR) < _JSON_STR_MAX and len(s) <= 64:
            _JSON_STR[s] = out
    return out


def _finite(x: Any) -> bool:
    """True for a plain finite float (``x - x`` is NaN for NaN and ±inf)."""
    return type(x) is float and x - x == 0.0


_FRAME_HEAD = (
    '{"arbitration_id":%d,"is_extended":%s,"dlc":%d,"data":"%s",'
    '"bus_stamp":{"sec":%d,"nsec":%d},"channel":%s,"is_fd":%s,"is_remote_frame":%s,'
    '"is_error_frame":%s,'
)
_FRAME_TAIL = '"stamp":{"sec":%d,"nsec":%d}}'
# by the record's direction field (None: a 9-field record, no direction key)
_FRAME: dict[str | None, str] = {
    None: _FRAME_HEAD + _FRAME_TAIL,
    **{d: _FRAME_HEAD + f'"direction":"{d}",' + _FRAME_TAIL for d in FRAME_DIRECTIONS},
}


def frame_json(rec: tuple[Any, ...], t_ns: int) -> bytes | None:
    """The ``/cmm/can_rx`` / ``/cmm/can_tx`` message of a ``FrameRecord``, or None."""
    n = len(rec)
    if n == 10:
        can_id, ext, dlc, data, ts, channel, fd, remote, error, direction = rec
        fmt = _FRAME.get(direction) if type(direction) is str else None
        if fmt is None:
            return None
    elif n == 9:
        can_id, ext, dlc, data, ts, channel, fd, remote, error = rec
        fmt = _FRAME[None]
    else:
        return None
    if not (
        type(can_id) is int
        and 0 <= can_id <= 0x1FFFFFFF
        and type(dlc) is int
        and 0 <= dlc <= 64
        and type(data) is bytes
        and type(ts) is float
        and 0.0 < ts < _TS_MAX
        and type(channel) is str
        and type(ext) is bool
        and type(fd) is bool
        and type(remote) is bool
        and type(error) is bool
    ):
        return None
    sec = int(ts)  # ts > 0: int() floors, as ns_from_can_timestamp
    bus_ns = sec * NS_PER_S + round((ts - sec) * NS_PER_S)
    bsec, bnsec = divmod(bus_ns, NS_PER_S)
    ssec, snsec = divmod(t_ns, NS_PER_S)
    b = _BOOL
    return (
        fmt
        % (
            can_id,
            b[ext],
            dlc,
            data.hex(),
            bsec,
            bnsec,
            _jstr(channel),
            b[fd],
            b[remote],
            b[error],
            ssec,
            snsec,
        )
    ).encode()


def _three_floats(v: Any) -> bool:
    return (
        type(v) in (tuple, list)
        and len(v) == 3
        and _finite(v[0])
        and _finite(v[1])
        and _finite(v[2])
    )


_RAW = (
    '{"seq":%d,"x_mm":%r,"y_mm":%r,"z_mm":%r,"travel_dir":[%d,%d,%d],"valid":[%s,%s,%s],'
    '"source":%s,"stylus_x_mm":%r,"stylus_y_mm":%r,"stylus_z_mm":%r%s,"stamp":{"sec":%d,"nsec":%d}}'
)


def raw_json(rec: tuple[Any, ...], t_ns: int) -> bytes | None:
    """The ``/cmm/raw`` message of a ``RawRecord``, or None."""
    if len(rec) != 9:
        return None
    seq, x, y, z, travel, valid, source, stylus, probe = rec
    if not (
        type(seq) is int
        and 0 <= seq <= _INT_MAX
        and _finite(x)
        and _finite(y)
        and _finite(z)
        and type(travel) in (tuple, list)
        and len(travel) == 3
        and type(valid) in (tuple, list)
        and len(valid) == 3
        and type(source) is str
        and _three_floats(stylus)
    ):
        return None
    for v in travel:
        if type(v) is not int or not -1 <= v <= 1:
            return None
    for v in valid:
        if type(v) is not bool:
            return None
    extra = ""
    if probe is not None:
        if not _three_floats(probe):
            return None
        extra = f',"dir_x":{probe[0]!r},"dir_y":{probe[1]!r},"dir_z":{probe[2]!r}'
    b = _BOOL
    ssec, snsec = divmod(t_ns, NS_PER_S)
    return (
        _RAW
        % (
            seq,
            x,
            y,
            z,
            travel[0],
            travel[1],
            travel[2],
            b[valid[0]],
            b[valid[1]],
            b[valid[2]],
            _jstr(source),
            stylus[0],
            stylus[1],
            stylus[2],
            extra,
            ssec,
            snsec,
        )
    ).encode()


_CORRECTED = (
    '{"seq":%d,"x_mm":%r,"y_mm":%r,"z_mm":%r,"status":%s,"dx_um":%r,"dy_um":%r,"dz_um":%r,'
    '"latency_us":%r,"applied":%d,"source":%s%s,"stamp":{"sec":%d,"nsec":%d}}'
)
_NM_PER_MM = 1_000_000


_U_NULL = ',"ux_um":null,"uy_um":null,"uz_um":null'


def _u_json(u: Any) -> str | None:
    """The U keys of a record's ``u_um`` (None: nulls), or None when not plain finite ≥ 0."""
    if u is None:
        return _U_NULL
    if not (_three_floats(u) and u[0] >= 0.0 and u[1] >= 0.0 and u[2] >= 0.0):
        return None
    return f',"ux_um":{u[0]!r},"uy_um":{u[1]!r},"uz_um":{u[2]!r}'


def corrected_json(rec: tuple[Any, ...], t_ns: int) -> bytes | None:
    """The ``/cmm/corrected`` message of a ``CorrectedRecord``, or None."""
    n = len(rec)
    u_part = "" if n == 10 else _u_json(rec[10]) if n == 11 else None
    if u_part is None:
        return None
    seq, x_nm, y_nm, z_nm, status, corr, latency_us, applied, source, detail = rec[:10]
    if not (
        type(seq) is int
        and 0 <= seq <= _INT_MAX
        and type(x_nm) is int
        and _INT_MIN <= x_nm <= _INT_MAX
        and type(y_nm) is int
        and _INT_MIN <= y_nm <= _INT_MAX
        and type(z_nm) is int
        and _INT_MIN <= z_nm <= _INT_MAX
        and type(status) is str
        and _three_floats(corr)
        and _finite(latency_us)
        and type(applied) is int
        and 0 <= applied <= _INT_MAX
        and type(source) is str
        and type(detail) is str
    ):
        return None
    extra = u_part + (f',"detail":{json.dumps(detail)}' if detail else "")
    ssec, snsec = divmod(t_ns, NS_PER_S)
    return (
        _CORRECTED
        % (
            seq,
            x_nm / _NM_PER_MM,
            y_nm / _NM_PER_MM,
            z_nm / _NM_PER_MM,
            _jstr(status),
            corr[0],
            corr[1],
            corr[2],
            latency_us,
            applied,
            _jstr(source),
            extra,
            ssec,
            snsec,
        )
    ).encode()


FAST_JSON: dict[str, Callable[[tuple[Any, ...], int], bytes | None]] = {
    "/cmm/can_rx": frame_json,
    "/cmm/can_tx": frame_json,
    "/cmm/raw": raw_json,
    "/cmm/corrected": corrected_json,
}
"""Record topic → fast encoder (exactly the general path's bytes, or None: take that path)."""
