"""The CAN endpoint answers a reading before it receives anything else.

A bus that logs every receive call and every frame sent: when a received frame completes a
reading, the answer frames must be the next thing on the log, with no receive call before them
(on a socket bus such as ``udp_multicast`` a receive call is a system call that gives the GIL
away, in the reply path of every reading). Frames already waiting behind it are then taken
and every reading they complete is answered, in order.
"""

from __future__ import annotations

import threading
import time
from typing import Any

import can
from test_daemon_support import base_config, channel, daemon_and_controller

from cmm_comp.protocol import CanIds, RawAxis, TemperatureSample, encode_message
from cmm_comp.protocol.can_ids import MessageKind
from cmm_comp.protocol.codes import NM_PER_MM, Axis, Status

IDS = CanIds()
RAW = {IDS.id_of(k) for k in (MessageKind.RAW_X, MessageKind.RAW_Y, MessageKind.RAW_Z)}
ANSWER = {IDS.corrected_id(a) for a in Axis} | {IDS.id_of(MessageKind.CORRECTION_STATUS)}
STATUS = IDS.id_of(MessageKind.CORRECTION_STATUS)


class LoggingBus(can.BusABC):
    """Hands out the frames put in :attr:`waiting` (all already waiting, as after a burst);
    logs ``("recv", id or None)`` per receive call and ``("send", id, data)`` per frame sent."""

    def __init__(self, *_: Any, **__: Any) -> None:
        super().__init__(channel="logging")
        self.lock = threading.Lock()
        self.waiting: list[can.Message] = []
        self.log: list[tuple[Any, ...]] = []

    def _recv_internal(self, timeout: float | None) -> tuple[can.Message | None, bool]:
        with self.lock:
            msg = self.waiting.pop(0) if self.waiting else None
            if msg is not None or timeout == 0.0:
                self.log.append(("recv", None if msg is None else msg.arbitration_id))
        if msg is None and timeout:
            time.sleep(min(timeout, 0.001))
        return msg, False

    def send(self, msg: can.Message, timeout: float | None = None) -> None:
        with self.lock:
            self.log.append(("send", msg.arbitration_id, bytes(msg.data)))


def raw_frames(seq: int, pos_mm: tuple[float, float, float]) -> list[can.Message]:
    return [
        encode_message(RawAxis(axis, seq, round(p * NM_PER_MM)), IDS)
        for axis, p in zip(Axis, pos_mm, strict=True)
    ]


def test_a_completed_reading_is_answered_before_the_next_receive() -> None:
    bus = LoggingBus()
    cfg = base_config(channel())
    cfg.metrics.enabled = False
    with daemon_and_controller(cfg, bus_factory=lambda c, i: bus) as (d, _ctl, _raw):
        temps = [encode_message(TemperatureSample(s, 20_500, 1, True), IDS) for s in range(4)]
        with bus.lock:
            bus.waiting += temps
        deadline = time.monotonic() + 10
        while bus.waiting and time.monotonic() < deadline:
            time.sleep(0.01)
        with bus.lock:  # three readings arrive together: 9 frames waiting
            for seq in (1, 2, 3):
                bus.waiting += raw_frames(seq, (400.0 + seq, 500.0, 200.0))
        while time.monotonic() < deadline:
            with bus.lock:
                n_status = sum(e[0] == "send" and e[1] == STATUS for e in bus.log)
            if n_status >= 3:
                break
            time.sleep(0.01)
        assert d.can is not None
        with bus.lock:
            log = list(bus.log)
    received_raw = [k for k, e in enumerate(log) if e[0] == "recv" and e[1] in RAW]
    assert len(received_raw) == 9
    z1 = received_raw[2]  # the frame completing reading 1
    after = [e for e in log[z1 + 1 :] if e[0] == "recv" or e[1] in ANSWER]
    assert [e[0] for e in after[:4]] == ["send"] * 4, after[:6]
    assert [e[1] for e in after[:4]] == [*(IDS.corrected_id(a) for a in Axis), STATUS]
    # every reading answered once, in order (status frame: seq in bytes 0-1, status in byte 2)
    statuses = [e[2] for e in log if e[0] == "send" and e[1] == STATUS]
    assert [int.from_bytes(s[:2], "little") for s in statuses] == [1, 2, 3]
    assert [s[2] for s in statuses] == [int(Status.OK)] * 3
