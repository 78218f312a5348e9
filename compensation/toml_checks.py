"""Checks of the values in a machine file's TOML, shared by the machine parser
(:mod:`.formats.machine_parser`) and the ``[uncertainty]`` reader (:mod:`.uncertainty.model`):
every problem is one :class:`~.errors.MachineFileError` naming the file, the key and what is
wrong or allowed."""

from __future__ import annotations

import math
from collections.abc import Container, Mapping
from typing import Any

from .errors import MachineFileError
from .parametric_errors import TABLE_COMPONENTS, canonical_name

__all__ = ["TomlChecks"]


class TomlChecks:
    """Validation of values read from the file ``source`` (``where`` names the key)."""

    def __init__(self, source: str) -> None:
        self.source = source

    def fail(self, where: str, problem: str) -> MachineFileError:
        return MachineFileError(self.source, where, problem)

    def number(self, value: Any, where: str, *, positive: bool = False) -> float:
        """A finite number (an int or a float, not a bool); ``positive``: > 0."""
        if isinstance(value, bool) or not isinstance(value, int | float):
            raise self.fail(where, f"expected a number, got {value!r}")
        out = float(value)
        if not math.isfinite(out):
            raise self.fail(where, f"expected a finite number, got {value!r}")
        if positive and out <= 0:
            raise self.fail(where, f"must be > 0, got {value!r}")
        return out

    def check_keys(self, table: Mapping[str, Any], where: str, allowed: set[str]) -> None:
        """Refuse keys of ``table`` not in ``allowed`` (all of them named, and the allowed)."""
        unknown = sorted(set(table) - allowed)
        if unknown:
            raise self.fail(where, f"unknown key(s) {unknown}; allowed: {sorted(allowed)}")

    def error_component(self, key: str, where: str, seen: Container[str]) -> str:
        """The canonical error component (``dx_x``, …) of a table key (ours or ISO 230-1 names),
        refused when unknown or when an alias of it is already in ``seen``."""
        canon = canonical_name(key)
        if canon is None or canon not in TABLE_COMPONENTS:
            raise self.fail(
                where,
                f"unknown error component; allowed: {', '.join(TABLE_COMPONENTS)} or ISO 230-1 names",
            )
        if canon in seen:
            raise self.fail(where, f"component {canon} is given twice (aliases count)")
        return canon
