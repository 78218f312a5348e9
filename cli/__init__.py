"""The one command line, ``cmm-comp``: one module per command group.

``model`` (map, diagonals, line, report, iso230, seed files), ``grid`` (grid build, correct,
keygen, sign), ``diagnosis`` (diagnose, extend), ``importing`` (import camonitor), ``daemon``
(daemon, replay), ``mcap`` (mcap recover), ``demo`` (simulated controller → daemon). Each module imports what its commands use only when they run.
"""

from __future__ import annotations

from .main import build_parser, main

__all__ = ["build_parser", "main"]
