"""Latest temperature of each sensor and the checks that decide whether it may be used.

A frame repeating the previous counter of its sensor is not a new sample: it is ignored
(nothing stored, whatever its value; :attr:`SensorState.repeated` tells the caller, who counts
it). A sample is usable when its sensor reports it valid, it is within the plausible range (a
sensor fault otherwise), it did not jump faster than ``max_rate_C_per_s`` from the previous
sample, it is within the range the compensation is valid for, and its sample counter changed
within ``stale_s``. Time is a monotonic clock in s supplied by the caller, so tests can step it.

:meth:`TemperatureTable.inputs` returns the ``temps_C`` mapping for the grid and, when a
required role is not usable, the status that says why (first reason in the order of roles).
"""

from __future__ import annotations

import threading
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, replace

from cmm_comp.compensation.thermal import FIRST_ORDER_LAG, FirstOrderLag, SignalFilter
from cmm_comp.protocol.codes import Status

from .config import TemperaturesSection


@dataclass(frozen=True, slots=True)
class SensorState:
    """What the daemon knows about one sensor."""

    sensor: int
    role: str
    temp_C: float
    counter: int
    valid: bool
    received_s: float
    """Monotonic time the last frame arrived, s."""
    changed_s: float
    """Monotonic time the counter last changed, s."""
    fault: Status | None
    """Why this sample is unusable (apart from staleness), or None."""
    detail: str
    repeated: bool = False
    """True on the state returned for an ignored frame that repeated the previous counter
    (the state is the previous sample's, unchanged)."""


@dataclass(frozen=True, slots=True)
class TemperatureVerdict:
    """Outcome of checking the temperatures one reading needs."""

    temps_C: dict[str, float]
    """Usable temperatures by role (°C)."""
    status: Status | None
    """None when every required role is usable; else the first fault."""
    detail: str


