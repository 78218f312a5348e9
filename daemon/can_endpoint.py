"""The daemon's CAN side: receive raw axis frames and temperatures, answer each reading at once.

One supervised thread owns the bus: it assembles X/Y/Z triplets
(:class:`protocol.TripletAssembler`); a received frame that completes a reading gets it
answered at once, then every frame already waiting (up to ``_DRAIN_MAX``) is taken and the
readings they complete are corrected together
(:meth:`daemon.engine.CorrectionEngine.correct_many`: one vectorised grid call for a batch,
the same answers bit for bit as one at a time). The answers' frames (three corrected axes,
the uncertainty frame with ``[can] send_uncertainty``, the correction status, per reading; or,
for a reading that came as one CAN FD RAW_XYZ frame, one CORRECTED_XYZ frame) go
out in one batch (:func:`daemon.can_send.send_batch`), then are counted. A temperature frame or an
``incomplete_reading`` answer first answers the readings completed before it, so the order of
the wire is kept.
Everything else about an answered reading (events, MCAP records of the reading, the answer
and every frame) waits until the bus has been quiet for ``_IDLE_S`` (or ``_DEFER_MAX``
readings pile up), then the MCAP writer is kicked: the logging work lands in the gap between
readings, never between a reading and its answer (nor on the peer still taking it in). The same
thread sends the heartbeat (every ``heartbeat_s`` and on a state change), drops readings that
stopped arriving (``triplet_timeout_s``) with an ``incomplete_reading`` status, and on a bus
error closes the bus and reopens it with back-off, reporting the condition to the state board.
No exception ends the thread silently: each reaches :meth:`CanEndpoint.on_error` (counted,
logged, reflected in the state). The message handler is a ``can.Listener`` so it could also be
driven by a ``can.Notifier``; the own loop is used because reconnecting replaces the bus.
"""

from __future__ import annotations

import threading
import time
from collections import OrderedDict
from collections.abc import Callable
from typing import Any

import can

from cmm_comp.protocol import (
    BadLength,
    BadValue,
    CanIds,
    CorrectedAxis,
    CorrectedReading,
    CorrectionStatus,
    CorrectionUncertainty,
    Duplicate,
    Heartbeat,
    Incomplete,
    NotData,
    OutOfOrder,
    ProbeDirection,
    RawAxis,
    RawReading,
    Superseded,
    TemperatureSample,
    Triplet,
    TripletAssembler,
    UnknownId,
    decode_message,
    encode_corrected_axes,
    encode_corrected_reading,
    encode_correction_status,
    encode_correction_uncertainty,
    encode_message,
)
from cmm_comp.protocol.can_codec import RawAxisDecoder
from cmm_comp.protocol.can_ids import MessageKind
from cmm_comp.protocol.codes import Axis, DaemonState, Status

from .can_send import recv_pending, send_batch
from .config import CanSection
from .engine import Answer, CorrectionEngine, Reading
from .events import EventLog
from .metrics import Metrics
from .osthread import name_os_thread
from .sessionlog.logger import SessionLogger
from .state import StateBoard

BusFactory = Callable[[CanSection, CanIds], can.BusABC]
_RECV_POLL_S = 0.01
_DRAIN_MAX = 512
"""Frames taken per wake-up at most before the completed readings are answered."""
_IDLE_S = 0.0002
"""Bookkeeping of answered readings waits until no frame came for this long, s."""
_DEFER_MAX = 32
"""…or until this many answered readings wait for it (a bus that never goes quiet)."""
_HOUSEKEEPING_S = 0.001
"""While frames keep coming, heartbeat/timeout checks run at most this often, s."""
_MAX_BACKOFF_S = 10.0
_PROBE_MEMORY = 16


def open_bus(cfg: CanSection, ids: CanIds) -> can.BusABC:
    """Open the configured python-can bus, filtered to this node's block of ids."""
    kwargs: dict[str, Any] = dict(cfg.options)
    if cfg.bitrate:
        kwargs["bitrate"] = cfg.bitrate
    return can.Bus(
        interface=cfg.interface,
        channel=cfg.channel,
        can_filters=ids.can_filters(),
        fd=cfg.fd,
        **kwargs,
    )


