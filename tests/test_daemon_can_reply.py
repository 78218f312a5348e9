"""The CAN reply the endpoint sends, byte for byte, against cantools encoding the DBC.

For a set of answers (edge values: negative and extreme int40 positions, seq 0 and 65535, every
status, every applied bit, corrections and latencies that round, reach the top of their field
or saturate) the four frames :class:`CanEndpoint` puts on the bus must equal what cantools
encodes from ``protocol/cmm_comp.dbc`` for the same physical values (mm, µm, µs), and what the
frame classes encode. The Modbus answer block quantises the same way.
"""

from __future__ import annotations

import time
from typing import Any

import can
import cantools
import pytest

from cmm_comp.daemon.can_endpoint import CanEndpoint
from cmm_comp.daemon.config import CanSection
from cmm_comp.daemon.engine import Answer
from cmm_comp.daemon.events import EventLog
from cmm_comp.daemon.metrics import Metrics
from cmm_comp.daemon.state import StateBoard
from cmm_comp.protocol import (
    AnswerBlock,
    Applied,
    Axis,
    CanIds,
    CorrectedAxis,
    CorrectionStatus,
    DaemonState,
    Heartbeat,
    Status,
    dbc_text,
    encode_corrected_axes,
    encode_correction_status,
)
from cmm_comp.protocol.can_frames import INT40_MAX, INT40_MIN
from cmm_comp.protocol.codes import NM_PER_MM, UINT16_MAX

DB = cantools.database.load_string(dbc_text(), database_format="dbc")
MAX_CORRECTION_UM = UINT16_MAX / 100  # 655.35 µm, the top of the DBC's Correction signal


class CaptureBus(can.BusABC):
    """Keeps what is sent; never receives."""

    def __init__(self, *_: Any, **__: Any) -> None:
        super().__init__(channel="capture")
        self.sent: list[can.Message] = []

    def send(self, msg: can.Message, timeout: float | None = None) -> None:
        self.sent.append(msg)

    def _recv_internal(self, timeout: float | None) -> tuple[None, bool]:
        return None, False


def endpoint(node_id: int = 0, send_uncertainty: bool = False) -> tuple[CanEndpoint, CaptureBus]:
    """An endpoint whose bus is open (no thread started: the test calls the reply path)."""
    bus = CaptureBus()
    cfg = CanSection(interface="virtual", channel="capture", node_id=node_id, log_frames=False)
    cfg.send_uncertainty = send_uncertainty
    ep = CanEndpoint(
        cfg,
        engine=None,  # type: ignore[arg-type]  # the reply path does not correct
        state=StateBoard(lambda *_: None),
        heartbeat=lambda: Heartbeat(DaemonState.READY),
        metrics=Metrics(),
        events=EventLog(None),
        bus_factory=lambda c, i: bus,
    )
    assert ep._open()
    return ep, bus


def correction_vector(norm_um: float) -> tuple[float, float, float]:
    """A correction vector (µm) whose length is ``norm_um`` exactly (all along one axis)."""
    return (0.0, -norm_um, 0.0)


ANSWERS = [
    # seq, status, position_nm, applied, |correction| µm
    (0, Status.OK, (0, 0, 0), Applied.NONE, 0.0),
    (1, Status.OK, (450_123_456, 575_000_001, -120_000_000), Applied.GEOMETRY, 3.21),
    (65535, Status.OK, (INT40_MAX, INT40_MIN, -1), Applied(0x1F), MAX_CORRECTION_UM),
    (40000, Status.NOT_THERMALLY_CORRECTED, (-1, 1, INT40_MIN), Applied.GEOMETRY, 0.004),
    (7, Status.MISSING_DIRECTION, (-549_755_813_887, 2, 3), Applied(0x03), 0.006),
    (8, Status.OK, (10, 20, 30), Applied(0x1D), 700.0),  # saturates at 655.35 µm
    (9, Status.OK, (10, 20, 30), Applied(0x11), 1e9),
    *(
        (100 + int(s), s, (-123_456_789, 987_654_321, -5), Applied.NONE, 0.0)
        for s in Status
        if not s.geometric_correction_applied
    ),
]
LATENCIES = {
    "now": 0.0,  # a few µs
    "saturated": 1.0,  # answered 1 s after the reading: 1e6 µs → 65535
    "future": -1.0,  # clock oddity (negative latency) → 0
}


