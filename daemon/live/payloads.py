"""One logged message to the JSON bytes the live view sends: the same object the MCAP log writes
(docs/mcap.md), with non-finite numbers as ``null`` instead of an error record.

The session log refuses a payload holding NaN or ±inf and writes an error record in its place
(``sessionlog.encoding``): a file must never hold a number no reader parses. A live view is for
looking at: a reading whose correction came out NaN should still be seen, with the bad field
empty. :func:`encode_live` therefore writes strict JSON (``allow_nan=False``; Foxglove and every
JavaScript reader reject ``NaN``) and replaces each non-finite float by ``null``, counting them.
Times are ``stamp = {sec, nsec}`` objects, never one int64 ns number (JSON numbers are doubles).
"""

from __future__ import annotations

import json
import math
from collections.abc import Callable
from typing import Any

from ..sessionlog.records import expand
from ..sessionlog.schemas import stamp_from_ns

_dumps: Callable[[Any], str] = json.JSONEncoder(separators=(",", ":"), allow_nan=False).encode
"""The session log's encoder (``sessionlog.encoding.json_encoder``): compact, ASCII, strict, so
a valid message's bytes are the MCAP log's bytes (and its fast path's, ``sessionlog.fastjson``)."""

MAX_DEPTH = 16
"""Deepest nesting walked when replacing non-finite numbers (deeper payloads are refused)."""


def null_nonfinite(value: Any, depth: int = 0) -> tuple[Any, int]:
    """``value`` with every non-finite float (in dicts, lists and tuples, at any depth up to
    :data:`MAX_DEPTH`) replaced by None, and how many were replaced. Containers holding no
    non-finite number are returned as they are (not copied)."""
    if isinstance(value, float):
        return (value, 0) if math.isfinite(value) else (None, 1)
    if depth > MAX_DEPTH:
        raise ValueError(f"payload nested deeper than {MAX_DEPTH} levels")
    if isinstance(value, dict):
        replaced = 0
        out: dict[Any, Any] = {}
        for key, item in value.items():
            new, n = null_nonfinite(item, depth + 1)
            out[key] = new
            replaced += n
        return (out, replaced) if replaced else (value, 0)
    if isinstance(value, list | tuple):
        replaced = 0
        items = []
        for item in value:
            new, n = null_nonfinite(item, depth + 1)
            items.append(new)
            replaced += n
        return (items, replaced) if replaced else (value, 0)
    return value, 0


def live_object(topic: str, payload: dict[str, Any] | tuple[Any, ...], t_ns: int) -> dict[str, Any]:
    """The JSON object of one logged message: a record tuple built by its topic's builder
    (``sessionlog.records``; TypeError/ValueError for a malformed one), a dict as it is, with
    ``stamp`` from ``t_ns`` (integer ns) when absent. Never mutates ``payload``."""
    obj = expand(topic, payload)
    if type(obj) is not dict:
        raise TypeError(f"{topic}: a {type(obj).__name__} payload is not a JSON object")
    if "stamp" not in obj:
        obj = {**obj, "stamp": stamp_from_ns(t_ns)}
    return obj


def encode_live(
    topic: str, payload: dict[str, Any] | tuple[Any, ...], t_ns: int
) -> tuple[bytes, dict[str, Any], int]:
    """``(json_bytes, object, nulled)``: the message as strict JSON, the object it encodes
    (non-finite numbers already None) and how many non-finite numbers became ``null``.

    Raises TypeError/ValueError (a malformed record, a value that is not JSON) and
    RecursionError: the caller counts those and goes on with the next message."""
    obj = live_object(topic, payload, t_ns)
    try:
        return _dumps(obj).encode(), obj, 0
    except ValueError as exc:
        if "Out of range float" not in str(exc):
            raise
    clean, nulled = null_nonfinite(obj)
    return _dumps(clean).encode(), clean, nulled
