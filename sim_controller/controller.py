"""Simulated CMM controller over CAN: a real peer on a real python-can bus.

It sends temperature samples and raw readings (probing direction, then X, Y, Z axis frames)
and collects the daemon's answers (three corrected axis frames + a correction-status frame)
in a receive thread. :meth:`CanController.exchange` sends one reading and waits for its
answer (lock-step); :meth:`CanController.stream` sends at a fixed rate with a bounded number
of readings in flight. Latency is measured at the controller: from just after the last raw
frame was sent to the arrival of the status frame, µs (``time.perf_counter``).

With ``fd=True`` it speaks the CAN FD pair instead (docs/can.md): one RAW_XYZ frame a reading,
one CORRECTED_XYZ frame an answer (U always in it); the bus must be opened with ``fd=True``.

On ``udp_multicast`` a bus receives its own frames: the controller ignores its own TX ids.
It is a context manager with ``stop(timeout_s)``; receive errors are counted and kept in
``errors``, never silent.
"""

from __future__ import annotations

import threading
import time
from collections.abc import Iterable
from dataclasses import dataclass

import can

from cmm_comp.protocol import (
    CanIds,
    CorrectedAxis,
    CorrectedReading,
    CorrectionStatus,
    CorrectionUncertainty,
    Heartbeat,
    ProbeDirection,
    RawAxis,
    TemperatureSample,
    Triplet,
    TripletAssembler,
    decode_message,
    encode_message,
)
from cmm_comp.protocol import RawReading as RawReadingFrame
from cmm_comp.protocol.codes import NM_PER_MM, Axis, Direction, Status


@dataclass(frozen=True, slots=True)
class RawReading:
    """A reading to send: indicated position (mm), travel directions, probing direction."""

    seq: int
    indicated_mm: tuple[float, float, float]
    travel_dir: tuple[int, int, int] = (0, 0, 0)
    probe_dir: tuple[float, float, float] | None = None
    valid: tuple[bool, bool, bool] = (True, True, True)


@dataclass(frozen=True, slots=True)
class AnswerRecord:
    """The daemon's answer to one reading, as the controller saw it."""

    seq: int
    status: str
    """docs/formats.md status label, or ``"timeout"`` when no answer came."""
    corrected_mm: tuple[float, float, float] | None
    latency_us: float
    daemon_latency_us: int = 0
    correction_um: float = 0.0
    applied: int = 0
    uncertainty_um: tuple[float, float, float] | None = None
    """U (k = 2) of X, Y, Z as the CORRECTION_UNCERTAINTY frame stated it (µm; NaN unknown,
    inf saturated); None when the daemon sent no such frame."""


