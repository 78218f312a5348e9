"""The ``[live]`` section of the daemon configuration: the live view over the Foxglove WebSocket
protocol (docs/live.md).

:class:`LiveSection` holds the settings, each with its rule (checked with the rest of the daemon
configuration, :mod:`..config`, and overridable by ``--live-<key>`` flags);
:func:`live_section_from_table` checks a parsed ``[live]`` TOML table on its own, raising
:class:`LiveConfigError` with every problem.

The server binds to a loopback address unless ``allow_remote = true``: the WebSocket protocol
has no authentication, and anyone who can reach the port sees every reading.
"""

from __future__ import annotations

import ipaddress
from collections.abc import Iterable, Mapping
from dataclasses import dataclass
from typing import Annotated, Any

from cmm_comp.compensation.errors import CmmCompError
from cmm_comp.compensation.toml_schema import (
    Num,
    Problem,
    Rule,
    SchemaError,
    Table,
    usable,
    validate,
)


class LiveConfigError(CmmCompError, ValueError):
    """A ``[live]`` setting is invalid. ``lines``: one line per problem."""

    def __init__(self, lines: list[str]) -> None:
        self.lines = list(lines)
        super().__init__("\n".join(self.lines))


_RATE_HZ = Num(0.0, 1000.0, "Hz", lo_open=True)


def _address(host: str) -> Iterable[Problem]:
    why = host_problem(host, allow_remote=True)
    if why is not None:
        yield f" = {why}"


@dataclass
class LiveSection(Table):
    """Live view: the session-log topics and a 3-D scene of the corrections, streamed over the
    Foxglove WebSocket protocol (``foxglove-sdk``, optional extra ``live``). Off by default."""

    enabled: bool = False
    """Start the WebSocket server (needs ``pip install 'cmm-comp[live]'``)."""
    host: Annotated[str, Rule(_address, doc="an IP literal or localhost")] = "127.0.0.1"
    """Bind address: an IP literal or ``localhost``; loopback only unless ``allow_remote``."""
    port: Annotated[int, Num(0, 65535)] = 8765
    """TCP port (Foxglove's default 8765); 0 = any free port."""
    allow_remote: bool = False
    """Allow a non-loopback ``host`` (the protocol has no authentication: anyone who reaches the
    port sees every reading)."""
    queue: Annotated[int, Num(1, 1_000_000, "messages")] = 4096
    """Size of the shared-memory ring between the daemon and the view's process, in messages
    (256 bytes a message): what arrives between two updates waits there; when it is full the
    newest are dropped, every drop counted (``live_dropped``)."""
    update_rate_hz: Annotated[float, _RATE_HZ] = 10.0
    """Updates sent to clients per second, at most (what arrived in between goes out
    together, the high-rate topics decimated). 10 by default: a viewer on the daemon's host
    competes with the reply path for CPU in proportion to what it receives; at 30 it cost the
    reply's p99 +36 µs on a 2-core host (docs/live.md, "Measured")."""
    max_per_update: Annotated[int, Num(1, 100_000, "messages")] = 4
    """``/cmm/raw`` and ``/cmm/corrected`` messages per update, at most (evenly picked, the
    newest always included; answers not ``ok`` are kept besides): 40 a second each at the
    defaults. The MCAP log is the full record."""
    scene_rate_hz: Annotated[float, _RATE_HZ] = 10.0
    """At most this many ``/cmm/scene`` updates per second."""
    scene_keep_arrows: Annotated[int, Num(1, 100_000)] = 256
    """Correction arrows kept in the 3-D scene (the newest replace the oldest)."""
    scene_max_new_arrows: Annotated[int, Num(1, 10_000)] = 8
    """At most this many new arrows per scene update (evenly picked among the new readings, the
    newest always included): bounds the scene's cost at high reading rates."""
    arrow_mm_per_um: Annotated[float, Num(0.0, 1e6, "mm/µm", lo_open=True)] = 5.0
    """Magnification of the correction arrows: drawn length, mm, per µm of correction."""

    def rules(self, context: Mapping[str, Any]) -> Iterable[Problem]:
        why = host_problem(self.host, self.allow_remote)
        if why is not None and usable(context, "host", "allow_remote"):
            yield ("host",), f" = {why}"


def host_problem(host: str, allow_remote: bool) -> str | None:
    """Why ``host`` cannot be bound, or None: it must be an IP literal or ``localhost``, and a
    loopback address unless ``allow_remote``."""
    if host == "localhost":
        return None
    try:
        addr = ipaddress.ip_address(host)
    except ValueError:
        return (
            f"{host!r} is not an IP address; allowed: an IP literal such as 127.0.0.1, or localhost"
        )
    if not addr.is_loopback and not allow_remote:
        return (
            f"{host!r} is not a loopback address; the live view has no authentication, so only "
            "127.0.0.0/8, ::1 or localhost are allowed unless live.allow_remote = true"
        )
    return None


def live_section_from_table(table: Mapping[str, Any] | None, source: str = "<live>") -> LiveSection:
    """A checked :class:`LiveSection` from a parsed ``[live]`` TOML table (None or empty =
    defaults). Raises :class:`LiveConfigError` listing every problem: unknown keys (naming the
    allowed ones), wrong types, values out of range, a host that may not be bound."""
    try:
        section: LiveSection = validate(_LiveFile, {"live": table or {}}, source).live
    except SchemaError as exc:
        raise LiveConfigError(exc.lines) from None
    return section


@dataclass
class _LiveFile(Table):
    """A file holding only ``[live]`` (so that messages name ``live.<key>``)."""

    live: LiveSection
