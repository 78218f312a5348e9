"""JSON Schemas of the MCAP session log (docs/formats.md §6) and the two time conversions.

Every topic is one JSON object per message, ``jsonschema`` schema encoding, draft 2020-12.
Times are ``{"sec": int, "nsec": int}`` objects: never one int64 nanosecond number, because
Foxglove (and every JavaScript reader) parses JSON numbers as doubles (53-bit mantissa).

The only two time conversions of the project's log live here:

* :func:`stamp_from_ns` - integer nanoseconds (MCAP ``log_time``) to ``{sec, nsec}``;
* :func:`ns_from_can_timestamp` - python-can's float seconds (``Message.timestamp``) to ns.

:func:`check_message` is a small validator for the subset of JSON Schema used here (type, also
as a list such as ``["number", "null"]``, required, properties, items, enum, minimum, maximum,
additionalProperties); it lets tests and
replay tools check payloads without the ``jsonschema`` package.
"""

from __future__ import annotations

import json
import math
from collections.abc import Mapping
from dataclasses import dataclass
from types import MappingProxyType
from typing import Any

NS_PER_S = 1_000_000_000
JSON_SCHEMA_DIALECT = "https://json-schema.org/draft/2020-12/schema"
SCHEMA_ENCODING = "jsonschema"
MESSAGE_ENCODING = "json"


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


# --------------------------------------------------------------------------- schema pieces

_TIME: dict[str, Any] = {
    "type": "object",
    "title": "time",
    "description": "Unix time: seconds and nanoseconds in [0, 1e9).",
    "properties": {
        "sec": {"type": "integer"},
        "nsec": {"type": "integer", "minimum": 0, "maximum": NS_PER_S - 1},
    },
    "required": ["sec", "nsec"],
}
_STAMP = {**_TIME, "description": "Time the daemon logged the message (MCAP log_time)."}
_NUM = {"type": "number"}
_INT = {"type": "integer"}
_UINT = {"type": "integer", "minimum": 0}
_STR = {"type": "string"}
_BOOL = {"type": "boolean"}
_U = {
    "type": ["number", "null"],
    "minimum": 0,
}
_U_TEXT = (
    "Expanded uncertainty U of the corrected {axis}, coverage factor k = 2 (per component), "
    "µm; null when unknown (status not ok). Present on every answer made with a grid that "
    "carries U (docs/uncertainty.md); absent otherwise."
)


def _obj(title: str, description: str, props: dict[str, Any], required: list[str]) -> dict:
    return {
        "$schema": JSON_SCHEMA_DIALECT,
        "title": title,
        "description": description,
        "type": "object",
        "properties": props,
        "required": required,
    }


def _d(base: Mapping[str, Any], description: str) -> dict[str, Any]:
    return {**base, "description": description}


FRAME_DIRECTIONS = ("rx", "tx", "tx_echo")
"""A logged CAN frame's ``direction``: ``rx`` received, sent by another node (the
controller); ``tx`` sent by the daemon (``/cmm/can_tx``); ``tx_echo`` received, but on an id
the daemon itself transmits: its own frame returned by the bus (``udp_multicast`` does that)."""


_CAN_FRAME = _obj(
    "cmm_comp.CanFrame",
    "One raw CAN frame as seen on the bus.",
    {
        "arbitration_id": _d(_UINT, "CAN identifier (11 or 29 bit)."),
        "is_extended": _d(_BOOL, "29-bit identifier."),
        "dlc": {"type": "integer", "minimum": 0, "maximum": 64, "description": "Data length."},
        "data": _d(_STR, "Payload bytes as lowercase hex, two digits a byte, no separators."),
        "bus_stamp": {**_TIME, "description": "Bus/driver timestamp (python-can timestamp)."},
        "channel": _d(_STR, "Bus channel name."),
        "is_fd": _BOOL,
        "is_remote_frame": _BOOL,
        "is_error_frame": _BOOL,
        "direction": {
            "type": "string",
            "enum": list(FRAME_DIRECTIONS),
            "description": "rx: received, sent by another node (the controller); tx: sent by "
            "the daemon; tx_echo: received, but on an id the daemon transmits (its own frame "
            "returned by the bus, as udp_multicast does). Absent in logs written before it.",
        },
        "stamp": _STAMP,
    },
    ["arbitration_id", "is_extended", "dlc", "data", "bus_stamp", "stamp"],
)


@dataclass(frozen=True)
class TopicSchema:
    """One topic's schema: ``name`` is the MCAP schema name, ``schema`` the JSON Schema dict."""

    topic: str
    name: str
    schema: Mapping[str, Any]

    def as_bytes(self) -> bytes:
        """Return the schema as UTF-8 JSON, the MCAP Schema record's data."""
        return json.dumps(self.schema, separators=(",", ":"), sort_keys=True).encode()


