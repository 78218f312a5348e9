"""The session log's topics, each defined once as a ``msgspec`` Struct (docs/formats.md §6).

A topic's Struct is the one definition of its messages: the keys, their types and ranges, which
keys are optional, the order they are written in. From it come

* the JSON Schema of the topic's MCAP channel (``msgspec.json.schema``, made self-contained:
  :data:`TOPIC_SCHEMAS`), what Foxglove and the live view advertise;
* the check of every message before it is written (:mod:`cmm_comp.daemon.sessionlog.encoding`:
  ``msgspec.convert`` against the Struct, a failure becomes an error record) and of a message
  read back (:func:`check_message`);
* the record layouts of the hot path: the CAN endpoint and the engine log compact tuples,
  which :func:`record_fields` turns into the Struct's keys in the writer.

Times are ``{"sec", "nsec"}`` objects (:class:`Time`), never one int64 nanosecond number:
Foxglove, and every JavaScript reader, parse JSON numbers as doubles. The only two time
conversions of the log live here: :func:`stamp_from_ns` (MCAP ``log_time``) and
:func:`ns_from_can_timestamp` (python-can's float seconds). Integers are 64-bit signed; a
non-finite number is never written (:mod:`cmm_comp.daemon.sessionlog.encoding`).
"""

from __future__ import annotations

import json
import math
import numbers
import re
from collections.abc import Callable, Mapping
from dataclasses import dataclass
from types import MappingProxyType
from typing import Annotated, Any, Literal

import msgspec
from msgspec import UNSET, Meta, Struct, UnsetType

from .codes import mm3_from_nm

NS_PER_S = 1_000_000_000
JSON_SCHEMA_DIALECT = "https://json-schema.org/draft/2020-12/schema"
SCHEMA_ENCODING = "jsonschema"
MESSAGE_ENCODING = "json"
INT_MIN, INT_MAX = -(2**63), 2**63 - 1
"""The integers a message may hold (int64)."""

FRAME_DIRECTIONS = ("rx", "tx", "tx_echo")
"""A logged CAN frame's ``direction``: ``rx`` received, sent by another node (the
controller); ``tx`` sent by the daemon (``/cmm/can_tx``); ``tx_echo`` received, but on an id
the daemon itself transmits: its own frame returned by the bus (``udp_multicast`` does that)."""


def stamp_from_ns(log_time_ns: int) -> dict[str, int]:
    """Return ``{"sec": s, "nsec": n}`` for integer nanoseconds since the Unix epoch.

    ``nsec`` is always in ``[0, 1e9)``; ``sec`` is floored, so negative times stay exact.
    """
    sec, nsec = divmod(int(log_time_ns), NS_PER_S)
    return {"sec": sec, "nsec": nsec}


def ns_from_stamp(stamp: Mapping[str, int]) -> int:
    """Return integer nanoseconds for a ``{"sec", "nsec"}`` stamp (the inverse of stamp_from_ns)."""
    return int(stamp["sec"]) * NS_PER_S + int(stamp["nsec"])


def ns_from_can_timestamp(timestamp_s: float) -> int:
    """Return integer nanoseconds for python-can's ``Message.timestamp`` (float seconds).

    The integer part is converted exactly; only the fraction goes through a float product, so
    the result is within one float ulp of the input (about 0.24 µs near the year 2024).
    """
    if not math.isfinite(timestamp_s):
        raise ValueError(f"CAN timestamp {timestamp_s!r} s is not finite; expected float seconds")
    sec = math.floor(timestamp_s)
    return int(sec) * NS_PER_S + round((timestamp_s - sec) * NS_PER_S)


# --------------------------------------------------------------------------- field types

Int = Annotated[int, Meta(ge=INT_MIN, le=INT_MAX)]
UInt = Annotated[int, Meta(ge=0, le=INT_MAX)]
Opt = UnsetType
"""``X | Opt = UNSET``: an optional key, left out of the message when not given."""


def D(text: str) -> Meta:
    """A key's description (the schema's)."""
    return Meta(description=text)


