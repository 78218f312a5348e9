"""Compact log records (``protocol.session_topics.RECORD_FIELDS``): the payload the writer
builds from a record equals the one written out by hand from the CAN message / reading, passes the
topic's schema, and a malformed record is counted as an encode error without stopping the writer."""

from __future__ import annotations

import math
from pathlib import Path

import can
import pytest
from hypothesis import given
from hypothesis import strategies as st

from cmm_comp.cli.sessionlog.reader import read_messages
from cmm_comp.daemon.can_endpoint import frame_record
from cmm_comp.daemon.sessionlog.encoding import message_struct
from cmm_comp.daemon.sessionlog.process_writer import McapProcessLogger
from cmm_comp.daemon.sessionlog.writer import SessionWriter
from cmm_comp.protocol.session_topics import check_message
from cmm_comp.protocol.session_topics import corrected_fields as corrected_payload
from cmm_comp.protocol.session_topics import frame_fields as frame_payload
from cmm_comp.protocol.session_topics import raw_fields as raw_payload

T0_S = 1_700_000_000


@given(
    can_id=st.integers(0, 0x7FF),
    ext=st.booleans(),
    data=st.binary(min_size=0, max_size=8),
    frac_us=st.integers(0, 999_999),
    remote=st.booleans(),
    direction=st.sampled_from(["rx", "tx", "tx_echo"]),
)
def test_frame_payload_matches_the_message_written_out_by_hand(
    can_id: int, ext: bool, data: bytes, frac_us: int, remote: bool, direction: str
) -> None:
    ts = T0_S + frac_us * 1e-6
    msg = can.Message(
        timestamp=ts,
        arbitration_id=can_id | (0x1000_0000 if ext else 0),
        is_extended_id=ext,
        data=data,
        is_remote_frame=remote and not data,
    )
    got = frame_payload(frame_record(msg, "vcan0", direction))
    stamp = got.pop("bus_stamp")
    assert got == {
        "arbitration_id": msg.arbitration_id,
        "is_extended": ext,
        "dlc": len(data),
        "data": "".join(f"{b:02x}" for b in data),
        "channel": "vcan0",
        "is_fd": False,
        "is_remote_frame": remote and not data,
        "is_error_frame": False,
        "direction": direction,
    }
    assert stamp["sec"] == T0_S
    assert abs(stamp["nsec"] - frac_us * 1000) <= 1000  # float seconds: within 1 µs
    check_message("/cmm/can_rx", {**got, "bus_stamp": stamp, "stamp": stamp})


def test_frame_record_copies_the_data_and_knows_no_timestamp() -> None:
    data = bytearray(b"\x01\x02")
    msg = can.Message(timestamp=0.0, arbitration_id=5, is_extended_id=False, data=data)
    rec = frame_record(msg, "c", "rx")
    msg.data[0] = 0xFF  # the record owns its bytes: later changes to the message do not leak
    p = frame_payload(rec)
    assert p["data"] == "0102" and p["bus_stamp"] == {"sec": 0, "nsec": 0}
    nan_ts = frame_payload((5, False, 2, b"\x01\x02", math.nan, "c", False, False, False))
    assert nan_ts["bus_stamp"] == {"sec": 0, "nsec": 0}
    assert "direction" not in nan_ts  # a 9-field record (the layout before directions)


@pytest.mark.parametrize("direction", ["RX", "echo", "", None, 1, b"rx"])
def test_a_frame_with_an_unknown_direction_is_refused(direction: object) -> None:
    with pytest.raises(ValueError, match="direction"):
        message_struct(
            "/cmm/can_rx", (5, False, 0, b"", 1.0, "c", False, False, False, direction), 0
        )


def test_raw_and_corrected_payloads() -> None:
    raw = raw_payload(
        (7, 1.5, -2.25, 3.0, (1, -1, 0), (True, True, False), "can", (0, 0, -120), None)
    )
    assert raw == {
        "seq": 7,
        "x_mm": 1.5,
        "y_mm": -2.25,
        "z_mm": 3.0,
        "travel_dir": [1, -1, 0],
        "valid": [True, True, False],
        "source": "can",
        "stylus_x_mm": 0.0,
        "stylus_y_mm": 0.0,
        "stylus_z_mm": -120.0,
    }
    probe = raw_payload(
        (7, 1.5, -2.25, 3.0, (0, 0, 0), (True,) * 3, "modbus", (0, 0, 0), (0, 0.6, -0.8))
    )
    assert (probe["dir_x"], probe["dir_y"], probe["dir_z"]) == (0.0, 0.6, -0.8)
    cor = corrected_payload(
        (7, 1_500_123, -2, 3_000_000_000, "ok", (0.1, -0.2, 0.3), 55.5, 3, "can", "")
    )
    assert cor == {
        "seq": 7,
        "x_mm": 1.500123,
        "y_mm": -2e-6,
        "z_mm": 3000.0,
        "status": "ok",
        "dx_um": 0.1,
        "dy_um": -0.2,
        "dz_um": 0.3,
        "latency_us": 55.5,
        "applied": 3,
        "source": "can",
    }
    warn = corrected_payload((7, 0, 0, 0, "ok", (0.0, 0.0, 0.0), 1.0, 1, "can", "big"))
    assert warn["detail"] == "big"
    stamp = {"sec": 1, "nsec": 2}
    for topic, p in (("/cmm/raw", raw), ("/cmm/raw", probe), ("/cmm/corrected", cor)):
        check_message(topic, {**p, "stamp": stamp})


@pytest.mark.parametrize("cls", [SessionWriter, McapProcessLogger])
def test_records_reach_the_file_and_a_bad_record_is_an_encode_error(
    tmp_path: Path, cls: type[SessionWriter] | type[McapProcessLogger]
) -> None:
    errors: list[BaseException] = []
    path = tmp_path / "s.mcap"
    lg = cls(path, on_error=errors.append)
    with pytest.raises(KeyError, match="takes a dict payload"):
        lg.log("/cmm/status", ("running",))
    rec = (0x181, False, 8, bytes(range(8)), T0_S + 0.5, "vcan0", False, False, False)
    assert lg.log("/cmm/can_rx", rec, T0_S * 10**9)
    assert lg.log("/cmm/can_tx", (1, 2), T0_S * 10**9 + 1)  # malformed: too short
    assert lg.log("/cmm/can_rx", rec, T0_S * 10**9 + 2)
    assert lg.stop()
    st = lg.stats()
    assert (st.written, st.encode_errors, st.dropped) == (2, 1, 1)
    assert errors and "can_tx" in str(errors[0])
    res = read_messages(path, topics=["/cmm/can_rx", "/cmm/can_tx"])
    assert [m.payload["data"] for m in res.messages] == [bytes(range(8)).hex()] * 2
    (err,) = read_messages(path, topics=["/cmm/log_error"]).messages  # the bad one's record
    assert err.payload["topic"] == "/cmm/can_tx" and err.payload["payload"] == "(1, 2)"
    assert res.messages[0].payload["stamp"] == {"sec": T0_S, "nsec": 0}
