"""Correct one reading: transport-independent core shared by the CAN and Modbus endpoints.

:meth:`CorrectionEngine.correct` turns a :class:`Reading` (indicated position in nm, travel
directions, valid flags, optional probing direction) into an :class:`Answer` with the status
that says exactly what was applied. Whenever the status is not ``ok``,
``not_thermally_corrected`` or ``missing_direction``, the answer carries the indicated position
unchanged: never a silently wrong coordinate. It never raises: an unexpected exception becomes
``internal_error`` (counted and logged).

When the grid carries an uncertainty (``grid build --uncertainty``), every answer computed
with it carries U (k = 2 per component, µm; docs/uncertainty.md): a value only when the final
status is ``ok`` (after the limits), NaN (unknown) otherwise, and ``Applied.UNCERTAINTY`` says
which. The endpoints put it on the wire (CAN ``CORRECTION_UNCERTAINTY`` when configured,
Modbus 324..326) and in the log.

The endpoints reply first and then call :meth:`CorrectionEngine.record` (metrics, MCAP, events)
so logging never adds to the reply latency.
"""

from __future__ import annotations

import math
import time
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from cmm_comp.compensation.thermal import STRUCTURE_ROLES, WORKPIECE
from cmm_comp.protocol.codes import Applied, Status, mm3_from_nm, nm3_from_mm

from .config import DaemonConfig
from .events import EventLog
from .grid_slot import GridSlot, LoadedGrid
from .metrics import Metrics
from .sessionlog.logger import SessionLogger
from .temperatures import TemperatureTable

GRID_STATUS = {
    "ok": Status.OK,
    "outside_volume": Status.OUTSIDE_VOLUME,
    "clamped_outside_volume": Status.OUTSIDE_VOLUME,
    "no_temperature": Status.NOT_THERMALLY_CORRECTED,
    "missing_input": Status.MISSING_DIRECTION,
    "invalid_input": Status.INVALID_READING,
}
_SCALE_ROLES = frozenset(STRUCTURE_ROLES)
_DIR_KEYS = ("dir_x", "dir_y", "dir_z")
BATCH_MIN = 8
"""Fewer readings than this are corrected one at a time (a vectorised call costs more)."""
BATCH_MAX = 128
"""Readings per vectorised grid call (below the grid's parallel threshold)."""
_PROBE_KEYS = ("nx", "ny", "nz")
_INF = math.inf
U_UNKNOWN: tuple[float, float, float] = (math.nan, math.nan, math.nan)
"""The uncertainty of an answer whose grid carries U but whose status is not ``ok``."""


@dataclass(frozen=True, slots=True)
class Reading:
    """One complete raw reading, as received from any transport."""

    seq: int
    position_nm: tuple[int, int, int]
    """Indicated X, Y, Z, nm."""
    directions: tuple[int, int, int] = (0, 0, 0)
    """Travel direction signs (+1, −1, 0 unknown) of X, Y, Z."""
    valid: tuple[bool, bool, bool] = (True, True, True)
    probe: tuple[float, float, float] | None = None
    """Probing direction unit vector, or None."""
    received_s: float = 0.0
    """``time.perf_counter()`` when the last input frame of the reading arrived, s."""
    source: str = "can"

    @property
    def position_mm(self) -> tuple[float, float, float]:
        """Indicated X, Y, Z, mm."""
        return mm3_from_nm(self.position_nm)


@dataclass(frozen=True, slots=True)
class Answer:
    """The daemon's answer to one reading."""

    seq: int
    status: Status
    position_nm: tuple[int, int, int]
    """Corrected X, Y, Z, nm (the indicated ones unless the geometry was applied)."""
    applied: Applied
    correction_um: tuple[float, float, float]
    """Applied correction vector (corrected − indicated), µm."""
    detail: str = ""
    uncertainty_um: tuple[float, float, float] | None = None
    """Expanded uncertainty U (k = 2) of the corrected X, Y, Z, µm: finite values ≥ 0 when
    the status is ``ok`` and the grid carries U; :data:`U_UNKNOWN` (NaN) for any other answer
    made with such a grid; None when no grid carrying U was used (no grid, or one without U)."""

    @property
    def uncertainty_known(self) -> bool:
        """True when :attr:`uncertainty_um` holds values."""
        u = self.uncertainty_um
        return u is not None and u[0] == u[0]

    @property
    def correction_norm_um(self) -> float:
        """Length of the applied correction, µm."""
        x, y, z = self.correction_um
        return math.sqrt(x * x + y * y + z * z)