class Time(Struct):
    """Unix time: seconds and nanoseconds in [0, 1e9)."""

    sec: Int
    nsec: Annotated[int, Meta(ge=0, le=NS_PER_S - 1)]


Stamp = Annotated[Time, D("Time the daemon logged the message (MCAP log_time).")]
_U = Annotated[float, Meta(ge=0)] | None | Opt
_U_TEXT = (
    "Expanded uncertainty U of the corrected {}, coverage factor k = 2 (per component), µm; "
    "null when unknown (status not ok). Present on every answer made with a grid that carries "
    "U (docs/uncertainty.md); absent otherwise."
)
_TRANSPORT = D("Transport: can or modbus.")


class _Topic(Struct, kw_only=True, omit_defaults=True, forbid_unknown_fields=True):
    """Every topic: keyword fields, optional ones (``UNSET``) left out, no undeclared key."""


class RawReading(_Topic, kw_only=True):
    """A complete raw (indicated) reading received from the CMM controller."""

    seq: Annotated[UInt, D("Controller sequence number of the reading.")]
    x_mm: Annotated[float, D("Indicated X position, mm.")]
    y_mm: Annotated[float, D("Indicated Y position, mm.")]
    z_mm: Annotated[float, D("Indicated Z position, mm.")]
    travel_dir: Annotated[
        list[Annotated[int, Meta(ge=-1, le=1)]] | Opt, D("Travel direction X, Y, Z: -1, 0, 1.")
    ] = UNSET
    valid: Annotated[list[bool] | Opt, D("Axis values valid X, Y, Z.")] = UNSET
    source: Annotated[str | Opt, _TRANSPORT] = UNSET
    stylus_x_mm: Annotated[float | Opt, D("Stylus offset X, mm (optional).")] = UNSET
    stylus_y_mm: Annotated[float | Opt, D("Stylus offset Y, mm (optional).")] = UNSET
    stylus_z_mm: Annotated[float | Opt, D("Stylus offset Z, mm (optional).")] = UNSET
    dir_x: Annotated[float | Opt, D("Probing direction, unit vector X (optional).")] = UNSET
    dir_y: Annotated[float | Opt, D("Probing direction, unit vector Y (optional).")] = UNSET
    dir_z: Annotated[float | Opt, D("Probing direction, unit vector Z (optional).")] = UNSET
    probe: Annotated[str | Opt, D("Probe/stylus identifier (optional).")] = UNSET
    stamp: Stamp


class Temperature(_Topic, kw_only=True):
    """One temperature sample."""

    sensor: Annotated[str, D("Sensor identifier.")]
    role: Annotated[str, D("Model input it feeds: T_x, T_y, T_z, T_wp, T_top, T_bottom, T_air.")]
    temp_C: Annotated[float, D("Temperature, °C.")]
    counter: Annotated[UInt | Opt, D("The sensor's sample counter.")] = UNSET
    valid: Annotated[bool | Opt, D("The sensor's own validity flag.")] = UNSET
    fault: Annotated[str | Opt, D("Why the sample is not used; empty when it is.")] = UNSET
    source: Annotated[str | Opt, _TRANSPORT] = UNSET
    stamp: Stamp


class Corrected(_Topic, kw_only=True):
    """The corrected answer sent back to the controller (corrected = indicated + error)."""

    seq: Annotated[UInt, D("Sequence number of the raw reading it answers.")]
    x_mm: Annotated[float, D("Corrected X, mm.")]
    y_mm: Annotated[float, D("Corrected Y, mm.")]
    z_mm: Annotated[float, D("Corrected Z, mm.")]
    status: Annotated[str, D('"ok" or the reason it could not correct.')]
    dx_um: Annotated[float | Opt, D("Applied correction X, µm.")] = UNSET
    dy_um: Annotated[float | Opt, D("Applied correction Y, µm.")] = UNSET
    dz_um: Annotated[float | Opt, D("Applied correction Z, µm.")] = UNSET
    latency_us: Annotated[float | Opt, D("Raw reading received to answer sent, µs.")] = UNSET
    applied: Annotated[
        UInt | Opt,
        D(
            "Applied bit mask: 1 geometry, 2 scale thermal, 4 workpiece thermal, 8 reversal, "
            "16 probe direction, 32 U known."
        ),
    ] = UNSET
    source: Annotated[str | Opt, _TRANSPORT] = UNSET
    ux_um: Annotated[_U, D(_U_TEXT.format("X"))] = UNSET
    uy_um: Annotated[_U, D(_U_TEXT.format("Y"))] = UNSET
    uz_um: Annotated[_U, D(_U_TEXT.format("Z"))] = UNSET
    detail: Annotated[str | Opt, D("Why the correction is warned about (status ok).")] = UNSET
    stamp: Stamp


