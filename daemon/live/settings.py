"""The ``[live]`` section of the daemon configuration: the live view over the Foxglove WebSocket
protocol (docs/live.md).

:class:`LiveSection` holds the settings (plain ``bool``/``str``/``int``/``float`` fields, so the
daemon's generic TOML parsing and ``--live-<key>`` override flags handle it like every other
section); :func:`live_problems` lists every rule a section violates, one line each, naming the
key, the value and what is allowed; :func:`live_section_from_table` builds and checks a section
from a parsed ``[live]`` TOML table on its own (unknown keys, wrong types, ranges, the host
policy), raising :class:`LiveConfigError` with every problem.

The server binds to a loopback address unless ``allow_remote = true``: the WebSocket protocol
has no authentication, and anyone who can reach the port sees every reading.
"""

from __future__ import annotations

import dataclasses
import ipaddress
import math
from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any, get_type_hints

from cmm_comp.compensation.errors import CmmCompError

from ..config_checks import Range


class LiveConfigError(CmmCompError, ValueError):
    """A ``[live]`` setting is invalid. ``lines``: one line per problem."""

    def __init__(self, lines: list[str]) -> None:
        self.lines = list(lines)
        super().__init__("\n".join(self.lines))


@dataclass
class LiveSection:
    """Live view: the session-log topics and a 3-D scene of the corrections, streamed over the
    Foxglove WebSocket protocol (``foxglove-sdk``, optional extra ``live``). Off by default."""

    enabled: bool = False
    """Start the WebSocket server (needs ``pip install 'cmm-comp[live]'``)."""
    host: str = "127.0.0.1"
    """Bind address: an IP literal or ``localhost``; loopback only unless ``allow_remote``."""
    port: int = 8765
    """TCP port (Foxglove's default 8765); 0 = any free port."""
    allow_remote: bool = False
    """Allow a non-loopback ``host`` (the protocol has no authentication: anyone who reaches the
    port sees every reading)."""
    queue: int = 4096
    """Messages the live view holds between two updates (its process's queue: when full the
    oldest are dropped; also the size of the shared-memory ring between the daemon and the
    process, 256 bytes a message: when full the newest are dropped); every drop is counted."""
    update_rate_hz: float = 10.0
    """Updates sent to clients per second, at most (what arrived in between goes out
    together, the high-rate topics decimated). 10 by default: a viewer on the daemon's host
    competes with the reply path for CPU in proportion to what it receives; at 30 it cost the
    reply's p99 +36 µs on a 2-core host (docs/live.md, "Measured")."""
    max_per_update: int = 4
    """``/cmm/raw`` and ``/cmm/corrected`` messages per update, at most (evenly picked, the
    newest always included; answers not ``ok`` are kept besides): 40 a second each at the
    defaults. The MCAP log is the full record."""
    scene_rate_hz: float = 10.0
    """At most this many ``/cmm/scene`` updates per second."""
    scene_keep_arrows: int = 256
    """Correction arrows kept in the 3-D scene (the newest replace the oldest)."""
    scene_max_new_arrows: int = 8
    """At most this many new arrows per scene update (evenly picked among the new readings, the
    newest always included): bounds the scene's cost at high reading rates."""
    arrow_mm_per_um: float = 5.0
    """Magnification of the correction arrows: drawn length, mm, per µm of correction."""


LIVE_RULES: dict[str, Range] = {
    "port": Range(0, 65535),
    "queue": Range(1, 1_000_000, unit="messages"),
    "update_rate_hz": Range(0.0, 1000.0, lo_open=True, unit="Hz"),
    "max_per_update": Range(1, 100_000, unit="messages"),
    "scene_rate_hz": Range(0.0, 1000.0, lo_open=True, unit="Hz"),
    "scene_keep_arrows": Range(1, 100_000),
    "scene_max_new_arrows": Range(1, 10_000),
    "arrow_mm_per_um": Range(0.0, 1e6, lo_open=True, unit="mm/µm"),
}
"""Allowed range of every numeric ``[live]`` key (NaN and ±inf never allowed)."""


def _section_types() -> dict[str, Any]:
    return get_type_hints(LiveSection)


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


def _bad_number(value: Any, rule: Range) -> bool:
    if isinstance(value, bool) or not isinstance(value, int | float):
        return True
    if isinstance(value, float) and not math.isfinite(value):
        return True
    return not rule.allows(value)


def live_problems(section: LiveSection, where: str, skip: set[str] | None = None) -> list[str]:
    """Every rule ``section`` violates, one line each (``<where>: live.<key> = <value>; allowed:
    …``). Keys in ``skip`` (``live.<key>``, already reported by the caller) are left out."""
    skip = skip or set()
    out: list[str] = []
    for key, rule in LIVE_RULES.items():
        if f"live.{key}" in skip:
            continue
        value = getattr(section, key)
        if _bad_number(value, rule):
            shown = repr(value) if isinstance(value, float) else str(value)
            out.append(f"{where}: live.{key} = {shown}; allowed: {rule.describe()}")
    if "live.host" not in skip and "live.allow_remote" not in skip:
        why = host_problem(section.host, section.allow_remote)
        if why is not None:
            out.append(f"{where}: live.host = {why}")
    return out


def _coerce(where: str, value: Any, hint: Any) -> Any:
    """``value`` as the field's type, else LiveConfigError's line (no silent conversion)."""
    if hint is bool:
        if isinstance(value, bool):
            return value
        raise ValueError(f"{where}: {value!r:.60} must be true or false")
    if hint is int:
        if isinstance(value, int) and not isinstance(value, bool):
            return value
        raise ValueError(f"{where}: {value!r:.60} must be an integer")
    if hint is float:
        if isinstance(value, int | float) and not isinstance(value, bool):
            try:
                return float(value)
            except OverflowError:
                raise ValueError(f"{where}: {value!r:.60} is too large") from None
        raise ValueError(f"{where}: {value!r:.60} must be a number")
    if isinstance(value, str):
        return value
    raise ValueError(f"{where}: {value!r:.60} must be a string")


def live_section_from_table(table: Mapping[str, Any] | None, source: str = "<live>") -> LiveSection:
    """A checked :class:`LiveSection` from a parsed ``[live]`` TOML table (None or empty =
    defaults). Raises :class:`LiveConfigError` listing every problem: unknown keys (naming the
    allowed ones), wrong types, values out of range, a host that may not be bound."""
    section = LiveSection()
    if table is None:
        return section
    if not isinstance(table, Mapping):
        raise LiveConfigError([f"{source}: [live] must be a table"])
    types = _section_types()
    errors: list[str] = []
    reported: set[str] = set()
    for key, value in table.items():
        if key not in types:
            errors.append(f"{source}: unknown key live.{key}; allowed: {', '.join(sorted(types))}")
            continue
        try:
            setattr(section, key, _coerce(f"{source}: live.{key}", value, types[key]))
        except ValueError as exc:
            errors.append(str(exc))
            reported.add(f"live.{key}")
    errors += live_problems(section, source, reported)
    if errors:
        raise LiveConfigError(errors)
    return section


def section_keys() -> tuple[str, ...]:
    """The ``[live]`` keys, in declaration order."""
    return tuple(f.name for f in dataclasses.fields(LiveSection))