def can_open_error(cfg: CanSection, exc: BaseException) -> str:
    """One line for a bus that did not open: interface, channel, the error and what to try."""
    return (
        f"cannot open CAN interface {cfg.interface!r} channel {str(cfg.channel)!r}: {exc!r}; "
        "no CAN hardware here? try --can-interface virtual (a bus inside this process) or "
        "--can-interface udp_multicast (a bus between processes on this host), docs/daemon.md"
    )


def frame_record(msg: can.Message, channel: str, direction: str) -> tuple[object, ...]:
    """The compact ``/cmm/can_rx`` / ``/cmm/can_tx`` record of one frame (the MCAP writer
    turns it into a ``protocol.session_topics.CanFrame``: ``session_topics.frame_fields``);
    ``direction``: ``rx``, ``tx`` or ``tx_echo`` (``session_topics.FRAME_DIRECTIONS``)."""
    return (
        msg.arbitration_id,
        msg.is_extended_id,
        msg.dlc,
        bytes(msg.data or b""),
        msg.timestamp or 0.0,
        channel,
        msg.is_fd,
        msg.is_remote_frame,
        msg.is_error_frame,
        direction,
    )


_LOG_BACKLOG_MAX = 256


class CanEndpoint(can.Listener):
    """Serve corrections on one CAN bus. Context manager; ``stop(timeout_s)``.

    :param heartbeat: builds the current :class:`Heartbeat` (state, counters, grid id).
    :param bus_factory: opens the bus (default :func:`open_bus`); tests inject failing buses.
    """

    def __init__(
        self,
        config: CanSection,
        engine: CorrectionEngine,
        state: StateBoard,
        heartbeat: Callable[[], Heartbeat],
        metrics: Metrics,
        events: EventLog,
        logger: SessionLogger | None = None,
        bus_factory: BusFactory = open_bus,
    ) -> None:
        self.config = config
        self.ids = CanIds(config.node_id, config.base_id)
        self.engine = engine
        self.state = state
        self._heartbeat = heartbeat
        self.metrics = metrics
        self.events = events
        self.logger = logger if config.log_frames else None
        self._bus_factory = bus_factory
        self._bus: can.BusABC | None = None
        self._assembler: TripletAssembler[RawAxis] = TripletAssembler(window=config.window)
        self._decode_raw = RawAxisDecoder(self.ids)  # hot path; decode_message for the rest
        self._probe: OrderedDict[int, tuple[float, float, float]] = OrderedDict()
        # Bookkeeping (counters, events, MCAP records) of answered readings and the frames to
        # log wait until the bus is quiet (or DEFER_MAX readings pile up): off the reply path,
        # and out of the way of the peer that is still taking in the answer.
        self._deferred: list[tuple[Reading, Answer, float]] = []
        self._ready: list[Reading] = []  # completed, not yet answered (this wake-up)
        self._ready_fd: list[bool] = []  # per ready reading: came as RAW_XYZ (answer in kind)
        self._log_backlog: list[tuple[str, can.Message]] = []
        self._last_axis_s = 0.0
        self._frames_rx = 0  # folded into the metrics by the housekeeping
        self._next_housekeeping_s = 0.0
        self._corrected_ids = (
            self.ids.corrected_id(Axis.X),
            self.ids.corrected_id(Axis.Y),
            self.ids.corrected_id(Axis.Z),
            self.ids.id_of(MessageKind.CORRECTION_STATUS),
            self.ids.id_of(MessageKind.CORRECTION_UNCERTAINTY),
            self.ids.id_of(MessageKind.CORRECTED_XYZ),
        )
        self._own_tx_ids = self.ids.daemon_tx_ids()  # received back: our own frames (echo)
        self._send_u = config.send_uncertainty
        self._stop = threading.Event()
        self._sent_state: DaemonState | None = None
        self._next_heartbeat = 0.0
        self.last_error: BaseException | None = None
        self._thread = threading.Thread(target=self._run, name="can-endpoint", daemon=True)

    # ------------------------------------------------------------------ lifecycle
    def start(self) -> CanEndpoint:
        """Open the bus (errors are reported, then retried) and start the thread."""
        self._open()
        self._thread.start()
        return self

    def stop(self, timeout_s: float = 2.0) -> bool:  # type: ignore[override]
        """Stop the thread and shut the bus down; True if the thread ended in ``timeout_s``."""
        self._stop.set()
        if self._thread.is_alive():
            self._thread.join(timeout_s)
        if not self._thread.is_alive():
            self._bookkeeping()  # what was received or sent last still reaches the log
            self._count_frames()
        self._close()
        return not self._thread.is_alive()

    def __enter__(self) -> CanEndpoint:
        return self.start()

    def __exit__(self, *exc: object) -> None:
        self.stop()

    @property
    def connected(self) -> bool:
        """True while the bus is open."""
        return self._bus is not None

    # ------------------------------------------------------------------ can.Listener
    def on_message_received(self, msg: can.Message) -> None:
        """Handle one received message (any content: never raises on bad input)."""
        self._handle(msg, time.perf_counter())
        self._answer_ready()
        self._bookkeeping()  # driven by a Notifier: no idle detection, book at once
        self._count_frames()

    def on_error(self, exc: Exception, message: str | None = None) -> None:
        """Every exception of the endpoint lands here: counted, logged (``message``, default
        the exception's repr), reflected in state."""
        self.last_error = exc
        self.metrics.fault("can_error")
        self.events.emit("can_error", "error", error=message or repr(exc))

    # ------------------------------------------------------------------ bus
    def _open(self) -> bool:
        try:
            self._bus = self._bus_factory(self.config, self.ids)
        except Exception as exc:
            self._bus = None
            message = can_open_error(self.config, exc)
            self.on_error(exc, message)
            self.state.set_condition("can", message)
            return False
        self.state.set_condition("can", None)
        self.events.emit(
            "can_open", interface=self.config.interface, channel=str(self.config.channel)
        )
        self._sent_state = None  # announce ourselves on the (re)opened bus
        return True

    def _close(self) -> None:
        bus, self._bus = self._bus, None
        if bus is not None:
            try:
                bus.shutdown()
            except Exception as exc:
                self.on_error(exc)

    def _bus_failed(self, exc: Exception) -> None:
        self.on_error(exc)
        self.metrics.fault("bus_error")
        self.state.set_condition("can", f"bus error: {exc}")
        self._close()

    def _run(self) -> None:
        name_os_thread()
        backoff = self.config.reconnect_s
        while not self._stop.is_set():
            try:
                bus = self._bus
                if bus is None:
                    if self._stop.wait(backoff):
                        break
                    if self._open():
                        self.metrics.count("can_reconnects")
                        backoff = self.config.reconnect_s
                    else:
                        backoff = min(2 * backoff, _MAX_BACKOFF_S)
                    continue
                busy = bool(self._deferred or self._log_backlog)
                try:
                    msg = bus.recv(_IDLE_S if busy else _RECV_POLL_S)
                except Exception as exc:  # bus gone, driver error: reopen
                    self._bus_failed(exc)
                    continue
                if msg is not None:
                    t_rx = time.perf_counter()
                    self._handle(msg, t_rx)
                    if self._ready:
                        # the reading it completed is answered before anything else is taken
                        # from the bus (a receive call there gives the GIL away, and an empty
                        # one is all it finds while readings come one at a time); then every
                        # frame already waiting is taken and what it completes is answered as
                        # one batch (under load: most readings)
                        self._answer_ready()
                        self._drain(bus)
                        self._answer_ready()
                    if len(self._deferred) >= _DEFER_MAX:
                        self._bookkeeping()
                    if t_rx >= self._next_housekeeping_s:
                        self._housekeeping()
                else:
                    if busy:
                        self._bookkeeping()
                    self._housekeeping()
            except Exception as exc:  # a bug in our own code: report and keep serving
                self.on_error(exc)
                self._stop.wait(0.01)

    # ------------------------------------------------------------------ receive
    def _drain(self, bus: can.BusABC) -> None:
        """Handle every frame already waiting (up to ``_DRAIN_MAX``), without blocking (one
        locked take on ``virtual``: :func:`daemon.can_send.recv_pending`)."""
        try:
            msgs = recv_pending(bus, _DRAIN_MAX - 1)
        except Exception as exc:  # bus gone: answer what is complete, then reopen
            self._answer_ready()
            self._bus_failed(exc)
            return
        if msgs:
            t_rx = time.perf_counter()  # they were all waiting: the same arrival for each
            handle = self._handle
            for msg in msgs:
                handle(msg, t_rx)

    def _handle(self, msg: can.Message, t_rx: float) -> None:
        self._frames_rx += 1
        frame = self._decode_raw(msg) or decode_message(msg, self.ids)
        if type(frame) is RawAxis:
            self._last_axis_s = t_rx
            for event in self._assembler.feed(frame):
                self._on_assembler(event, t_rx)
        elif type(frame) is RawReading:
            self._last_axis_s = t_rx
            if self.config.fd:
                self._ready_reading(frame, t_rx)
            else:  # its answer could not go out as a CAN FD frame on a classic bus
                self.metrics.fault("fd_frame_on_classic_bus")
                self.events.emit(
                    "fd_frame_on_classic_bus",
                    "warning",
                    reason=f"RAW_XYZ seq {frame.seq} (CAN FD) not answered: the bus is opened "
                    "for classic CAN; set [can] fd = true (docs/can.md)",
                )
        elif isinstance(frame, TemperatureSample):
            self._answer_ready()  # readings completed before this sample are corrected without it
            self.engine.temperature(frame.sensor, frame.temp_C, frame.counter, frame.valid, "can")
        elif isinstance(frame, ProbeDirection):
            if frame.present:
                self._probe[frame.seq] = frame.unit_vector
                while len(self._probe) > _PROBE_MEMORY:
                    self._probe.popitem(last=False)
        elif isinstance(
            frame,
            CorrectedAxis | CorrectionStatus | CorrectionUncertainty | CorrectedReading | Heartbeat,
        ):
            self.metrics.count("own_frames_ignored")  # udp_multicast echoes our own frames
        else:
            self._on_undecodable(frame)
        if self.logger is not None:
            self._log_backlog.append(("/cmm/can_rx", msg))
            if len(self._log_backlog) >= _LOG_BACKLOG_MAX:
                self._flush_log()

    def _bookkeeping(self) -> None:
        """Report (events, MCAP) the readings answered since the last call, then log the
        frames; then let the MCAP writer work (the line is quiet now)."""
        deferred, self._deferred = self._deferred, []
        if deferred:
            self.engine.report_many(deferred)
        if self.logger is not None and (deferred or self._log_backlog):
            self._flush_log()
            self.logger.kick()

    def _flush_log(self) -> None:
        """Hand the frames received/sent since the last answer to the MCAP logger."""
        if self.logger is None or not self._log_backlog:
            return
        ch = str(self.config.channel)
        backlog, self._log_backlog = self._log_backlog, []
        own = self._own_tx_ids  # a frame on one of these came from us: the bus echoed it
        rx = [
            frame_record(
                msg, ch, "tx_echo" if msg.arbitration_id in own and not msg.is_extended_id else "rx"
            )
            for topic, msg in backlog
            if topic == "/cmm/can_rx"
        ]
        tx = [frame_record(msg, ch, "tx") for topic, msg in backlog if topic != "/cmm/can_rx"]
        self.logger.log_many("/cmm/can_rx", rx)
        self.logger.log_many("/cmm/can_tx", tx)

    def _on_undecodable(self, result: object) -> None:
        if isinstance(result, UnknownId):
            kind = "unknown_id"
        elif isinstance(result, BadLength):
            kind = "bad_length"
        elif isinstance(result, BadValue):
            kind = "bad_value"
        elif isinstance(result, NotData):
            kind = "error_frame" if result.reason == "error frame" else "remote_frame"
        else:  # pragma: no cover - decode_message returns one of the above
            kind = "undecodable"
        self.metrics.fault(kind)
        self.events.emit(kind, "warning", reason=getattr(result, "reason", repr(result)))

    def _on_assembler(self, event: object, t_rx: float) -> None:
        if isinstance(event, Triplet):
            x, y, z = event.x, event.y, event.z
            self._add_ready(
                event.seq,
                (x.position_nm, y.position_nm, z.position_nm),
                (x.direction.sign, y.direction.sign, z.direction.sign),
                (x.valid, y.valid, z.valid),
                t_rx,
                fd=False,
            )
        elif isinstance(event, Incomplete | Superseded):
            self._answer_ready()
            self._answer_incomplete(event.seq, event.reason, t_rx)
        elif isinstance(event, Duplicate):
            self.metrics.fault("duplicate_frame")
            self.events.emit("duplicate_frame", "warning", reason=event.reason)
        elif isinstance(event, OutOfOrder):
            self.metrics.fault("out_of_order")
            self.events.emit("out_of_order", "warning", reason=event.reason)

    def _ready_reading(self, frame: RawReading, t_rx: float) -> None:
        """A whole reading in one CAN FD frame: ready to answer (no assembly; a repeat of a
        seq is a new reading, as a restarted controller's would be)."""
        d = frame.directions
        self._add_ready(
            frame.seq,
            frame.position_nm,
            (d[0].sign, d[1].sign, d[2].sign),
            frame.valid,
            t_rx,
            fd=True,
        )

    def _add_ready(
        self,
        seq: int,
        position_nm: tuple[int, int, int],
        directions: tuple[int, int, int],
        valid: tuple[bool, bool, bool],
        t_rx: float,
        fd: bool,
    ) -> None:
        """One completed reading, answered with the others of this wake-up; ``fd``: it came as
        one RAW_XYZ frame and is answered in kind (the ready list and its flags stay paired)."""
        self._ready.append(
            Reading(
                seq=seq,
                position_nm=position_nm,
                directions=directions,
                valid=valid,
                probe=self._probe.pop(seq, None),
                received_s=t_rx,
                source="can",
            )
        )
        self._ready_fd.append(fd)

    def _answer_incomplete(self, seq: int, reason: str, t_rx: float) -> None:
        self.metrics.fault("incomplete_reading")
        status = CorrectionStatus(seq, Status.INCOMPLETE_READING, latency_us=0)
        self._send([status])
        # answered when it expired: its wait is not a reply latency (kept out of the histogram)
        self.metrics.answer(Status.INCOMPLETE_READING.label, None)
        self.events.emit("answer_incomplete_reading", "warning", seq=seq, detail=reason)

    # ------------------------------------------------------------------ send
    def _answer_ready(self) -> None:
        """Correct the readings completed so far (one batch), send every answer (one batch),
        count them; their reports wait for the bookkeeping."""
        ready, fd = self._ready, self._ready_fd
        if not ready:
            return
        self._ready, self._ready_fd = [], []
        if len(ready) == 1:  # one reading (the paced case): no batch bookkeeping on its path
            reading = ready[0]
            answer = self.engine.correct(reading)  # = correct_many([reading])
            latency_us = self._send_answer(answer, reading.received_s, fd[0])
            self.engine.count_many((answer,), (latency_us,))
            self._deferred.append((reading, answer, latency_us))
            return
        answers = self.engine.correct_many(ready)
        msgs: list[can.Message] = []
        latencies = [
            self._answer_frames(a, r.received_s, msgs, f)
            for r, a, f in zip(ready, answers, fd, strict=True)
        ]
        self._send_msgs(msgs)
        self.engine.count_many(answers, latencies)
        # reported when the bus is quiet
        self._deferred += zip(ready, answers, latencies, strict=True)

    def _answer_frames(
        self, answer: Answer, t_rx: float, out: list[can.Message], fd: bool = False
    ) -> float:
        """Append the answer frames of ``answer`` to ``out`` (X, Y, Z, U when configured,
        STATUS last; ``fd``: the one CORRECTED_XYZ frame, U always in it); return the
        latency, µs."""
        seq, st = answer.seq, int(answer.status)
        ids = self._corrected_ids
        if fd:
            latency_us = (time.perf_counter() - t_rx) * 1e6
            data = encode_corrected_reading(
                seq,
                st,
                int(answer.applied),
                answer.position_nm,
                latency_us,
                answer.correction_norm_um,
                answer.uncertainty_um,
            )
            out.append(
                can.Message(arbitration_id=ids[5], is_extended_id=False, is_fd=True, data=data)
            )
            return latency_us
        x, y, z = encode_corrected_axes(seq, st, answer.position_nm)
        out += (
            can.Message(arbitration_id=ids[0], is_extended_id=False, data=x),
            can.Message(arbitration_id=ids[1], is_extended_id=False, data=y),
            can.Message(arbitration_id=ids[2], is_extended_id=False, data=z),
        )
        if self._send_u:  # unknown (0xFFFF) unless the status is ok and the grid carries U
            u = encode_correction_uncertainty(seq, answer.uncertainty_um)
            out.append(can.Message(arbitration_id=ids[4], is_extended_id=False, data=u))
        latency_us = (time.perf_counter() - t_rx) * 1e6
        status = encode_correction_status(
            seq, st, int(answer.applied), latency_us, answer.correction_norm_um
        )
        out.append(can.Message(arbitration_id=ids[3], is_extended_id=False, data=status))
        return latency_us

    def _send_answer(self, answer: Answer, t_rx: float, fd: bool = False) -> float:
        """Send the frames of one answer now; return the latency in its status frame, µs."""
        msgs: list[can.Message] = []
        latency_us = self._answer_frames(answer, t_rx, msgs, fd)
        self._send_msgs(msgs)
        return latency_us

    def _send(self, frames: list[Any]) -> None:
        self._send_msgs([encode_message(f, self.ids) for f in frames])

    def _send_msgs(self, msgs: list[can.Message]) -> None:
        """Send answer frames (packed by the protocol's fast encoders on the hot path; equal
        to the frame classes' ``encode()`` and to cantools on the DBC, which tests check)."""
        bus = self._bus
        if bus is None:
            self.metrics.fault("send_without_bus", len(msgs))
            return
        try:
            send_batch(bus, msgs, self.config.send_timeout_s)
        except Exception as exc:
            self.metrics.fault("send_error")
            self.on_error(exc)
            return
        self.metrics.count("frames_tx", len(msgs))
        if self.logger is not None:
            now = time.time()
            for msg in msgs:
                msg.timestamp = now
                self._log_backlog.append(("/cmm/can_tx", msg))

    # ------------------------------------------------------------------ periodic
    def _count_frames(self) -> None:
        n, self._frames_rx = self._frames_rx, 0
        if n:
            self.metrics.count("frames_rx", n)

    def _housekeeping(self) -> None:
        self._count_frames()
        now = time.perf_counter()
        self._next_housekeeping_s = now + _HOUSEKEEPING_S
        pending = self._assembler.pending_seqs
        if (
            pending
            and now - self._last_axis_s > self.config.triplet_timeout_s
            and self._bus is not None
        ):
            # frames already waiting arrived before the deadline: take them first (a thread
            # that was not scheduled for a while must not time out readings it holds)
            self._drain(self._bus)
            self._answer_ready()
            pending = self._assembler.pending_seqs
        if pending and now - self._last_axis_s > self.config.triplet_timeout_s:
            timeout_ms = self.config.triplet_timeout_s * 1e3
            for inc in self._assembler.flush(f"no axis frame for {timeout_ms:.0f} ms"):
                self._answer_incomplete(inc.seq, inc.reason, self._last_axis_s)
        state = self.state.state
        if now >= self._next_heartbeat or state != self._sent_state:
            self._next_heartbeat = now + self.config.heartbeat_s
            self._sent_state = state
            self._send([self._heartbeat()])