class Status(_Topic, kw_only=True):
    """A daemon status change."""

    state: Annotated[str, D("Daemon state, e.g. starting, running, degraded, stopped.")]
    detail: Annotated[str, D("Human-readable reason.")]
    grid_sha256: Annotated[str, D("SHA-256 (hex) of the loaded grid, empty if none.")]
    stamp: Stamp


class CanFrame(_Topic, kw_only=True):
    """One raw CAN frame as seen on the bus."""

    arbitration_id: Annotated[int, Meta(ge=0, le=2**29 - 1), D("CAN identifier (11 or 29 bit).")]
    is_extended: Annotated[bool, D("29-bit identifier.")]
    dlc: Annotated[int, Meta(ge=0, le=64), D("Data length.")]
    data: Annotated[str, D("Payload bytes as lowercase hex, two digits a byte, no separators.")]
    bus_stamp: Annotated[Time, D("Bus/driver timestamp (python-can timestamp; 0: unknown).")]
    channel: Annotated[str | Opt, D("Bus channel name.")] = UNSET
    is_fd: bool | Opt = UNSET
    is_remote_frame: bool | Opt = UNSET
    is_error_frame: bool | Opt = UNSET
    direction: Annotated[
        Literal["rx", "tx", "tx_echo"] | Opt,
        D(
            "rx: received, sent by another node (the controller); tx: sent by the daemon; "
            "tx_echo: received, but on an id the daemon transmits (its own frame returned by "
            "the bus, as udp_multicast does). Absent in logs written before it."
        ),
    ] = UNSET
    stamp: Stamp


class ModbusAccess(_Topic, kw_only=True):
    """One Modbus register read or write, as server or client."""

    op: Literal["read", "write"]
    function_code: UInt | Opt = UNSET
    device_id: UInt | Opt = UNSET
    address: Annotated[UInt, D("First register, 0-based.")]
    count: Annotated[UInt, D("Number of registers.")]
    values: list[Annotated[int, Meta(ge=0, le=65535)]]
    ok: bool | Opt = UNSET
    error: Annotated[str | Opt, D("Exception/error text when ok is false.")] = UNSET
    stamp: Stamp


class Grid(_Topic, kw_only=True):
    """Identity of the correction grid in use."""

    sha256: Annotated[str, D("SHA-256 (hex) of the grid file.")]
    machine: Annotated[str, D("Machine name.")]
    model: Annotated[str, D("Machine model.")]
    steps: Annotated[list[UInt], D("Grid steps (x, y, z).")]
    path: Annotated[str, D("Grid file path.")]
    loaded_at: Annotated[Time, D("Time the grid was loaded.")]
    signals: Annotated[list[str] | Opt, D("Runtime signals the grid needs (optional).")] = UNSET
    uncertainty: Annotated[
        bool | Opt, D("The grid carries U: answers carry ux_um/uy_um/uz_um (optional).")
    ] = UNSET
    stamp: Stamp