_SCHEMAS: tuple[TopicSchema, ...] = (
    TopicSchema(
        "/cmm/raw",
        "cmm_comp.RawReading",
        _obj(
            "cmm_comp.RawReading",
            "A complete raw (indicated) reading received from the CMM controller.",
            {
                "seq": _d(_UINT, "Controller sequence number of the reading."),
                "x_mm": _d(_NUM, "Indicated X position, mm."),
                "y_mm": _d(_NUM, "Indicated Y position, mm."),
                "z_mm": _d(_NUM, "Indicated Z position, mm."),
                "dir_x": _d(_NUM, "Probing direction, unit vector X (optional)."),
                "dir_y": _d(_NUM, "Probing direction, unit vector Y (optional)."),
                "dir_z": _d(_NUM, "Probing direction, unit vector Z (optional)."),
                "probe": _d(_STR, "Probe/stylus identifier (optional)."),
                "stylus_x_mm": _d(_NUM, "Stylus offset X, mm (optional)."),
                "stylus_y_mm": _d(_NUM, "Stylus offset Y, mm (optional)."),
                "stylus_z_mm": _d(_NUM, "Stylus offset Z, mm (optional)."),
                "stamp": _STAMP,
            },
            ["seq", "x_mm", "y_mm", "z_mm", "stamp"],
        ),
    ),
    TopicSchema(
        "/cmm/temperature",
        "cmm_comp.Temperature",
        _obj(
            "cmm_comp.Temperature",
            "One temperature sample.",
            {
                "sensor": _d(_STR, "Sensor identifier."),
                "role": _d(
                    _STR, "Model input it feeds: T_x, T_y, T_z, T_wp, T_top, T_bottom, T_air."
                ),
                "temp_C": _d(_NUM, "Temperature, °C."),
                "stamp": _STAMP,
            },
            ["sensor", "role", "temp_C", "stamp"],
        ),
    ),
    TopicSchema(
        "/cmm/corrected",
        "cmm_comp.Corrected",
        _obj(
            "cmm_comp.Corrected",
            "The corrected answer sent back to the controller (corrected = indicated + error).",
            {
                "seq": _d(_UINT, "Sequence number of the raw reading it answers."),
                "x_mm": _d(_NUM, "Corrected X, mm."),
                "y_mm": _d(_NUM, "Corrected Y, mm."),
                "z_mm": _d(_NUM, "Corrected Z, mm."),
                "status": _d(_STR, '"ok" or the reason it could not correct.'),
                "dx_um": _d(_NUM, "Applied correction X, µm."),
                "dy_um": _d(_NUM, "Applied correction Y, µm."),
                "dz_um": _d(_NUM, "Applied correction Z, µm."),
                "latency_us": _d(_NUM, "Raw reading received to answer sent, µs."),
                "applied": _d(
                    _UINT,
                    "Applied bit mask: 1 geometry, 2 scale thermal, 4 workpiece thermal, "
                    "8 reversal, 16 probe direction, 32 U known.",
                ),
                "ux_um": _d(_U, _U_TEXT.format(axis="X")),
                "uy_um": _d(_U, _U_TEXT.format(axis="Y")),
                "uz_um": _d(_U, _U_TEXT.format(axis="Z")),
                "stamp": _STAMP,
            },
            ["seq", "x_mm", "y_mm", "z_mm", "status", "stamp"],
        ),
    ),
    TopicSchema(
        "/cmm/status",
        "cmm_comp.Status",
        _obj(
            "cmm_comp.Status",
            "A daemon status change.",
            {
                "state": _d(_STR, "Daemon state, e.g. starting, running, degraded, stopped."),
                "detail": _d(_STR, "Human-readable reason."),
                "grid_sha256": _d(_STR, "SHA-256 (hex) of the loaded grid, empty if none."),
                "stamp": _STAMP,
            },
            ["state", "detail", "grid_sha256", "stamp"],
        ),
    ),
    TopicSchema("/cmm/can_rx", "cmm_comp.CanFrame", _CAN_FRAME),
    TopicSchema("/cmm/can_tx", "cmm_comp.CanFrame", _CAN_FRAME),
    TopicSchema(
        "/cmm/modbus",
        "cmm_comp.ModbusAccess",
        _obj(
            "cmm_comp.ModbusAccess",
            "One Modbus register read or write, as server or client.",
            {
                "op": {"type": "string", "enum": ["read", "write"]},
                "function_code": _UINT,
                "device_id": _UINT,
                "address": _d(_UINT, "First register, 0-based."),
                "count": _d(_UINT, "Number of registers."),
                "values": {
                    "type": "array",
                    "items": {"type": "integer", "minimum": 0, "maximum": 65535},
                },
                "ok": _BOOL,
                "error": _d(_STR, "Exception/error text when ok is false."),
                "stamp": _STAMP,
            },
            ["op", "address", "count", "values", "stamp"],
        ),
    ),
    TopicSchema(
        "/cmm/grid",
        "cmm_comp.Grid",
        _obj(
            "cmm_comp.Grid",
            "Identity of the correction grid in use.",
            {
                "sha256": _d(_STR, "SHA-256 (hex) of the grid file."),
                "machine": _d(_STR, "Machine name."),
                "model": _d(_STR, "Machine model."),
                "steps": {"type": "array", "items": _UINT, "description": "Grid steps (x, y, z)."},
                "path": _d(_STR, "Grid file path."),
                "loaded_at": {**_TIME, "description": "Time the grid was loaded."},
                "uncertainty": _d(
                    _BOOL, "The grid carries U: answers carry ux_um/uy_um/uz_um (optional)."
                ),
                "stamp": _STAMP,
            },
            ["sha256", "machine", "model", "steps", "path", "loaded_at", "stamp"],
        ),
    ),
    TopicSchema(
        "/cmm/counters",
        "cmm_comp.Counters",
        _obj(
            "cmm_comp.Counters",
            "Periodic counters since start and the latency histogram of the last period.",
            {
                "period_s": _d(_NUM, "Period the histogram covers, s."),
                "counters": {
                    "type": "object",
                    "additionalProperties": _UINT,
                    "description": "Monotonic counters since start, e.g. frames_rx, mcap_dropped.",
                },
                "latency_edges_us": {
                    "type": "array",
                    "items": _NUM,
                    "description": "Histogram bin edges, µs (len = bins + 1).",
                },
                "latency_counts": {
                    "type": "array",
                    "items": _UINT,
                    "description": "Histogram counts per bin.",
                },
                "latency_p50_us": _NUM,
                "latency_p99_us": _NUM,
                "stamp": _STAMP,
            },
            ["counters", "stamp"],
        ),
    ),
    TopicSchema(
        "/cmm/log_error",
        "cmm_comp.LogError",
        _obj(
            "cmm_comp.LogError",
            "A message that could not be encoded (NaN/inf, a value out of the 64-bit range, a "
            "wrong type...): written here instead of on its topic, and counted.",
            {
                "topic": _d(_STR, "Topic the message was logged on."),
                "error": _d(_STR, "Why it could not be encoded."),
                "payload": _d(_STR, "repr() of the payload, at most 1000 characters."),
                "log_time": {**_TIME, "description": "The message's own log time."},
                "stamp": _STAMP,
            },
            ["topic", "error", "payload", "log_time", "stamp"],
        ),
    ),
)

