"""One logged message to the JSON bytes of its topic's Struct, or else an error record.

One path for every topic and both consumers (the MCAP writer and the live view): the payload
— a compact record tuple (``session_topics.RECORD_FIELDS``) or a dict of the topic's keys — gets its
``stamp`` from the log time when it has none, is converted to the topic's Struct
(``msgspec.convert``: every declared key of its declared type and range, strict — no bool for
an int, no bytes for a string, no numpy scalar, no undeclared key) and encoded by ``msgspec``.

A number that is not finite has no JSON form. The session log must never hold a number no
reader parses nor a plausible wrong one: :func:`encode_message` refuses the message, and the
writer writes an *error record* on :data:`ERROR_TOPIC` in its place (:func:`error_payload`,
always encodable), counts it and carries on. The live view is for looking at: it sends such a
message with the number as ``null`` (:func:`struct_json`), and counts it.
"""

from __future__ import annotations

import io
import math
import numbers
import pickle
from typing import Any

import msgspec

from cmm_comp.protocol.session_topics import (
    INT_MAX,
    INT_MIN,
    RECORD_FIELDS,
    TOPIC_TYPES,
    problem,
    stamp_from_ns,
)

ERROR_TOPIC = "/cmm/log_error"
"""Topic of the error records that replace messages which could not be encoded."""
REPR_CHARS = 1000
"""Longest ``payload`` text kept in an error record, characters."""

_ENCODER = msgspec.json.Encoder()
_DECODERS = {topic: msgspec.json.Decoder(cls) for topic, cls in TOPIC_TYPES.items()}


class NotJson:
    """Stands in for an object that is not plain data (a class instance, a function...) on its
    way to a child process: pickled as its repr, never valid in a message there, so the
    message becomes an error record with that repr, as it would in the daemon's process."""

    __slots__ = ("text",)

    def __init__(self, text: str) -> None:
        self.text = text

    def __repr__(self) -> str:
        return self.text


def message_struct(topic: str, payload: dict[str, Any] | tuple[Any, ...], t_ns: int) -> Any:
    """The checked Struct of one message: a record tuple's keys (``session_topics.RECORD_FIELDS``)
    or a dict's, ``stamp`` from ``t_ns`` (integer ns) when absent. Raises KeyError for a topic
    that is not logged or takes no record, ValueError (naming the key path) or TypeError for
    a payload that is not a message of the topic."""
    cls = TOPIC_TYPES[topic]
    if type(payload) is tuple:
        fields = RECORD_FIELDS[topic](payload)
    elif type(payload) is dict:
        fields = payload
        for key, value in payload.items():  # msgspec would take these, as a list or a float
            if type(value) in (set, frozenset):
                raise TypeError(f"{topic}.{key}: a set is not a JSON value")
            if type(value) is int and not INT_MIN <= value <= INT_MAX:
                raise ValueError(f"{topic}.{key}: integer out of the 64-bit range")
    else:
        raise TypeError(f"{topic}: a {type(payload).__name__} payload is not a JSON object")
    if "stamp" not in fields:
        fields = {**fields, "stamp": stamp_from_ns(t_ns)}
    try:
        return msgspec.convert(fields, cls)
    except msgspec.ValidationError as exc:
        raise ValueError(problem(topic, exc, fields)) from None


def struct_json(topic: str, obj: Any, nonfinite_as_null: bool = False) -> tuple[bytes, int]:
    """``(json_bytes, nulled)`` of a checked message (:func:`message_struct`). A number that is
    not finite is encoded as ``null``: where the topic's Struct does not allow ``null`` that
    raises ValueError naming the key, unless ``nonfinite_as_null`` (the live view), which
    counts them in ``nulled``."""
    data = _ENCODER.encode(obj)
    if b"null" in data:
        try:
            _DECODERS[topic].decode(data)
        except msgspec.ValidationError as exc:
            if not nonfinite_as_null:
                raise ValueError(problem(topic, exc, msgspec.to_builtins(obj))) from None
            return data, _nonfinite(msgspec.to_builtins(obj))
    return data, 0


def encode_message(topic: str, payload: dict[str, Any] | tuple[Any, ...], t_ns: int) -> bytes:
    """The JSON bytes of one message for the session log; raises (ValueError, TypeError,
    KeyError) when it is not a message of the topic or holds a number that is not finite."""
    return struct_json(topic, message_struct(topic, payload, t_ns))[0]


def _nonfinite(value: Any) -> int:
    """How many floats in ``value`` (dicts and lists of JSON values) are NaN or ±inf."""
    if type(value) is float:
        return 0 if math.isfinite(value) else 1
    if type(value) is dict:
        value = value.values()
    elif type(value) is not list:
        return 0
    return sum(_nonfinite(v) for v in value)


def safe_repr(obj: Any, limit: int = REPR_CHARS) -> str:
    """``repr(obj)`` cut to ``limit`` characters; never raises (a failing ``__repr__`` gives
    ``<unrepresentable T>``)."""
    try:
        text = repr(obj)
    except Exception:
        text = f"<unrepresentable {type(obj).__name__}>"
    return cut(text, limit)


def safe_str(exc: BaseException) -> str:
    """``str(exc)``; never raises."""
    try:
        return str(exc)
    except Exception:
        return f"<unprintable {type(exc).__name__}>"


def cut(text: str, limit: int = REPR_CHARS) -> str:
    """``text`` cut to ``limit`` characters."""
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
        "error": cut(f"{type(exc).__name__}: {safe_str(exc)}"),
        "payload": safe_repr(payload),
        "log_time": log_time,
    }


def encode_error(record: dict[str, Any]) -> bytes:
    """The JSON bytes of an :func:`error_payload` record (with its ``stamp``)."""
    return _ENCODER.encode(record)


class _PlainPickler(pickle.Pickler):
    """Plain data pickles as usual; numpy-like numbers become Python numbers; any other object
    becomes a :class:`NotJson` holding its repr, so the child never imports a class
    and a bad payload still becomes an error record there."""

    def reducer_override(self, obj: Any) -> Any:
        if isinstance(obj, numbers.Integral) and not isinstance(obj, bool):
            return int, (int(obj),)
        if isinstance(obj, numbers.Real) and not isinstance(obj, bool):
            return float, (float(obj),)
        if isinstance(obj, type):
            return NotImplemented  # classes pickle by reference (NotJson itself)
        return NotJson, (safe_repr(obj),)


class Packer:
    """Pickles ring records ``(topic, payloads, *more)`` (the MCAP writer's and the live view's
    children read them) with one reused :class:`_PlainPickler` (a new pickler per record cost twice as much). A payload that
    cannot be pickled at all (nested too deep) becomes a :class:`NotJson`. Not
    thread-safe: the caller holds its lock."""

    def __init__(self) -> None:
        self._buf = io.BytesIO()
        self._pickler = _PlainPickler(self._buf, protocol=pickle.HIGHEST_PROTOCOL)

    def __call__(self, batch: tuple[Any, ...]) -> bytes:
        try:
            return self._dump(batch)
        except Exception:
            pass
        topic, payloads, *more = batch
        safe: list[Any] = []
        for p in payloads:
            try:
                self._dump(p)
                safe.append(p)
            except Exception as exc:
                safe.append(NotJson(f"<not picklable: {type(exc).__name__}> {safe_repr(p, 200)}"))
        return self._dump((topic, safe, *more))

    def _dump(self, obj: Any) -> bytes:
        buf = self._buf
        buf.seek(0)
        buf.truncate()
        self._pickler.clear_memo()
        self._pickler.dump(obj)
        return buf.getvalue()