class Counters(_Topic, kw_only=True):
    """Periodic counters since start and the latency histogram of the last period."""

    period_s: Annotated[float | Opt, D("Period the histogram covers, s.")] = UNSET
    counters: Annotated[
        dict[str, UInt], D("Monotonic counters since start, e.g. frames_rx, mcap_dropped.")
    ]
    latency_edges_us: Annotated[
        list[float] | Opt, D("Histogram bin edges, µs (len = bins + 1).")
    ] = UNSET
    latency_counts: Annotated[list[UInt] | Opt, D("Histogram counts per bin.")] = UNSET
    latency_over_top: Annotated[UInt | Opt, D("Latencies above the top edge.")] = UNSET
    latency_p50_us: float | Opt = UNSET
    latency_p99_us: float | Opt = UNSET
    latency_max_us: Annotated[float | Opt, D("Largest latency of the period, µs.")] = UNSET
    stamp: Stamp


class LogError(_Topic, kw_only=True):
    """A message that could not be encoded (NaN/inf, a value out of the 64-bit range, a wrong
    type...): written here instead of on its topic, and counted."""

    topic: Annotated[str, D("Topic the message was logged on.")]
    error: Annotated[str, D("Why it could not be encoded.")]
    payload: Annotated[str, D("repr() of the payload, at most 1000 characters.")]
    log_time: Annotated[Time, D("The message's own log time.")]
    stamp: Stamp


TOPIC_TYPES: Mapping[str, type[_Topic]] = MappingProxyType(
    {
        "/cmm/raw": RawReading,
        "/cmm/temperature": Temperature,
        "/cmm/corrected": Corrected,
        "/cmm/status": Status,
        "/cmm/can_rx": CanFrame,
        "/cmm/can_tx": CanFrame,
        "/cmm/modbus": ModbusAccess,
        "/cmm/grid": Grid,
        "/cmm/counters": Counters,
        "/cmm/log_error": LogError,
    }
)
"""Every logged topic to its Struct."""


# --------------------------------------------------------------------------- JSON Schemas


def _inline(node: Any, defs: Mapping[str, Any]) -> Any:
    """``node`` with every ``{"$ref": "#/$defs/X", ...}`` replaced by ``X`` (its own keys win)."""
    if isinstance(node, list):
        return [_inline(v, defs) for v in node]
    if not isinstance(node, dict):
        return node
    out = {k: _inline(v, defs) for k, v in node.items() if k != "$ref"}
    if "$ref" in node:
        out = {**_inline(defs[node["$ref"].rsplit("/", 1)[1]], defs), **out}
    return out


def json_schema(cls: type[Struct], name: str) -> dict[str, Any]:
    """The self-contained JSON Schema (draft 2020-12) of ``cls``, titled ``name``."""
    raw = msgspec.json.schema(cls)
    body = _inline(raw, raw.get("$defs", {}))
    body.pop("$defs", None)
    return {"$schema": JSON_SCHEMA_DIALECT, **body, "title": name}


@dataclass(frozen=True)
class TopicSchema:
    """One topic's schema: ``name`` is the MCAP schema name, ``schema`` the JSON Schema dict."""

    topic: str
    name: str
    schema: Mapping[str, Any]

    def as_bytes(self) -> bytes:
        """Return the schema as UTF-8 JSON, the MCAP Schema record's data."""
        return json.dumps(self.schema, separators=(",", ":"), sort_keys=True).encode()


TOPIC_SCHEMAS: Mapping[str, TopicSchema] = MappingProxyType(
    {
        topic: TopicSchema(
            topic, f"cmm_comp.{cls.__name__}", json_schema(cls, f"cmm_comp.{cls.__name__}")
        )
        for topic, cls in TOPIC_TYPES.items()
    }
)
"""Every logged topic to its schema (read-only)."""


# --------------------------------------------------------------------------- record layouts


def _num(value: Any, what: str = "number") -> Any:
    """A number of a message as a Python number (numpy ones too); anything else as it is, for
    the Struct's check to refuse (never the number of a bool, a string...). An integer beyond
    64 bits is refused here (a float key would take it)."""
    if type(value) is float or isinstance(value, bool):
        return value
    if type(value) is int or isinstance(value, numbers.Integral):
        n = int(value)
        if not INT_MIN <= n <= INT_MAX:
            raise ValueError(f"{what}: integer {n:.3g} out of the 64-bit range")
        return n
    return float(value) if isinstance(value, numbers.Real) else value


