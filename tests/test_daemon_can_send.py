"""send_batch on python-can's ``virtual`` bus delivers exactly what ``VirtualBus.send`` does.

Oracle: python-can's own ``VirtualBus.send`` of the same messages on a second channel; every
receiver (not the sender unless it asked for its own frames) gets equal messages, in order."""

from __future__ import annotations

import uuid

import can
import pytest

from cmm_comp.daemon.can_send import send_batch

FIELDS = (
    "arbitration_id",
    "is_extended_id",
    "is_remote_frame",
    "is_error_frame",
    "dlc",
    "data",
    "is_fd",
    "is_rx",
    "bitrate_switch",
    "error_state_indicator",
    "channel",
)


def _msgs() -> list[can.Message]:
    return [
        can.Message(arbitration_id=0x208, is_extended_id=False, data=bytes(range(8))),
        can.Message(arbitration_id=0x12345, is_extended_id=True, data=b"\x01\x02"),
        can.Message(arbitration_id=0x20B, is_extended_id=False, is_remote_frame=True, dlc=8),
        can.Message(arbitration_id=0x20F, is_fd=True, bitrate_switch=True, data=bytes(64)),
    ]


def _received(send, receive_own: bool) -> tuple[list[list[tuple]], list[float]]:
    ch = f"send-{uuid.uuid4().hex[:8]}"
    sender = can.Bus(interface="virtual", channel=ch, receive_own_messages=receive_own)
    peers = [can.Bus(interface="virtual", channel=ch) for _ in range(2)]
    try:
        send(sender, _msgs())
        out, stamps = [], []
        for bus in ([sender] if receive_own else []) + peers:
            got = []
            while (m := bus.recv(0.0)) is not None:
                got.append((*(getattr(m, f) for f in FIELDS[:-1]), m.channel == ch))
                stamps.append(m.timestamp)
            out.append(got)
        return out, stamps
    finally:
        for bus in [sender, *peers]:
            bus.shutdown()


@pytest.mark.parametrize("receive_own", [False, True])
def test_send_batch_equals_virtualbus_send(receive_own: bool) -> None:
    def one_by_one(bus: can.BusABC, msgs: list[can.Message]) -> None:
        for m in msgs:
            bus.send(m)

    expected, _ = _received(one_by_one, receive_own)
    got, stamps = _received(lambda b, m: send_batch(b, m, 1.0), receive_own)
    assert got == expected
    assert all(len(g) == 4 for g in got)
    assert all(s > 0 for s in stamps)  # stamped at send time, as VirtualBus does


def test_send_batch_on_a_closed_bus_raises_like_send() -> None:
    bus = can.Bus(interface="virtual", channel=f"send-{uuid.uuid4().hex[:8]}")
    bus.shutdown()
    with pytest.raises(can.CanOperationError):
        send_batch(bus, _msgs(), 1.0)


def test_other_buses_get_one_send_per_frame() -> None:
    class Recording(can.BusABC):
        def __init__(self) -> None:
            super().__init__(channel="rec")
            self.sent: list[tuple[int, float | None]] = []

        def send(self, msg: can.Message, timeout: float | None = None) -> None:
            self.sent.append((msg.arbitration_id, timeout))

        def _recv_internal(self, timeout):
            return None, False

    bus = Recording()
    send_batch(bus, _msgs(), 0.25)
    assert bus.sent == [(0x208, 0.25), (0x12345, 0.25), (0x20B, 0.25), (0x20F, 0.25)]
    bus.shutdown()
