"""Exceptions with messages written for people: they name the file, key or value and what is allowed."""

from __future__ import annotations


class CmmCompError(ValueError):
    """Base class of every error this project raises on bad input."""


class MachineFileError(CmmCompError):
    """A machine description (TOML, CSV or seed-style file set) is malformed."""

    def __init__(self, source: str, where: str, problem: str) -> None:
        self.source = source
        self.where = where
        self.problem = problem
        location = f"{source}: {where}" if where else source
        super().__init__(f"{location}: {problem}")


class MeasurementFileError(CmmCompError):
    """A verification measurements file is malformed."""