def _three(value: Any, what: str) -> tuple[Any, Any, Any] | list[Any]:
    """``value`` if a tuple or list of three items (x, y, z)."""
    if type(value) in (tuple, list) and len(value) == 3:
        return value  # type: ignore[no-any-return]
    raise TypeError(f"{what}: {type(value).__name__} {value!r:.40} is not three values (x, y, z)")


def frame_fields(rec: tuple[Any, ...]) -> dict[str, Any]:
    """A CAN frame record ``(arbitration_id, is_extended, dlc, data, timestamp_s, channel,
    is_fd, is_remote, is_error, direction)`` as :class:`CanFrame` keys: ``data`` bytes → hex,
    ``timestamp_s`` (python-can's float s; 0, None or NaN: unknown) → ``bus_stamp``. The CAN
    endpoint builds it (``can_endpoint.frame_record``); a 9-field record (without direction,
    the layout before it) writes no ``direction`` key."""
    if len(rec) not in (9, 10):
        raise ValueError(f"a CAN frame record has 9 or 10 fields, not {len(rec)}")
    can_id, ext, dlc, data, ts, channel, fd, remote, error = rec[:9]
    if not isinstance(data, bytes | bytearray | memoryview):
        raise TypeError(f"data: {type(data).__name__} is not bytes")
    ts = _num(ts)
    if type(ts) is not float and type(ts) is not int and ts is not None:
        raise TypeError(f"timestamp_s: {type(ts).__name__} {ts!r:.40} is not a number")
    out = {
        "arbitration_id": can_id,
        "is_extended": ext,
        "dlc": dlc,
        "data": bytes(data).hex(),
        "bus_stamp": stamp_from_ns(ns_from_can_timestamp(ts) if ts and ts == ts else 0),
        "channel": str(_num(channel, "channel")) if type(channel) is int else channel,
        "is_fd": fd,
        "is_remote_frame": remote,
        "is_error_frame": error,
    }
    if len(rec) == 10:
        out["direction"] = rec[9]
    return out


def raw_fields(rec: tuple[Any, ...]) -> dict[str, Any]:
    """A ``/cmm/raw`` record ``(seq, x_mm, y_mm, z_mm, travel_dir, valid, source, stylus_mm,
    probe_dir or None)`` as :class:`RawReading` keys (the engine builds it)."""
    seq, x, y, z, travel, valid, source, stylus_mm, probe = rec
    stylus = _three(stylus_mm, "stylus_mm")
    out: dict[str, Any] = {
        "seq": seq,
        "x_mm": _num(x, "x_mm"),
        "y_mm": _num(y, "y_mm"),
        "z_mm": _num(z, "z_mm"),
        "travel_dir": [_num(v, "travel_dir") for v in _three(travel, "travel_dir")],
        "valid": [bool(v) if hasattr(v, "dtype") else v for v in _three(valid, "valid")],
        "source": source,
        "stylus_x_mm": _num(stylus[0]),
        "stylus_y_mm": _num(stylus[1]),
        "stylus_z_mm": _num(stylus[2]),
    }
    if probe is not None:
        dirs = _three(probe, "probe direction")
        out["dir_x"], out["dir_y"], out["dir_z"] = (_num(v) for v in dirs)
    return out