class TemperatureTable:
    """Sensor id → latest sample, with the configured checks. Thread-safe."""

    def __init__(self, config: TemperaturesSection, roles: dict[int, str]) -> None:
        self.config = config
        self.roles = dict(roles)
        self._lock = threading.Lock()
        self._sensors: dict[int, SensorState] = {}
        self._by_role: dict[str, int] = {role: sid for sid, role in self.roles.items()}
        self._lags: dict[tuple[str, float], FirstOrderLag] = {}
        self._version = 0  # bumped by every stored sample
        # the last all-usable verdict: (version, required roles, usable until s, verdict)
        self._ok_cache: tuple[int, tuple[str, ...], float, TemperatureVerdict] | None = None

    def update(
        self, sensor: int, temp_C: float, counter: int, valid: bool, now_s: float
    ) -> SensorState | None:
        """Store a sample; return its state (None for a sensor id not in the configuration).

        A frame whose counter equals the previous sample's is ignored: the previous state is
        returned with ``repeated=True`` and nothing changes."""
        role = self.roles.get(sensor)
        if role is None:
            return None
        cfg = self.config
        with self._lock:
            prev = self._sensors.get(sensor)
            if prev is not None and prev.counter == counter:
                return replace(prev, repeated=True)
            changed_s = now_s
            fault: Status | None = None
            detail = ""
            if not valid:
                fault, detail = Status.NO_TEMPERATURE, f"sensor {sensor} ({role}) reports invalid"
            elif not cfg.plausible_C[0] <= temp_C <= cfg.plausible_C[1]:
                fault = Status.IMPLAUSIBLE_TEMPERATURE
                detail = (
                    f"sensor {sensor} ({role}) {temp_C:.3f} °C outside plausible "
                    f"{cfg.plausible_C[0]}..{cfg.plausible_C[1]} °C"
                )
            elif (
                prev is not None
                and prev.valid
                and now_s > prev.received_s
                and abs(temp_C - prev.temp_C) / (now_s - prev.received_s) > cfg.max_rate_C_per_s
            ):
                rate = abs(temp_C - prev.temp_C) / (now_s - prev.received_s)
                fault = Status.IMPLAUSIBLE_TEMPERATURE
                detail = (
                    f"sensor {sensor} ({role}) jumped {prev.temp_C:.3f} → {temp_C:.3f} °C "
                    f"({rate:.2f} °C/s > {cfg.max_rate_C_per_s} °C/s)"
                )
            elif not cfg.valid_range_C[0] <= temp_C <= cfg.valid_range_C[1]:
                fault = Status.IMPLAUSIBLE_TEMPERATURE
                detail = (
                    f"sensor {sensor} ({role}) {temp_C:.3f} °C outside the compensated range "
                    f"{cfg.valid_range_C[0]}..{cfg.valid_range_C[1]} °C"
                )
            state = SensorState(
                sensor, role, temp_C, counter, valid, now_s, changed_s, fault, detail
            )
            self._sensors[sensor] = state
            self._version += 1
            if fault is None:
                for (lag_role, _tau), lag in self._lags.items():
                    if lag_role == role:
                        lag.update(now_s, temp_C)
            return state

    def inputs(self, required: tuple[str, ...], now_s: float) -> TemperatureVerdict:
        """Usable temperatures and the first fault among ``required`` roles at ``now_s``.

        The answer to the common case (every role usable) is reused until a new sample
        arrives or the oldest of them would turn stale: do not mutate its ``temps_C``."""
        c = self._ok_cache
        if c is not None and c[0] == self._version and now_s <= c[2] and c[1] == required:
            return c[3]
        with self._lock:
            version = self._version
            verdict = self._check(required, now_s)
            if verdict.status is None:
                changed = [self._sensors[self._by_role[r]].changed_s for r in required]
                until = min(changed, default=float("inf")) + self.config.stale_s
                self._ok_cache = (version, tuple(required), until, verdict)
        return verdict

    def _check(self, required: tuple[str, ...], now_s: float) -> TemperatureVerdict:
        """:meth:`inputs` without reuse (the caller holds the lock)."""
        temps: dict[str, float] = {}
        status: Status | None = None
        detail = ""
        stale_s = self.config.stale_s
        for role in required:
            sid = self._by_role.get(role)
            state = self._sensors.get(sid) if sid is not None else None
            if state is None:
                why: Status | None = Status.NO_TEMPERATURE
                text = f"no sample for {role}" + ("" if sid is not None else " (no sensor)")
            elif state.fault is not None:
                why, text = state.fault, state.detail
            elif now_s - state.changed_s > stale_s:
                why = Status.STALE_TEMPERATURE
                text = (
                    f"sensor {state.sensor} ({role}) unchanged for "
                    f"{now_s - state.changed_s:.1f} s > {stale_s} s"
                )
            else:
                temps[role] = state.temp_C
                continue
            if status is None:
                status, detail = why, text
        return TemperatureVerdict(temps, status, detail)

    def effective(
        self, temps_C: Mapping[str, float], filters: Sequence[SignalFilter], now_s: float
    ) -> dict[str, float]:
        """Temperatures the grid expects after its signal filters (``grid.signal_filters``).

        For a ``first_order_lag`` filter (the thermal-lag effect found by model discovery) each
        listed role becomes ``T + w·(lag_τ(T) − T)``; the lag is fed with every usable sample of
        that role from the first time it is asked for (starting in equilibrium) and held between
        samples. Roles without a filter pass through unchanged.
        """
        out = dict(temps_C)
        for spec in filters:
            if spec.kind != FIRST_ORDER_LAG:
                continue
            tau = spec.time_constant_s
            for role in spec.signals:
                if role not in temps_C:
                    continue
                with self._lock:
                    lag = self._lags.get((role, tau))
                    if lag is None:
                        lag = self._lags[(role, tau)] = FirstOrderLag(tau)
                        sid = self._by_role.get(role)
                        state = self._sensors.get(sid) if sid is not None else None
                        t0 = state.received_s if state is not None else now_s
                        lag.update(t0, float(temps_C[role]))
                    lagged = lag.value_at(now_s)
                out[role] = spec.effective(temps_C[role], lagged)
        return out

    def snapshot(self) -> list[SensorState]:
        """All sensor states, by sensor id."""
        with self._lock:
            return [self._sensors[k] for k in sorted(self._sensors)]
