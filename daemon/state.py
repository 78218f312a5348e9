"""The daemon's state (starting, ready, degraded, no_grid, fault, stopping) and its changes.

Every change is logged once: a ``state`` event on stdout and a ``/cmm/status`` message. The
state is derived from conditions the parts report (``set_condition("can", "bus error")``) and
whether a grid is loaded; the worst one wins.
"""

from __future__ import annotations

import threading
from collections.abc import Callable

from cmm_comp.protocol.codes import DaemonState


class StateBoard:
    """Current :class:`DaemonState` and detail; calls ``on_change(state, detail)`` on changes.

    Conditions are named problems (``"can"``, ``"temperatures"``, ``"mcap"``) with a text; any
    condition makes the daemon DEGRADED; a missing grid makes it NO_GRID; a condition named
    ``fault:*`` makes it FAULT.
    """

    def __init__(self, on_change: Callable[[DaemonState, str], None]) -> None:
        self._on_change = on_change
        self._lock = threading.Lock()
        self._conditions: dict[str, str] = {}
        self._has_grid = False
        self._phase = DaemonState.STARTING
        self.state = DaemonState.STARTING
        self.detail = "starting"

    def set_condition(self, name: str, detail: str | None) -> None:
        """Raise (``detail`` text) or clear (None) a named condition."""
        with self._lock:
            if detail is None:
                if self._conditions.pop(name, None) is None:
                    return
            else:
                if self._conditions.get(name) == detail:
                    return
                self._conditions[name] = detail
        self._evaluate()

    def conditions(self) -> dict[str, str]:
        """Active conditions."""
        with self._lock:
            return dict(self._conditions)

    def set_grid(self, present: bool) -> None:
        """Whether a grid is active."""
        self._has_grid = present
        self._evaluate()

    def set_phase(self, phase: DaemonState) -> None:
        """STARTING, READY (running) or STOPPING: the lifecycle phase."""
        self._phase = phase
        self._evaluate()

    def _evaluate(self) -> None:
        with self._lock:
            conds = dict(self._conditions)
            state: DaemonState
            if self._phase in (DaemonState.STARTING, DaemonState.STOPPING):
                state, detail = self._phase, self._phase.label
            elif faults := {k: v for k, v in conds.items() if k.startswith("fault:")}:
                state = DaemonState.FAULT
                detail = "; ".join(f"{k[6:]}: {v}" for k, v in sorted(faults.items()))
            elif not self._has_grid:
                state, detail = DaemonState.NO_GRID, "no grid loaded: answers are not corrected"
            elif conds:
                state = DaemonState.DEGRADED
                detail = "; ".join(f"{k}: {v}" for k, v in sorted(conds.items()))
            else:
                state, detail = DaemonState.READY, "ready"
            changed = (state, detail) != (self.state, self.detail)
            self.state, self.detail = state, detail
        if changed:
            self._on_change(state, detail)
