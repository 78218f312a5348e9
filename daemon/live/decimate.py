"""Which messages of one live-view update are sent: the high-rate topics are decimated.

The live view is for eyes: a plot gains nothing from 1000 points a second, and every message
sent costs the server, the network and the client (Foxglove on the same two cores as the
daemon). The session log (MCAP) is the full record; the live view sends, per update (at most
``update_rate_hz`` a second) and per high-rate topic (:data:`DECIMATED_TOPICS`), at most
``max_per_update`` messages evenly picked among those that arrived since the last update, the
newest always included; an answer whose status is not ``ok`` is kept besides (the newest
``max_per_update`` of them), so an ``outside_volume`` blip is never decimated away. Every other
topic (temperatures, status, counters, grid) is sent whole. The 3-D scene draws from every
answer, before this decimation (:mod:`.scene`, its own limits).
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

DECIMATED_TOPICS: frozenset[str] = frozenset({"/cmm/raw", "/cmm/corrected"})
"""Topics with a message per reading (up to kHz): decimated per update."""
_CORRECTED = "/cmm/corrected"
_STATUS_FIELD = 4
"""Index of the status label in a ``/cmm/corrected`` record tuple (session_topics.corrected_fields)."""


def pick_evenly(count: int, k: int) -> list[int]:
    """At most ``k`` (≥ 1) indices of ``range(count)``, evenly spread, always ending with the
    last."""
    if count <= k:
        return list(range(count))
    if k == 1:
        return [count - 1]
    return [round(i * (count - 1) / (k - 1)) for i in range(k)]


def is_not_ok(payload: Any) -> bool:
    """True for a ``/cmm/corrected`` payload (record tuple or object) whose status is not
    ``ok``, or whose status cannot be read (shown rather than hidden)."""
    try:
        status = payload[_STATUS_FIELD] if type(payload) is tuple else payload["status"]
    except (IndexError, KeyError, TypeError):
        return True
    return status != "ok"


def kept(topic: str, payloads: Sequence[Any], max_per_update: int) -> set[int] | None:
    """Indices of ``payloads`` (this update's messages of ``topic``, oldest first) to send, or
    None for all of them."""
    n = len(payloads)
    if topic not in DECIMATED_TOPICS or n <= max_per_update:
        return None
    keep = set(pick_evenly(n, max_per_update))
    if topic == _CORRECTED:
        bad = [i for i in range(n) if i not in keep and is_not_ok(payloads[i])]
        keep.update(bad[-max_per_update:])
    return keep
