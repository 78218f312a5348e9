"""The active correction grid: loaded from a file, checked, swapped atomically on reload.

:func:`load_grid` reads a grid file (``compensation.grid.CorrectionGrid.load``), checks that it
is trusted (:mod:`.grid_trust`: signature, machine, volume), then checks it can actually
correct: a point at the centre of its volume, at the reference temperatures, must come back
finite with status ``ok``. A file that fails any of this raises :class:`GridLoadError` and
changes nothing. :class:`GridSlot` holds the active grid; readers take one reference
(``slot.current``) per reading, so a reload between two readings never mixes two grids inside
one answer. :class:`GridReloader` prepares a reload (read, verify, build) in its own thread and
ends it with one reference swap: the reply path never waits for a reload.
"""

from __future__ import annotations

import os
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from cmm_comp.compensation.errors import CmmCompError
from cmm_comp.compensation.grid import CorrectionGrid
from cmm_comp.compensation.grid.file import GridContents
from cmm_comp.compensation.thermal import TEMPERATURE_ROLES

from .grid_trust import GridTrust
from .osthread import name_os_thread

KERNEL_CACHE_OFF = (
    "no writable cache folder for the compiled grid kernels (NUMBA_CACHE_DIR unset, the "
    "installation read-only, no home): they are compiled in every daemon process at start "
    "(~18 s of CPU measured, ~2 s with a cache) instead of once; set NUMBA_CACHE_DIR to a "
    "folder this user can write (the systemd unit: CacheDirectory=)"
)
"""The warning (at start and in ``--check``) when numba has nowhere to cache the kernels."""

STYLUS_TOL_MM = 1e-9
"""A configured stylus closer than this to the grid's probe offset (per axis, mm) is equal."""


def stylus_note(
    configured: list[float] | None, probe_mm: tuple[float, float, float], grid_path: str
) -> str | None:
    """The line saying a configured ``grid.stylus_mm`` differs from the grid's probe offset
    (mm), or None when it is unset or equal."""
    if configured is None or len(configured) != 3:  # a bad length is a configuration problem
        return None
    if np.all(np.abs(np.asarray(configured, float) - np.asarray(probe_mm)) <= STYLUS_TOL_MM):
        return None
    return (
        f"grid.stylus_mm = {list(configured)} differs from the probe offset {list(probe_mm)} "
        f"mm the grid {grid_path} was built with: every reading is corrected for the configured "
        "stylus (remove grid.stylus_mm to use the grid's)"
    )


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
    signed_by: str = ""
    """Key id of the verified signature; empty when the grid was accepted unsigned."""
    loaded_by_pid: int = 0
    """Process that read, verified and built it (a SIGHUP reload: the loader process)."""
    has_uncertainty: bool = False
    """The grid carries U (``grid build --uncertainty``): answers carry it too."""
    probe_offset_mm: tuple[float, float, float] = (0.0, 0.0, 0.0)
    """The probe offset the grid was built with (its machine's ``[probe] offset_mm``), mm: the
    stylus used when ``grid.stylus_mm`` is not set."""

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
            "uncertainty": self.has_uncertainty,
        }


def load_grid(path: str | Path, trust: GridTrust | None = None) -> LoadedGrid:
    """Load and check ``path``; :class:`GridLoadError` naming the file on any problem.

    ``trust``: the daemon's trust rules (:class:`GridTrust`); None = no signature or machine
    check (offline tools only).
    """
    path = Path(path)
    signer = [""]
    try:
        machine_ref = trust.resolve_machine() if trust is not None else None

        def verify(contents: GridContents) -> None:
            if trust is not None:
                signer[0] = trust.check(contents, machine_ref)

        grid = CorrectionGrid.load(path, verify=verify)
    except FileNotFoundError:
        raise GridLoadError(f"{path}: grid file not found") from None
    except (ValueError, OSError, KeyError, TypeError, RecursionError) as exc:
        raise GridLoadError(f"{path}: {exc}" if str(path) not in str(exc) else str(exc)) from None
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
    probe = grid_probe_offset_mm(grid.metadata)
    if probe is None:
        raise GridLoadError(
            f"{path}: header probe_offset_mm {grid.metadata.get('probe_offset_mm')!r} is not "
            "3 finite numbers (mm)"
        )
    return LoadedGrid(
        grid=grid,
        path=str(path),
        sha256=grid.sha256,
        loaded_at_ns=time.time_ns(),
        temperature_roles=tuple(temps),
        input_signals=tuple(inputs),
        machine=str(machine.get("name", "")),
        model=str(machine.get("model", "")),
        signed_by=signer[0],
        loaded_by_pid=os.getpid(),
        has_uncertainty=bool(getattr(grid, "has_uncertainty", False)),
        probe_offset_mm=probe,
    )


