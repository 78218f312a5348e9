"""The active correction grid: loaded from a file, checked, swapped atomically on reload.

:func:`load_grid` reads a grid file (``compensation.grid.CorrectionGrid.load``), then checks it
can actually correct: a point at the centre of its volume, at the reference temperatures,
must come back finite with status ``ok``. A file that fails any of this raises
:class:`GridLoadError` and changes nothing. :class:`GridSlot` holds the active grid; readers
take one reference (``slot.current``) per reading, so a reload between two readings never
mixes two grids inside one answer.
"""

from __future__ import annotations

import threading
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from cmm_comp.compensation.errors import CmmCompError
from cmm_comp.compensation.grid import CorrectionGrid
from cmm_comp.compensation.thermal import TEMPERATURE_ROLES


class GridLoadError(CmmCompError, ValueError):
    """A grid file could not be used (message names the file and the problem)."""


@dataclass(frozen=True)
class LoadedGrid:
    """A grid that passed its checks, and what the daemon needs to know about it."""

    grid: CorrectionGrid
    path: str
    sha256: str
    loaded_at_ns: int
    temperature_roles: tuple[str, ...]
    """Temperature signals the grid needs (T_x …)."""
    input_signals: tuple[str, ...]
    """Other signals the grid needs (dir_x …, nx …)."""
    machine: str
    model: str

    def identity(self) -> dict[str, Any]:
        """The /cmm/grid payload (without stamp)."""
        sec, nsec = divmod(self.loaded_at_ns, 1_000_000_000)
        return {
            "sha256": self.sha256,
            "machine": self.machine,
            "model": self.model,
            "steps": [int(s) for s in self.grid.steps],
            "path": self.path,
            "loaded_at": {"sec": sec, "nsec": nsec},
            "signals": [s.name for s in self.grid.signals if s.needed],
        }


def load_grid(path: str | Path, expect_machine_sha256: str = "") -> LoadedGrid:
    """Load and check ``path``; :class:`GridLoadError` naming the file on any problem."""
    path = Path(path)
    try:
        grid = CorrectionGrid.load(path, expect_machine=expect_machine_sha256 or None)
    except FileNotFoundError:
        raise GridLoadError(f"{path}: grid file not found") from None
    except (ValueError, OSError, KeyError, TypeError) as exc:
        raise GridLoadError(f"{path}: {exc}") from None
    needed = [s for s in grid.signals if s.needed]
    temps = {s.name: s.reference for s in needed if s.name in TEMPERATURE_ROLES}
    inputs = {s.name: s.reference for s in needed if s.name not in TEMPERATURE_ROLES}
    centre = 0.5 * (np.asarray(grid.lower_mm) + np.asarray(grid.upper_mm))
    try:
        out, status = grid.correct(centre[None, :], (0.0, 0.0, 0.0), temps, inputs)
    except Exception as exc:  # a grid that cannot correct is refused, whatever the reason
        raise GridLoadError(f"{path}: self-check correction failed: {exc!r}") from None
    if status[0] != "ok" or not np.all(np.isfinite(out)):
        raise GridLoadError(
            f"{path}: self-check at the volume centre gave status {status[0]!r}, {out[0].tolist()}"
        )
    if grid.sha256 is None:  # pragma: no cover - load() always sets it
        raise GridLoadError(f"{path}: grid has no SHA-256")
    machine = grid.metadata.get("machine", {}) or {}
    return LoadedGrid(
        grid=grid,
        path=str(path),
        sha256=grid.sha256,
        loaded_at_ns=time.time_ns(),
        temperature_roles=tuple(temps),
        input_signals=tuple(inputs),
        machine=str(machine.get("name", "")),
        model=str(machine.get("model", "")),
    )


class GridSlot:
    """Holds the active :class:`LoadedGrid` (or None); replacement is one reference swap."""

    def __init__(self) -> None:
        self._current: LoadedGrid | None = None
        self._lock = threading.Lock()  # serialises reloads, never taken by readers

    @property
    def current(self) -> LoadedGrid | None:
        """The active grid; take it once per reading."""
        return self._current

    def reload(self, path: str | Path, expect_machine_sha256: str = "") -> LoadedGrid:
        """Load ``path`` and make it active; on GridLoadError the old grid stays active."""
        with self._lock:
            loaded = load_grid(path, expect_machine_sha256)
            self._current = loaded
            return loaded

    def clear(self) -> None:
        """Drop the active grid (answers say ``no_grid``)."""
        self._current = None