def corrected_fields(rec: tuple[Any, ...]) -> dict[str, Any]:
    """A ``/cmm/corrected`` record ``(seq, x_nm, y_nm, z_nm, status, correction_um,
    latency_us, applied, source, detail)``, optionally followed by ``u_um`` — ``(Ux, Uy, Uz)``
    µm, or None (unknown: nulls); a 10-field record writes no U keys — as :class:`Corrected`
    keys (positions nm → mm; the engine builds it)."""
    if len(rec) not in (10, 11):
        raise ValueError(f"a /cmm/corrected record has 10 or 11 fields, not {len(rec)}")
    seq, x_nm, y_nm, z_nm, status, corr_um, latency_us, applied, source, detail = rec[:10]
    for name, v in (("x_nm", x_nm), ("y_nm", y_nm), ("z_nm", z_nm)):
        if isinstance(v, bool) or not isinstance(v, numbers.Integral):
            raise TypeError(f"{name}: {type(v).__name__} {v!r:.40} is not an integer")
    x_mm, y_mm, z_mm = mm3_from_nm((_num(x_nm, "x_nm"), _num(y_nm, "y_nm"), _num(z_nm, "z_nm")))
    dx, dy, dz = _three(corr_um, "correction_um")
    out: dict[str, Any] = {
        "seq": seq,
        "x_mm": x_mm,
        "y_mm": y_mm,
        "z_mm": z_mm,
        "status": status,
        "dx_um": _num(dx),
        "dy_um": _num(dy),
        "dz_um": _num(dz),
        "latency_us": _num(latency_us, "latency_us"),
        "applied": applied,
        "source": source,
    }
    if len(rec) == 11:
        u = rec[10]
        ux, uy, uz = (None, None, None) if u is None else _three(u, "u_um")
        out["ux_um"], out["uy_um"], out["uz_um"] = _num(ux), _num(uy), _num(uz)
    if detail or type(detail) is not str:
        out["detail"] = detail
    return out


RECORD_FIELDS: Mapping[str, Callable[[tuple[Any, ...]], dict[str, Any]]] = MappingProxyType(
    {
        "/cmm/can_rx": frame_fields,
        "/cmm/can_tx": frame_fields,
        "/cmm/raw": raw_fields,
        "/cmm/corrected": corrected_fields,
    }
)
"""Topics that take a compact record tuple, and the function giving its keys."""


# --------------------------------------------------------------------------- checking

_PATH = re.compile(r"\$((?:\.\w+|\[\d+\])*)")


def problem(topic: str, exc: msgspec.ValidationError, payload: Any) -> str:
    """``msgspec``'s complaint as ``<topic><key path>: <value> <what is wrong>``."""
    text = str(exc)
    text, _, at = text.partition(" - at `")
    m = _PATH.match(at.rstrip("`"))
    path = m.group(1) if m else ""
    value: Any = payload
    for part in re.findall(r"\.(\w+)|\[(\d+)\]", path):
        try:
            value = value[part[0]] if part[0] else value[int(part[1])]
        except (KeyError, IndexError, TypeError):
            break
    if text.startswith("Object missing required field"):
        return f"{topic}{path}: required key {text.split('`')[1]!r} is missing"
    bound = re.match(r"Expected `\w+` ([<>]=?) (\S+)", text)
    if bound:
        what = "above the maximum" if bound.group(1).startswith("<") else "below the minimum"
        return f"{topic}{path}: {value!r:.80} is {what} {bound.group(2)}"
    kind = re.match(r"Expected `(\w+)`, got `(\w+)`", text)
    if kind and kind[2] == "null" and isinstance(value, float):
        return f"{topic}{path}: {value!r} is not finite"
    if kind:
        name = {"int": "integer", "float": "number", "str": "string", "bool": "boolean"}
        return f"{topic}{path}: {value!r:.80} is not of type {name.get(kind[1], kind[1])}"
    return f"{topic}{path}: {text}"


def check_message(topic: str, payload: Any) -> Any:
    """Validate ``payload`` (a decoded message, ``stamp`` included) against the Struct of
    ``topic`` and return it.

    Raises ValueError naming the topic, the key path and the problem. Keys the Struct does
    not declare are allowed here (a reader takes the logs of later versions; docs/formats.md:
    optional keys may be added).
    """
    cls = TOPIC_TYPES.get(topic)
    if cls is None:
        raise ValueError(f"unknown topic {topic!r}; known: {sorted(TOPIC_TYPES)}")
    if not isinstance(payload, dict):
        raise ValueError(f"{topic}: {type(payload).__name__} is not a JSON object")
    known = {k: v for k, v in payload.items() if k in cls.__struct_fields__}
    try:
        msgspec.convert(known, cls)
    except msgspec.ValidationError as exc:
        raise ValueError(problem(topic, exc, payload)) from None
    return payload