def grid_probe_offset_mm(header: dict[str, Any]) -> tuple[float, float, float] | None:
    """A grid header's ``probe_offset_mm`` (mm; absent: 0, 0, 0), None when malformed."""
    value = header.get("probe_offset_mm", [0.0, 0.0, 0.0])
    try:
        xyz = np.asarray(value, dtype=float).reshape(3)
    except (TypeError, ValueError):
        return None
    if not np.all(np.isfinite(xyz)):
        return None
    return (float(xyz[0]), float(xyz[1]), float(xyz[2]))


class GridSlot:
    """Holds the active :class:`LoadedGrid` (or None); replacement is one reference swap."""

    def __init__(self) -> None:
        self._current: LoadedGrid | None = None
        self._lock = threading.Lock()  # serialises reloads, never taken by readers

    @property
    def current(self) -> LoadedGrid | None:
        """The active grid; take it once per reading."""
        return self._current

    def reload(
        self,
        path: str | Path,
        trust: GridTrust | None = None,
        loader: Callable[[str | Path, GridTrust | None], LoadedGrid] = load_grid,
    ) -> LoadedGrid:
        """Load ``path`` and make it active; on GridLoadError the old grid stays active.

        The load runs in the calling thread; readers keep using the old grid until the one
        reference swap at the end.
        """
        with self._lock:
            loaded = loader(path, trust)
            self._current = loaded
            return loaded

    def clear(self) -> None:
        """Drop the active grid (answers say ``no_grid``)."""
        self._current = None


class GridReloader:
    """A thread that performs requested reloads (``request()``, e.g. from SIGHUP) off the
    reply path. Requests that arrive during a reload are merged into one more reload.

    :param reload: does one reload (load, verify, build, swap, report); must not raise.
    Context manager; ``stop(timeout_s)``.
    """

    def __init__(self, reload: Callable[[], object]) -> None:
        self._reload = reload
        self._wake = threading.Event()
        self._stopping = False
        self._thread = threading.Thread(target=self._run, name="grid-reload", daemon=True)
        self.completed = 0
        """Reloads finished (successful or refused)."""
        self.errors: list[str] = []
        """Unexpected exceptions of ``reload`` (it should report its own problems)."""

    def start(self) -> GridReloader:
        """Start the thread."""
        self._thread.start()
        return self

    def request(self) -> None:
        """Ask for a reload (returns at once; safe from a signal handler)."""
        self._wake.set()

    def _run(self) -> None:
        name_os_thread()
        while True:
            self._wake.wait()
            if self._stopping:
                return
            self._wake.clear()
            try:
                self._reload()
            except Exception as exc:  # never let the thread die silently
                self.errors.append(repr(exc))
            self.completed += 1

    def stop(self, timeout_s: float = 5.0) -> bool:
        """Stop after the reload in progress (if any); True if the thread ended in time."""
        self._stopping = True
        self._wake.set()
        if self._thread.is_alive():
            self._thread.join(timeout_s)
        return not self._thread.is_alive()

    def __enter__(self) -> GridReloader:
        return self.start()

    def __exit__(self, *exc: object) -> None:
        self.stop()
