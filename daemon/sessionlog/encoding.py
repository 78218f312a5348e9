"""One logged message to JSON bytes every reader accepts, or else an error record in its place.

The log must never stop and never lie: a payload that is not plain, finite JSON (NaN or ±inf,
an integer no 64-bit reader can hold, a non-string key, bytes, an arbitrary object, ``None``
where the schema wants a number, a cycle, absurd nesting) is not written on its topic. The
writer writes an *error record* on :data:`ERROR_TOPIC` instead (built by
:func:`error_payload`, always encodable), counts it, and carries on with the next message.

* Compact record tuples (``records.RECORD_BUILDERS``) are checked field by field by their
  builders (strict types and ranges, no coercion of a wrong type into a plausible value).
* Dict payloads are walked against their topic's JSON Schema by :func:`check_payload`:
  declared keys must have their declared type (numbers finite, integers within
  [−2⁶³, 2⁶⁴ − 1]), every key is a string, undeclared keys may hold any JSON value (same
  rules, ``null`` allowed), nesting at most :data:`MAX_DEPTH` levels.
* The encoder itself rejects NaN/inf (``allow_nan=False``) as a last line.
"""

from __future__ import annotations

import json
import math
from collections.abc import Callable, Mapping
from typing import Any

from .records import expand
from .schemas import TopicSchema, stamp_from_ns

ERROR_TOPIC = "/cmm/log_error"
"""Topic of the error records that replace messages which could not be encoded."""
INT_MIN = -(2**63)
"""Smallest integer written, int64."""
INT_MAX = 2**64 - 1
"""Largest integer written, uint64 (counters); readers that parse doubles lose digits above 2⁵³."""
MAX_DEPTH = 16
"""Deepest nesting of objects/arrays accepted in a payload."""
REPR_CHARS = 1000
"""Longest ``payload`` text kept in an error record, characters."""

ENCODE_ERRORS: tuple[type[Exception], ...] = (
    TypeError,
    ValueError,
    KeyError,
    IndexError,
    OverflowError,
    RecursionError,
    AttributeError,
)
"""What building, checking or encoding a bad payload raises (anything else is a bug, and still
becomes an error record: the writers catch ``Exception``)."""


class NotJson:
    """Stands in for an object that is not plain data (a class instance, a function...) on its
    way to the process writer's child: pickled as its repr, never JSON-encodable there, so the
    message becomes an error record with that repr, as in the thread writer."""

    __slots__ = ("text",)

    def __init__(self, text: str) -> None:
        self.text = text

    def __repr__(self) -> str:
        return self.text


def json_encoder() -> Callable[[Any], str]:
    """The compact JSON encoder of the log (no spaces, ASCII, NaN/Inf rejected)."""
    return json.JSONEncoder(separators=(",", ":"), allow_nan=False).encode


def _bad(where: str, value: Any, what: str) -> ValueError:
    return ValueError(f"{where}: {safe_repr(value, 80)} {what}")


def check_payload(value: Any, schema: Mapping[str, Any] | None, where: str, depth: int = 0) -> None:
    """Raise ValueError/TypeError naming the key path when ``value`` is not acceptable JSON for
    ``schema`` (a JSON Schema subset: type — a name or a list of names —, properties, required,
    additionalProperties, items, enum, minimum, maximum; ``None`` = any JSON value)."""
    if depth > MAX_DEPTH:
        raise ValueError(f"{where}: nested deeper than {MAX_DEPTH} levels")
    kind = None if schema is None else schema.get("type")
    kinds: tuple[str, ...] | None = (
        None if kind is None else (kind,) if isinstance(kind, str) else tuple(kind)
    )  # a list of types, e.g. ["number", "null"]: any of them
    t = type(value)
    if t is float or (t is not bool and isinstance(value, float)):
        if kinds is not None and "number" not in kinds:
            raise _bad(where, value, f"is not of type {kind}")
        if not math.isfinite(value):
            raise _bad(where, value, "is not finite")
    elif t is int or (t is not bool and isinstance(value, int)):
        if kinds is not None and "number" not in kinds and "integer" not in kinds:
            raise _bad(where, value, f"is not of type {kind}")
        if not INT_MIN <= value <= INT_MAX:
            raise ValueError(f"{where}: integer out of the 64-bit range")
    elif t is bool:
        if kinds is not None and "boolean" not in kinds:
            raise _bad(where, value, f"is not of type {kind}")
        return
    elif t is str:
        if kinds is not None and "string" not in kinds:
            raise _bad(where, value, f"is not of type {kind}")
    elif value is None:
        if kinds is not None and "null" not in kinds:
            raise _bad(where, value, f"is not of type {kind}")
        return
    elif t is dict:
        if kinds is not None and "object" not in kinds:
            raise _bad(where, value, f"is not of type {kind}")
        _check_object(value, schema, where, depth)
        return
    elif t is list or t is tuple:
        if kinds is not None and "array" not in kinds:
            raise _bad(where, value, f"is not of type {kind}")
        items = None if schema is None else schema.get("items")
        for i, item in enumerate(value):
            check_payload(item, items, f"{where}[{i}]", depth + 1)
        return
    else:
        raise TypeError(f"{where}: a {t.__name__} is not a JSON value")
    if schema is not None:
        if "enum" in schema and value not in schema["enum"]:
            raise _bad(where, value, f"is not one of {schema['enum']}")
        if "minimum" in schema and value < schema["minimum"]:
            raise _bad(where, value, f"is below the minimum {schema['minimum']}")
        if "maximum" in schema and value > schema["maximum"]:
            raise _bad(where, value, f"is above the maximum {schema['maximum']}")


