"""The daemon's state (starting, ready, degraded, no_grid, fault, stopping) and its changes.

Every change is logged once: a ``state`` event on stdout and a ``/cmm/status`` message. The
state is derived from conditions the parts report (``set_condition("can", "bus error")``) and
whether a grid is loaded; the worst one wins.

A change of the state or of the set of conditions is reported at once. A change of the detail
text only (a stale sensor's age, "unchanged for 10.3 s", "10.4 s", …) is a *repeat*: reported
at most every ``repeat_s`` seconds, with the number of repeats not reported since; the next
real change (e.g. the condition clearing) carries the remaining count.
"""

from __future__ import annotations

import threading
import time
from collections.abc import Callable

from cmm_comp.protocol.codes import DaemonState


class StateBoard:
    """Current :class:`DaemonState` and detail; calls ``on_change(state, detail, repeats)``
    on changes (``repeats``: detail-only changes not reported since the last call).

    Conditions are named problems (``"can"``, ``"temperatures"``, ``"mcap"``) with a text; any
    condition makes the daemon DEGRADED; a missing grid makes it NO_GRID; a condition named
    ``fault:*`` makes it FAULT.

    :param repeat_s: detail-only changes are reported at most this often, s.
    :param clock: monotonic seconds (tests pass a fake clock).
    """

    def __init__(
        self,
        on_change: Callable[[DaemonState, str, int], None],
        repeat_s: float = 10.0,
        clock: Callable[[], float] = time.monotonic,
    ) -> None:
        self._on_change = on_change
        self._repeat_s = repeat_s
        self._clock = clock
        self._lock = threading.Lock()
        self._conditions: dict[str, str] = {}
        self._has_grid = False
        self._phase = DaemonState.STARTING
        self.state = DaemonState.STARTING
        self.detail = "starting"
        self._kinds: tuple[str, ...] = ()
        self._last_report_s = -float("inf")
        self._repeats = 0

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
            if (state, detail) == (self.state, self.detail):
                return
            kinds = tuple(sorted(conds))
            now = self._clock()
            repeat = state == self.state and kinds == self._kinds
            self.state, self.detail, self._kinds = state, detail, kinds
            if repeat and now - self._last_report_s < self._repeat_s:
                self._repeats += 1
                return
            repeats, self._repeats, self._last_report_s = self._repeats, 0, now
        self._on_change(state, detail, repeats)
