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


def test_recv_pending_equals_recv_on_virtual_with_filters() -> None:
    """Oracle: the filter rule of python-can's docs (``id & mask == can_id & mask``, and
    ``extended`` when given) applied by hand to what was sent, in order. A bus that filters in
    software (``virtual``) answers ``recv(0)`` with None at a frame its filters refuse
    (``BusABC.recv``), so one call may stop there: calls in a row, as the endpoint's loop makes
    them, take every matching frame, in order, none twice."""
    from cmm_comp.daemon.can_send import recv_pending

    ch = f"recv-{uuid.uuid4().hex[:8]}"
    filters = [{"can_id": 0x200, "can_mask": 0x7F0, "extended": False}]
    rx = can.Bus(interface="virtual", channel=ch, can_filters=filters)
    tx = can.Bus(interface="virtual", channel=ch)
    plain = can.Bus(interface="virtual", channel=ch)
    try:
        sent = [
            can.Message(arbitration_id=i, is_extended_id=ext, data=bytes([k % 256]))
            for k, (i, ext) in enumerate(
                [(0x200, False), (0x20B, False), (0x300, False), (0x205, True), (0x20F, False)] * 40
            )
        ]
        for m in sent:
            tx.send(m)
        want = [
            (m.arbitration_id, m.data)
            for m in sent
            if not m.is_extended_id and m.arbitration_id & 0x7F0 == 0x200
        ]
        got: list[can.Message] = []
        for _ in range(len(sent)):
            got += recv_pending(rx, 10_000)
        assert [(m.arbitration_id, m.data) for m in got] == want
        assert all(m.is_rx and m.channel == ch for m in got)
        assert recv_pending(rx, 10) == []
        one_by_one = [plain.recv(0.0) for _ in range(len(sent))]
        got_plain = recv_pending(plain, 10)  # already empty
        assert got_plain == [] and all(m is not None for m in one_by_one)
        for m in sent[:30]:
            tx.send(m)
        first = recv_pending(plain, 7)  # at most max_n, oldest first
        assert [m.data for m in first] == [m.data for m in sent[:7]]
        assert len(recv_pending(plain, 100)) == 23
    finally:
        for bus in (rx, tx, plain):
            bus.shutdown()


def test_recv_pending_frees_a_bounded_queue_and_raises_when_closed() -> None:
    from cmm_comp.daemon.can_send import recv_pending

    ch = f"recv-{uuid.uuid4().hex[:8]}"
    rx = can.Bus(interface="virtual", channel=ch, rx_queue_size=3)
    tx = can.Bus(interface="virtual", channel=ch)
    try:
        for k in range(3):
            tx.send(can.Message(arbitration_id=k, data=b"x"), timeout=1.0)
        assert len(recv_pending(rx, 10)) == 3
        for k in range(3):  # room again: a full queue would block (and time out)
            tx.send(can.Message(arbitration_id=k, data=b"y"), timeout=0.5)
        assert [m.data for m in recv_pending(rx, 10)] == [b"y"] * 3
    finally:
        tx.shutdown()
        rx.shutdown()
    with pytest.raises(can.CanOperationError):
        recv_pending(rx, 1)


def test_recv_pending_on_other_buses_calls_recv_zero() -> None:
    from cmm_comp.daemon.can_send import recv_pending

    class Queued(can.BusABC):
        def __init__(self, frames: list[can.Message]) -> None:
            super().__init__(channel="q")
            self.frames = frames
            self.timeouts: list[float | None] = []

        def send(self, msg: can.Message, timeout: float | None = None) -> None:
            pass

        def _recv_internal(self, timeout):
            self.timeouts.append(timeout)
            return (self.frames.pop(0) if self.frames else None), False

    bus = Queued([can.Message(arbitration_id=k) for k in range(5)])
    assert [m.arbitration_id for m in recv_pending(bus, 3)] == [0, 1, 2]
    assert [m.arbitration_id for m in recv_pending(bus, 9)] == [3, 4]
    assert set(bus.timeouts) == {0.0}
    bus.shutdown()