class CorrectionEngine:
    """Grid + temperatures + limits → answers. Thread-safe (readers share no mutable state
    except the counters, which take their own lock)."""

    def __init__(
        self,
        config: DaemonConfig,
        grids: GridSlot,
        temperatures: TemperatureTable,
        metrics: Metrics,
        events: EventLog,
        logger: SessionLogger | None = None,
    ) -> None:
        self.config = config
        self.grids = grids
        self.temperatures = temperatures
        self.metrics = metrics
        self.events = events
        self.logger = logger
        stylus = config.grid.stylus_mm
        self._stylus_t: tuple[float, float, float] | None = (
            None if stylus is None else (float(stylus[0]), float(stylus[1]), float(stylus[2]))
        )
        """The configured stylus, mm; None: each grid's own probe offset (:meth:`stylus_mm`)."""
        self._applied_cache: tuple[LoadedGrid | None, dict[tuple[bool, bool, bool, bool], Applied]]
        self._applied_cache = (None, {})
        """The grid the cache is for (held: its id can never be another grid's) and the cache;
        one attribute, swapped whole, so two endpoint threads never mix two grids' flags."""
        self._warn_um = config.limits.warn_um
        self._error_um = config.limits.error_um
        self._geometry_only = config.temperatures.on_fault == "geometry_only"

    # ------------------------------------------------------------------ hot path
    def _raw(
        self,
        r: Reading,
        status: Status,
        detail: str = "",
        u: tuple[float, float, float] | None = None,
    ) -> Answer:
        """The indicated position with ``status`` (``u``: :data:`U_UNKNOWN` when the grid
        consulted carries U, else None)."""
        return Answer(r.seq, status, r.position_nm, Applied.NONE, (0.0, 0.0, 0.0), detail, u)

    def correct(self, reading: Reading, now_s: float | None = None) -> Answer:
        """Answer ``reading``; ``now_s`` is the monotonic time for staleness checks, s."""
        try:
            return self._correct(reading, time.monotonic() if now_s is None else now_s)
        except Exception as exc:  # never let one reading kill the daemon
            self.metrics.fault("internal_error")
            self.events.emit("internal_error", "error", seq=reading.seq, error=repr(exc))
            return self._raw(reading, Status.INTERNAL_ERROR, repr(exc))

    def _correct(self, r: Reading, now_s: float) -> Answer:
        loaded = self.grids.current
        if loaded is None:
            return self._raw(r, Status.NO_GRID, "no grid loaded")
        unknown = U_UNKNOWN if loaded.has_uncertainty else None
        if not all(r.valid):
            bad = "".join(a for a, v in zip("XYZ", r.valid, strict=True) if not v)
            msg = f"controller flagged {bad} invalid"
            return self._raw(r, Status.INVALID_READING, msg, unknown)
        verdict = self.temperatures.inputs(self.required_roles(loaded), now_s)
        temps: dict[str, float] | None = verdict.temps_C
        if verdict.status is not None:
            if not self._geometry_only:
                return self._raw(r, verdict.status, verdict.detail, unknown)
            temps = None  # geometry only: the grid flags the missing thermal terms
        if temps and (filters := loaded.grid.signal_filters):
            temps = self.temperatures.effective(temps, filters, now_s)
        inputs: dict[str, float] = {}
        for key, sign in zip(_DIR_KEYS, r.directions, strict=True):
            if sign:
                inputs[key] = float(sign)
        if r.probe is not None:
            inputs.update(zip(_PROBE_KEYS, r.probe, strict=True))
        p = mm3_from_nm(r.position_nm)
        grid = loaded.grid
        stylus = self._stylus_t if self._stylus_t is not None else loaded.probe_offset_mm
        u: tuple[float, float, float] | None = None
        if unknown is not None:  # the grid carries U: correction and U in one call
            c, label, u = grid.correct_point_with_uncertainty(p, stylus, temps, inputs or None)
        else:
            c, label = grid.correct_point(p, stylus, temps, inputs or None)
        has_dir = r.directions != (0, 0, 0)
        return self._finish(r, p, c, label, loaded, temps, has_dir, r.probe is not None, u)

    def _finish(
        self,
        r: Reading,
        p: tuple[float, float, float],
        c: tuple[float, float, float],
        label: str,
        loaded: LoadedGrid,
        temps: dict[str, float] | None,
        has_dir: bool,
        has_probe: bool,
        u: tuple[float, float, float] | None = None,
    ) -> Answer:
        """The answer from the grid's corrected position ``c`` (mm), status ``label`` and U
        ``u`` (µm; None: the grid carries no U) of indicated ``p`` (mm): limits, applied
        terms, rounding to nm; U is kept only for a final status ``ok`` and finite values."""
        status = GRID_STATUS.get(label, Status.INTERNAL_ERROR)
        unknown = None if u is None else U_UNKNOWN
        if not status.geometric_correction_applied:
            return self._raw(r, status, f"grid status {label}", unknown)
        if not (math.isfinite(c[0]) and math.isfinite(c[1]) and math.isfinite(c[2])):
            return self._raw(r, Status.INTERNAL_ERROR, "non-finite correction", unknown)
        d_um = ((c[0] - p[0]) * 1000.0, (c[1] - p[1]) * 1000.0, (c[2] - p[2]) * 1000.0)
        norm = math.sqrt(d_um[0] ** 2 + d_um[1] ** 2 + d_um[2] ** 2)
        if norm > self._error_um:
            detail = f"|correction| {norm:.1f} µm > error limit {self._error_um} µm"
            return self._raw(r, Status.CORRECTION_LIMIT, detail, unknown)
        detail = ""
        if norm > self._warn_um:
            detail = f"|correction| {norm:.1f} µm > warning limit {self._warn_um} µm"
        if u is not None and not (
            status is Status.OK and 0.0 <= u[0] < _INF and 0.0 <= u[1] < _INF and 0.0 <= u[2] < _INF
        ):
            u = U_UNKNOWN  # a term left out (its uncertainty too), or no usable value
        known = u is not None and u is not U_UNKNOWN
        applied = self._applied(loaded, temps, has_dir, has_probe, status, known)
        pos = nm3_from_mm(c)
        return Answer(r.seq, status, pos, applied, d_um, detail, u)

    def correct_many(self, readings: Sequence[Reading], now_s: float | None = None) -> list[Answer]:
        """Answers to ``readings``, equal bit for bit to :meth:`correct` of each at ``now_s``
        (monotonic s): a batch of at least :data:`BATCH_MIN` plain readings (valid, no probing
        direction) under usable temperatures is corrected in one vectorised grid call, the
        rest one at a time. Never raises."""
        now = time.monotonic() if now_s is None else now_s
        if len(readings) < BATCH_MIN:
            return [self.correct(r, now) for r in readings]
        try:
            return self._correct_batch(readings, now)
        except Exception as exc:  # the batch failed as a whole: each reading on its own
            self.metrics.fault("batch_fallback")
            self.events.emit("batch_fallback", "error", error=repr(exc))
            return [self.correct(r, now) for r in readings]

    def _correct_batch(self, readings: Sequence[Reading], now_s: float) -> list[Answer]:
        loaded = self.grids.current
        if loaded is None:
            return [self.correct(r, now_s) for r in readings]
        verdict = self.temperatures.inputs(self.required_roles(loaded), now_s)
        if verdict.status is not None:  # faults, geometry-only: the single path says why
            return [self.correct(r, now_s) for r in readings]
        temps: dict[str, float] = verdict.temps_C
        if temps and (filters := loaded.grid.signal_filters):
            temps = self.temperatures.effective(temps, filters, now_s)
        answers: list[Answer | None] = [None] * len(readings)
        with_u = loaded.has_uncertainty
        stylus = np.array(self.stylus_mm(loaded))
        plain = [i for i, r in enumerate(readings) if r.probe is None and all(r.valid)]
        for start in range(0, len(plain), BATCH_MAX):
            idx = plain[start : start + BATCH_MAX]
            rs = [readings[i] for i in idx]
            pts = [mm3_from_nm(r.position_nm) for r in rs]
            inputs: dict[str, np.ndarray] = {}
            for k, key in enumerate(_DIR_KEYS):
                signs = [r.directions[k] for r in rs]
                if any(signs):  # 0 (unknown) is an absent input, as in correct(): NaN
                    inputs[key] = np.array([float(v) if v else math.nan for v in signs])
            u_rows: list[list[float]] | None = None
            if with_u:
                out, st, u_arr = loaded.grid.correct_with_uncertainty(
                    np.array(pts), stylus, temps, inputs or None
                )
                u_rows = u_arr.tolist()
            else:
                out, st = loaded.grid.correct(
                    np.array(pts), stylus, temps, inputs or None, outside=None
                )
            rows = out.tolist()
            labels = st.tolist()
            for j, i in enumerate(idx):
                r = rs[j]
                c = (rows[j][0], rows[j][1], rows[j][2])
                u = None if u_rows is None else (u_rows[j][0], u_rows[j][1], u_rows[j][2])
                has_dir = r.directions != (0, 0, 0)
                answers[i] = self._finish(r, pts[j], c, labels[j], loaded, temps, has_dir, False, u)
        return [
            a if a is not None else self.correct(readings[i], now_s) for i, a in enumerate(answers)
        ]

    def stylus_mm(self, loaded: LoadedGrid | None) -> tuple[float, float, float]:
        """The stylus offset readings are corrected for with ``loaded``, mm: ``grid.stylus_mm``
        when configured, else the grid's probe offset (no grid: 0, 0, 0)."""
        if self._stylus_t is not None:
            return self._stylus_t
        return loaded.probe_offset_mm if loaded is not None else (0.0, 0.0, 0.0)

    def required_roles(self, loaded: LoadedGrid) -> tuple[str, ...]:
        req = self.config.temperatures.required
        return loaded.temperature_roles if req is None else tuple(req)

    def _applied(
        self,
        loaded: LoadedGrid,
        temps: dict[str, float] | None,
        has_dir: bool,
        has_probe: bool,
        st: Status,
        u_known: bool = False,
    ) -> Applied:
        """Terms that went into the answer, and whether its U is known (cached per input
        pattern for the current grid; a new grid starts an empty cache: keyed by ``id``, a
        reloaded grid could take a freed grid's id and its flags)."""
        grid, cache = self._applied_cache
        if grid is not loaded:
            cache = {}
            self._applied_cache = (loaded, cache)
        key = (
            bool(temps),
            has_dir and st != Status.MISSING_DIRECTION,
            has_probe,
            u_known,
        )
        cached = cache.get(key)
        if cached is not None:
            return cached
        applied = Applied.UNCERTAINTY | Applied.GEOMETRY if u_known else Applied.GEOMETRY
        if temps:
            roles = set(loaded.temperature_roles) & set(temps)
            if roles & _SCALE_ROLES:
                applied |= Applied.SCALE_THERMAL
            if WORKPIECE in roles:
                applied |= Applied.WORKPIECE_THERMAL
        needed = set(loaded.input_signals)
        if key[1] and needed & set(_DIR_KEYS):
            applied |= Applied.REVERSAL
        if has_probe and needed & set(_PROBE_KEYS):
            applied |= Applied.PROBE_DIRECTION
        cache[key] = applied  # at most 16 keys (four flags)
        return applied

    # ------------------------------------------------------------------ after the reply
    def record(self, reading: Reading, answer: Answer, latency_us: float) -> None:
        """Count, log to MCAP and report one answered reading (call after replying)."""
        self.count_many((answer,), (latency_us,))
        self.report_many(((reading, answer, latency_us),))

    def count_many(self, answers: Sequence[Answer], latencies_us: Sequence[float]) -> None:
        """The counters of the answers (with their latencies, µs), under one lock (cheap:
        right after replying, so they are never behind what the peer has seen)."""
        self.metrics.readings_answered(
            [
                (a.status.label, lat, bool(a.detail) and a.status == Status.OK)
                for a, lat in zip(answers, latencies_us, strict=True)
            ]
        )

    def report_many(self, batch: Sequence[tuple[Reading, Answer, float]]) -> None:
        """Events and MCAP records (compact: the writer builds the JSON,
        ``protocol.session_topics.RECORD_FIELDS``) of each ``(reading, answer, latency_us)``, after
        the reply (may wait until the line is quiet): the events one by one, the records of all
        with one ``log_many`` per topic (one log time)."""
        for _, answer, _ in batch:
            if answer.detail or answer.status != Status.OK:
                self._report_event(answer)
        log = self.logger
        if log is None or not batch:
            return
        log.log_many("/cmm/raw", [self._raw_record(r) for r, _, _ in batch])
        log.log_many("/cmm/corrected", [self._corrected_record(r, a, lat) for r, a, lat in batch])

    def _report_event(self, answer: Answer) -> None:
        label = answer.status.label
        if answer.detail and answer.status == Status.OK:
            self.events.emit("correction_warning", "warning", seq=answer.seq, detail=answer.detail)
        elif answer.status != Status.OK:
            self.events.emit(
                f"answer_{label}", "warning", seq=answer.seq, status=label, detail=answer.detail
            )

    def _raw_record(self, reading: Reading) -> tuple[object, ...]:
        """The compact ``/cmm/raw`` record (``protocol.session_topics.raw_fields``)."""
        return (
            reading.seq,
            *reading.position_mm,
            reading.directions,
            reading.valid,
            reading.source,
            # (a reload between the answer and this record could change a grid-derived stylus:
            # only when grid.stylus_mm is unset and the new grid's probe offset differs)
            self.stylus_mm(self.grids.current),
            reading.probe,
        )

    def _corrected_record(
        self, reading: Reading, answer: Answer, latency_us: float
    ) -> tuple[object, ...]:
        """The compact ``/cmm/corrected`` record (``protocol.session_topics.corrected_fields``): U
        appended when the answer's grid carries U (None = unknown: logged as nulls)."""
        rec = (
            answer.seq,
            *answer.position_nm,
            answer.status.label,
            answer.correction_um,
            latency_us,
            int(answer.applied),
            reading.source,
            answer.detail,
        )
        u = answer.uncertainty_um
        if u is None:
            return rec
        return (*rec, u if u[0] == u[0] else None)

    def temperature(
        self, sensor: int, temp_C: float, counter: int, valid: bool, source: str
    ) -> None:
        """Store one temperature sample (any transport) and log it. A frame repeating the
        previous counter of its sensor is not a sample: ignored, counted as
        ``temperature_repeats`` (docs/can.md)."""
        state = self.temperatures.update(sensor, temp_C, counter, valid, time.monotonic())
        if state is None:
            self.metrics.count("temperature_samples")
            self.metrics.fault("unknown_sensor")
            self.events.emit("unknown_sensor", "warning", sensor=sensor, source=source)
            return
        if state.repeated:
            self.metrics.count("temperature_repeats")
            return
        self.metrics.count("temperature_samples")
        if state.fault is not None:
            self.metrics.fault(f"temperature_{state.fault.label}")
            self.events.emit("temperature_fault", "warning", sensor=sensor, detail=state.detail)
        if self.logger is not None:
            self.logger.log(
                "/cmm/temperature",
                {
                    "sensor": str(sensor),
                    "role": state.role,
                    "temp_C": temp_C,
                    "counter": counter,
                    "valid": valid,
                    "fault": state.fault.label if state.fault is not None else "",
                    "source": source,
                },
            )