def cantools_reply(
    ids: CanIds,
    seq: int,
    status: Status,
    pos_nm: tuple[int, int, int],
    applied: int,
    latency_us: float,
    corr_um: float,
) -> list[tuple[int, bytes]]:
    """(id, payload) of the four reply frames, encoded by cantools from physical values."""
    out = []
    for axis, p in zip(Axis, pos_nm, strict=True):
        msg = DB.get_message_by_name(f"CORRECTED_{axis.name}")
        signals = {"Position": p / NM_PER_MM, "Seq": seq, "Axis": int(axis), "Status": int(status)}
        out.append((ids.corrected_id(axis), msg.encode(signals)))
    msg = DB.get_message_by_name("CORRECTION_STATUS")
    signals = {
        "Seq": seq,
        "Status": int(status),
        "Applied": int(applied),
        "Latency": min(max(latency_us, 0.0), float(UINT16_MAX)),
        "Correction": min(corr_um, MAX_CORRECTION_UM),
    }
    out.append((msg.frame_id, msg.encode(signals)))
    return out


@pytest.mark.parametrize("when", sorted(LATENCIES))
@pytest.mark.parametrize("answer", ANSWERS, ids=lambda a: f"{a[0]}-{a[1].label}")
def test_endpoint_reply_equals_cantools_on_the_dbc(answer: tuple[Any, ...], when: str) -> None:
    seq, status, pos, applied, corr_um = answer
    ep, bus = endpoint()
    ans = Answer(seq, status, pos, applied, correction_vector(corr_um))
    assert ans.correction_norm_um == corr_um
    latency_us = ep._send_answer(ans, time.perf_counter() - LATENCIES[when])
    got = [(m.arbitration_id, bytes(m.data)) for m in bus.sent]
    assert all(not m.is_extended_id and m.dlc == 8 for m in bus.sent)
    want = cantools_reply(ep.ids, seq, status, pos, int(applied), latency_us, corr_um)
    assert got == want
    # …and the frame classes say the same
    frames = [CorrectedAxis(a, seq, p, status) for a, p in zip(Axis, pos, strict=True)]
    latency_raw = CorrectionStatus.decode(got[3][1]).latency_us
    corr_raw = min(round(corr_um * 100), UINT16_MAX)
    frames_status = CorrectionStatus(seq, status, applied, latency_raw, corr_raw)
    assert [d for _, d in got] == [f.encode() for f in (*frames, frames_status)]
    if when == "saturated":
        assert latency_raw == UINT16_MAX
    elif when == "future":
        assert latency_raw == 0


def test_reply_uses_this_nodes_ids() -> None:
    ep, bus = endpoint(node_id=3)
    ep._send_answer(Answer(5, Status.OK, (1, 2, 3), Applied.GEOMETRY, (0.0, 0.0, 0.0)), 0.0)
    ids = CanIds(node_id=3)
    want = [ids.corrected_id(Axis.X), ids.corrected_id(Axis.Y), ids.corrected_id(Axis.Z)]
    assert [m.arbitration_id for m in bus.sent][:3] == want
    assert bus.sent[3].arbitration_id == ids.id_of(CorrectionStatus.kind)


def test_fast_encoders_reject_what_the_wire_cannot_carry() -> None:
    with pytest.raises(OverflowError):
        encode_corrected_axes(0, 0, (INT40_MAX + 1, 0, 0))
    with pytest.raises(Exception, match="format requires"):
        encode_correction_status(65536, 0, 0, 0.0, 0.0)


@pytest.mark.parametrize("answer", ANSWERS, ids=lambda a: f"{a[0]}-{a[1].label}")
def test_modbus_answer_block_quantises_like_the_can_reply(answer: tuple[Any, ...]) -> None:
    seq, status, pos, applied, corr_um = answer
    for latency_us in (0.4, 12.5, 13.5, -3.0, 1e6):
        block = AnswerBlock.from_physical(seq, status, pos, applied, latency_us, corr_um)
        frame = CorrectionStatus.decode(
            encode_correction_status(seq, int(status), int(applied), latency_us, corr_um)
        )
        assert (block.latency_us, block.correction_10nm) == (
            frame.latency_us,
            frame.correction_10nm,
        )
