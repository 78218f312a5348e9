"""Range rules of every numeric daemon setting, and the check that lists every violation.

:data:`NUMERIC_RULES` gives each numeric key (``section.key``) its allowed range; lists of numbers
(``grid.stylus_mm``, ``temperatures.plausible_C`` …) apply the rule to each element.
:func:`range_errors` returns one line per bad key, naming the key, the value and the allowed
range, so ``cmm-comp daemon --check`` lists all problems at once. NaN and ±inf are never allowed:
a NaN period would silence the heartbeat, a NaN limit would switch a check off.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

from cmm_comp.protocol.can_ids import NODE_STRIDE, STANDARD_ID_MAX


@dataclass(frozen=True)
class Range:
    """A closed or half-open numeric interval ``lo .. hi`` with units for the message."""

    lo: float
    hi: float
    lo_open: bool = False
    """True: ``lo`` itself is not allowed (``> lo``)."""
    unit: str = ""
    length: int | None = None
    """For list settings: the number of elements required."""

    def allows(self, value: float) -> bool:
        """Finite and inside the interval (ints compared exactly: no float overflow)."""
        if isinstance(value, float) and not math.isfinite(value):
            return False
        above = value > self.lo if self.lo_open else value >= self.lo
        return above and value <= self.hi

    def describe(self) -> str:
        """``> 0 and <= 60 s`` / ``0 .. 65535``."""
        if self is FINITE_DEFAULT:
            return "a finite number"
        unit = f" {self.unit}" if self.unit else ""
        lo = f"{self.lo:g}" if isinstance(self.lo, float) else str(self.lo)
        hi = f"{self.hi:g}" if isinstance(self.hi, float) else str(self.hi)
        text = f"> {lo} and <= {hi}{unit}" if self.lo_open else f"{lo} .. {hi}{unit}"
        if self.length is not None:
            text = f"{self.length} finite values, each {text}"
        return text


_TEMP_C = Range(-100.0, 300.0, unit="°C", length=2)

NUMERIC_RULES: dict[str, Range] = {
    "grid.stylus_mm": Range(-2000.0, 2000.0, unit="mm", length=3),
    "can.bitrate": Range(0, 20_000_000, unit="bit/s"),
    "can.node_id": Range(0, (STANDARD_ID_MAX + 1) // NODE_STRIDE - 1),
    "can.base_id": Range(0, STANDARD_ID_MAX + 1 - NODE_STRIDE),
    "can.triplet_timeout_s": Range(0.0, 10.0, lo_open=True, unit="s"),
    "can.window": Range(1, 1024),
    "can.send_timeout_s": Range(0.0, 10.0, lo_open=True, unit="s"),
    "can.heartbeat_s": Range(0.0, 60.0, lo_open=True, unit="s"),
    "can.reconnect_s": Range(0.0, 600.0, lo_open=True, unit="s"),
    "modbus.port": Range(0, 65535),
    "modbus.device_id": Range(1, 247),
    "modbus.idle_timeout_s": Range(0.0, 86400.0, unit="s (0 = never)"),
    "modbus.frame_timeout_s": Range(0.0, 60.0, lo_open=True, unit="s"),
    "temperatures.stale_s": Range(0.0, 86400.0, lo_open=True, unit="s"),
    "temperatures.plausible_C": _TEMP_C,
    "temperatures.valid_range_C": _TEMP_C,
    "temperatures.max_rate_C_per_s": Range(0.0, 1e9, lo_open=True, unit="°C/s"),
    "limits.warn_um": Range(0.0, 1e6, lo_open=True, unit="µm"),
    "limits.error_um": Range(0.0, 1e6, lo_open=True, unit="µm"),
    "mcap.roll_mb": Range(0.0, 1e6, unit="MB (0 = never)"),
    "mcap.roll_s": Range(0.0, 1e7, unit="s (0 = never)"),
    "mcap.flush_s": Range(0.0, 3600.0, lo_open=True, unit="s"),
    "metrics.port": Range(0, 65535),
    "metrics.period_s": Range(0.0, 3600.0, lo_open=True, unit="s"),
    "log.max_per_s": Range(0.0, 1e6, unit="lines/s (0 = unlimited)"),
    "log.state_repeat_s": Range(0.0, 86400.0, lo_open=True, unit="s"),
}
"""Every numeric setting's allowed range (``section.key`` → :class:`Range`)."""

FINITE_DEFAULT = Range(-1e300, 1e300)
"""Numeric settings without an entry above must at least be finite."""


def _bad(value: Any, rule: Range) -> bool:
    if rule.length is not None:
        if not isinstance(value, list) or len(value) != rule.length:
            return True
        return not all(isinstance(v, int | float) and rule.allows(v) for v in value)
    return not (isinstance(value, int | float) and rule.allows(value))


def _show(value: Any) -> str:
    if isinstance(value, list):
        return "[" + ", ".join(_show(v) for v in value) + "]"
    if isinstance(value, float):
        return repr(value)  # nan, inf, 1e+300 as written
    return str(value)


def range_errors(where: str, values: dict[str, Any], skip: set[str]) -> dict[str, str]:
    """One line per numeric setting outside its range: ``section.key`` → message.

    :param values: ``section.key`` → value, for every numeric setting (ints, floats, lists of
        floats). Keys in ``skip`` (already reported, e.g. of the wrong type) are not checked.
    """
    out = {}
    for name, value in values.items():
        if name in skip or value is None:  # None: an optional setting left unset
            continue
        rule = NUMERIC_RULES.get(name, FINITE_DEFAULT)
        if _bad(value, rule):
            out[name] = f"{where}: {name} = {_show(value)}; allowed: {rule.describe()}"
    return out