TOPIC_SCHEMAS: Mapping[str, TopicSchema] = MappingProxyType({s.topic: s for s in _SCHEMAS})
"""Every logged topic to its schema (read-only)."""


# --------------------------------------------------------------------------- validation

_TYPES: dict[str, tuple[type, ...]] = {
    "object": (dict,),
    "array": (list, tuple),
    "string": (str,),
    "boolean": (bool,),
    "integer": (int,),
    "number": (int, float),
}


def _is_type(value: Any, kind: str) -> bool:
    if kind == "null":
        return value is None
    if kind in ("integer", "number") and isinstance(value, bool):
        return False
    return isinstance(value, _TYPES[kind])


def _check(value: Any, schema: Mapping[str, Any], where: str) -> None:
    kind = schema.get("type")
    if kind is not None:
        kinds = (kind,) if isinstance(kind, str) else tuple(kind)
        if not any(_is_type(value, k) for k in kinds):
            raise ValueError(f"{where}: {value!r} is not of type {kind}")
    if value is None:
        return
    if "enum" in schema and value not in schema["enum"]:
        raise ValueError(f"{where}: {value!r} is not one of {schema['enum']}")
    if "minimum" in schema and value < schema["minimum"]:
        raise ValueError(f"{where}: {value!r} is below the minimum {schema['minimum']}")
    if "maximum" in schema and value > schema["maximum"]:
        raise ValueError(f"{where}: {value!r} is above the maximum {schema['maximum']}")
    if isinstance(value, dict):
        for key in schema.get("required", ()):
            if key not in value:
                raise ValueError(f"{where}: required key {key!r} is missing")
        props = schema.get("properties", {})
        extra = schema.get("additionalProperties")
        for key, item in value.items():
            if key in props:
                _check(item, props[key], f"{where}.{key}")
            elif isinstance(extra, Mapping):
                _check(item, extra, f"{where}.{key}")
    if isinstance(value, list | tuple) and "items" in schema:
        for i, item in enumerate(value):
            _check(item, schema["items"], f"{where}[{i}]")


def check_message(topic: str, payload: Any) -> Any:
    """Validate ``payload`` against the schema of ``topic`` and return it.

    Raises ValueError naming the topic, the key path and the problem. Unknown keys are allowed
    (docs/formats.md: optional keys may be added freely).
    """
    if topic not in TOPIC_SCHEMAS:
        raise ValueError(f"unknown topic {topic!r}; known: {sorted(TOPIC_SCHEMAS)}")
    _check(payload, TOPIC_SCHEMAS[topic].schema, topic)
    return payload