class CanController(can.Listener):
    """Controller side of the CAN message set on ``bus`` (which it does not own).

    :param ids: the node's CAN ids.
    :param answer_timeout_s: how long :meth:`exchange` waits for an answer, s.
    :param fd: send each reading as one CAN FD RAW_XYZ frame (the answer comes as one
        CORRECTED_XYZ frame) instead of the classic RAW_X/Y/Z frames.
    """

    def __init__(
        self,
        bus: can.BusABC,
        ids: CanIds | None = None,
        answer_timeout_s: float = 1.0,
        fd: bool = False,
    ):
        self.bus = bus
        self.fd = fd
        self.ids = ids or CanIds()
        self.answer_timeout_s = answer_timeout_s
        self._own = self.ids.controller_tx_ids()
        self._assembler: TripletAssembler[CorrectedAxis] = TripletAssembler(window=64)
        self._triplets: dict[int, Triplet[CorrectedAxis]] = {}
        self._uncertainty: dict[int, tuple[float, float, float]] = {}
        self._answers: dict[int, AnswerRecord] = {}
        self._sent_at: dict[int, float] = {}
        self._cond = threading.Condition()
        self._counters: dict[int, int] = {}
        self.heartbeat: Heartbeat | None = None
        self.heartbeats = 0
        self.errors: list[BaseException] = []
        self.ignored = 0
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, name="sim-controller-rx", daemon=True)

    # ------------------------------------------------------------------ lifecycle
    def start(self) -> CanController:
        """Start the receive thread."""
        self._thread.start()
        return self

    def stop(self, timeout_s: float = 2.0) -> bool:  # type: ignore[override]
        """Stop the receive thread (the bus stays open); True if it ended in ``timeout_s``."""
        self._stop.set()
        if self._thread.is_alive():
            self._thread.join(timeout_s)
        return not self._thread.is_alive()

    def __enter__(self) -> CanController:
        return self.start()

    def __exit__(self, *exc: object) -> None:
        self.stop()

    def _run(self) -> None:
        while not self._stop.is_set():
            try:
                msg = self.bus.recv(0.01)
            except Exception as exc:
                self.on_error(exc)
                self._stop.wait(0.05)
                continue
            if msg is not None:
                try:
                    self.on_message_received(msg)
                except Exception as exc:
                    self.on_error(exc)

    def on_error(self, exc: Exception) -> None:
        """Keep every receive error (tests and the demo check ``errors``)."""
        self.errors.append(exc)

    # ------------------------------------------------------------------ receive
    def on_message_received(self, msg: can.Message) -> None:
        """Collect answer frames and heartbeats; ignore our own frames and foreign ids."""
        t = time.perf_counter()
        if msg.arbitration_id in self._own and not msg.is_extended_id:
            self.ignored += 1
            return
        frame = decode_message(msg, self.ids)
        if isinstance(frame, CorrectedAxis):
            for ev in self._assembler.feed(frame):
                if isinstance(ev, Triplet):
                    self._triplets[ev.seq] = ev
        elif isinstance(frame, CorrectionUncertainty):
            self._uncertainty[frame.seq] = frame.u_um
            while len(self._uncertainty) > 64:  # never-completed seqs do not pile up
                del self._uncertainty[next(iter(self._uncertainty))]
        elif isinstance(frame, CorrectionStatus):
            self._complete(frame, t)
        elif isinstance(frame, CorrectedReading):
            self._complete_fd(frame, t)
        elif isinstance(frame, Heartbeat):
            self.heartbeat = frame
            self.heartbeats += 1
        else:
            self.ignored += 1

    def _complete(self, st: CorrectionStatus, t: float) -> None:
        trip = self._triplets.pop(st.seq, None)
        pos = None
        if trip is not None:
            pos = (
                trip.x.position_nm / NM_PER_MM,
                trip.y.position_nm / NM_PER_MM,
                trip.z.position_nm / NM_PER_MM,
            )
        with self._cond:
            sent = self._sent_at.pop(st.seq, t)
            self._answers[st.seq] = AnswerRecord(
                st.seq,
                Status(st.status).label,
                pos,
                (t - sent) * 1e6,
                st.latency_us,
                st.correction_um,
                int(st.applied),
                self._uncertainty.pop(st.seq, None),
            )
            self._cond.notify_all()

    def _complete_fd(self, a: CorrectedReading, t: float) -> None:
        x, y, z = a.position_nm
        with self._cond:
            sent = self._sent_at.pop(a.seq, t)
            self._answers[a.seq] = AnswerRecord(
                a.seq,
                Status(a.status).label,
                (x / NM_PER_MM, y / NM_PER_MM, z / NM_PER_MM),
                (t - sent) * 1e6,
                a.latency_us,
                a.correction_um,
                int(a.applied),
                a.u_um,
            )
            self._cond.notify_all()

    # ------------------------------------------------------------------ send
    def send_temperatures(self, temps_by_sensor: dict[int, float], valid: bool = True) -> None:
        """Send one sample per sensor (°C), each with its counter incremented."""
        for sensor, temp_C in temps_by_sensor.items():
            counter = (self._counters.get(sensor, 0) + 1) & 0xFFFF
            self._counters[sensor] = counter
            sample = TemperatureSample.from_celsius(sensor, temp_C, counter, valid)
            self.bus.send(encode_message(sample, self.ids), timeout=1.0)

    def send_reading(self, r: RawReading) -> None:
        """Send the probing direction (if any), then X, Y, Z; record the send time."""
        msgs = []
        if r.probe_dir is not None:
            pd = ProbeDirection.from_unit_vector(r.seq, r.probe_dir)
            msgs.append(encode_message(pd, self.ids))
        if self.fd:
            whole = RawReadingFrame(
                r.seq,
                (
                    round(r.indicated_mm[0] * NM_PER_MM),
                    round(r.indicated_mm[1] * NM_PER_MM),
                    round(r.indicated_mm[2] * NM_PER_MM),
                ),
                tuple(Direction.from_sign(s) for s in r.travel_dir),  # type: ignore[arg-type]
                r.valid,
            )
            msgs.append(encode_message(whole, self.ids))
        else:
            for axis, pos, sign, ok in zip(
                Axis, r.indicated_mm, r.travel_dir, r.valid, strict=True
            ):
                frame = RawAxis(axis, r.seq, round(pos * NM_PER_MM), Direction.from_sign(sign), ok)
                msgs.append(encode_message(frame, self.ids))
        with self._cond:
            self._answers.pop(r.seq, None)
        for msg in msgs:
            self.bus.send(msg, timeout=1.0)
        with self._cond:
            self._sent_at[r.seq] = time.perf_counter()

    def wait_answer(self, seq: int, timeout_s: float | None = None) -> AnswerRecord:
        """The answer to ``seq`` (status ``"timeout"`` if none arrives in time)."""
        deadline = time.monotonic() + (self.answer_timeout_s if timeout_s is None else timeout_s)
        with self._cond:
            while seq not in self._answers:
                left = deadline - time.monotonic()
                if left <= 0:
                    self._sent_at.pop(seq, None)
                    return AnswerRecord(seq, "timeout", None, float("nan"))
                self._cond.wait(left)
            return self._answers.pop(seq)

    def exchange(self, r: RawReading, timeout_s: float | None = None) -> AnswerRecord:
        """Send ``r`` and wait for its answer."""
        self.send_reading(r)
        return self.wait_answer(r.seq, timeout_s)

    def stream(
        self, readings: Iterable[RawReading], rate_hz: float, in_flight: int = 16
    ) -> list[AnswerRecord]:
        """Send at ``rate_hz`` (readings/s; 0 = as fast as answers allow) with at most
        ``in_flight`` unanswered readings; return the answers in send order."""
        period = 1.0 / rate_hz if rate_hz > 0 else 0.0
        order: list[int] = []
        out: list[AnswerRecord] = []
        next_t = time.perf_counter()
        pending: list[int] = []
        for r in readings:
            while len(pending) >= in_flight:
                out.append(self.wait_answer(pending.pop(0)))
            if period:
                # sleep until the slot, never spin: a simulated controller sharing a process
                # (and 2 cores) with the daemon must not keep a core busy while it waits
                delay = next_t - time.perf_counter()
                if delay > 0:
                    time.sleep(delay)
                next_t += period
            self.send_reading(r)
            order.append(r.seq)
            pending.append(r.seq)
        for seq in pending:
            out.append(self.wait_answer(seq))
        return out