def _check_object(
    value: dict[Any, Any], schema: Mapping[str, Any] | None, where: str, depth: int
) -> None:
    props: Mapping[str, Any] = {} if schema is None else schema.get("properties", {})
    extra = None if schema is None else schema.get("additionalProperties")
    extra_schema = extra if isinstance(extra, Mapping) else None
    for key, item in value.items():
        if type(key) is not str:
            raise TypeError(f"{where}: key {safe_repr(key, 80)} is not a string")
        check_payload(item, props.get(key, extra_schema), f"{where}.{key}", depth + 1)
    if schema is not None:
        for key in schema.get("required", ()):
            if key not in value and key != "stamp":  # the writer adds stamp
                raise ValueError(f"{where}: required key {key!r} is missing")


def encode_message(
    topic: str,
    payload: dict[str, Any] | tuple[Any, ...],
    t_ns: int,
    dumps: Callable[[Any], str],
    schema: TopicSchema | None = None,
) -> bytes:
    """The JSON bytes of one logged message: a record tuple expanded (and checked) by its
    topic's builder, a dict checked against ``schema`` (when given), ``stamp`` added from
    ``t_ns`` (ns) when absent. Raises one of :data:`ENCODE_ERRORS` when the payload cannot be
    encoded."""
    is_record = type(payload) is tuple
    obj = expand(topic, payload)
    if not is_record and schema is not None:
        check_payload(obj, schema.schema, topic)
    if "stamp" not in obj:
        obj = {**obj, "stamp": stamp_from_ns(t_ns)}
    return dumps(obj).encode()


def safe_repr(obj: Any, limit: int = REPR_CHARS) -> str:
    """``repr(obj)`` cut to ``limit`` characters; never raises (a failing ``__repr__`` gives
    ``<unrepresentable T>``)."""
    try:
        text = repr(obj)
    except Exception:
        text = f"<unrepresentable {type(obj).__name__}>"
    if not isinstance(text, str):  # pragma: no cover - repr() always returns str
        text = f"<unrepresentable {type(obj).__name__}>"
    return text if len(text) <= limit else text[: limit - 1] + "…"


def error_payload(topic: str, payload: Any, t_ns: Any, exc: BaseException) -> dict[str, Any]:
    """The :data:`ERROR_TOPIC` record that replaces a message that could not be encoded:
    ``topic``, ``error`` (exception type and text), ``payload`` (its repr, at most
    :data:`REPR_CHARS` characters) and ``log_time`` (the message's own time). Only str and
    int values: always encodable."""
    try:
        log_time = stamp_from_ns(int(t_ns))
    except Exception:
        log_time = {"sec": 0, "nsec": 0}
    return {
        "topic": str(topic),
        "error": safe_repr_text(f"{type(exc).__name__}: {safe_str(exc)}"),
        "payload": safe_repr(payload),
        "log_time": log_time,
    }


def safe_str(exc: BaseException) -> str:
    """``str(exc)``; never raises."""
    try:
        return str(exc)
    except Exception:
        return f"<unprintable {type(exc).__name__}>"


def safe_repr_text(text: str, limit: int = REPR_CHARS) -> str:
    """``text`` cut to ``limit`` characters."""
    return text if len(text) <= limit else text[: limit - 1] + "…"
