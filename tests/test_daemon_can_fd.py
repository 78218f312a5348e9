"""The daemon on CAN FD: a RAW_XYZ reading gets one CORRECTED_XYZ answer that says exactly what
the classic answer (X, Y, Z, U and status frames) says for the same reading; cantools decodes
it from the DBC; classic and FD readings may share the bus; a classic-only bus refuses FD
readings with a named event instead of answering wrongly."""

from __future__ import annotations

import math
from pathlib import Path

import can
import cantools
import pytest
from test_daemon_support import base_config, channel, send_temps
from test_daemon_uncertainty import OK_POINTS_MM, TEMP_C, u_grid_path

from cmm_comp.cli.sessionlog.replay import replay_to_bus
from cmm_comp.daemon.service import DaemonService
from cmm_comp.protocol import CanIds, MessageKind, dbc_text, encode_message
from cmm_comp.protocol import RawReading as RawReadingFrame
from cmm_comp.protocol.codes import nm3_from_mm
from cmm_comp.sim_controller.controller import CanController, RawReading

DB = cantools.database.load_string(dbc_text(), database_format="dbc")
IDS = CanIds()
READINGS = [
    *(RawReading(i + 1, p, travel_dir=(1, -1, 0)) for i, p in enumerate(OK_POINTS_MM)),
    RawReading(20, (-30.0, 100.0, 100.0)),  # outside the volume
    RawReading(21, (100.0, 100.0, 100.0), valid=(True, False, True)),  # invalid scale
]


def _fd_config() -> object:
    cfg = base_config(channel(), u_grid_path())
    cfg.can.fd = True
    cfg.can.send_uncertainty = True  # the classic answer carries U too, to compare
    cfg.metrics.enabled = False
    return cfg.check()


def test_fd_answer_equals_the_classic_answer_and_cantools_reads_it() -> None:
    cfg = _fd_config()
    with DaemonService(cfg, events_stream=None):  # type: ignore[arg-type]
        ch = cfg.can.channel  # type: ignore[attr-defined]
        classic_bus = can.Bus(interface="virtual", channel=ch, fd=True)
        fd_bus = can.Bus(interface="virtual", channel=ch, fd=True)
        spy = can.Bus(interface="virtual", channel=ch, fd=True)
        try:
            with (
                CanController(classic_bus, answer_timeout_s=10.0) as classic,
                CanController(fd_bus, answer_timeout_s=10.0, fd=True) as fd,
            ):
                send_temps(classic, TEMP_C)
                a_classic = {r.seq: classic.exchange(r) for r in READINGS}
                # the same readings again (new seqs), one CAN FD frame each
                shifted = [RawReading(r.seq + 100, *_rest(r)) for r in READINGS]
                a_fd = {r.seq - 100: fd.exchange(r) for r in shifted}
            frames = []
            while (msg := spy.recv(0.0)) is not None:
                frames.append(msg)
        finally:
            for bus in (classic_bus, fd_bus, spy):
                bus.shutdown()
    fd_answers = [m for m in frames if m.arbitration_id == IDS.id_of(MessageKind.CORRECTED_XYZ)]
    fd_readings = [m for m in frames if m.arbitration_id == IDS.id_of(MessageKind.RAW_XYZ)]
    assert len(fd_answers) == len(fd_readings) == len(READINGS)  # one frame each way
    assert all(m.is_fd and len(m.data) == 32 for m in fd_answers)
    by_seq = {DB.decode_message(m.arbitration_id, m.data)["Seq"]: m for m in fd_answers}
    for r in READINGS:
        c, f = a_classic[r.seq], a_fd[r.seq]
        assert c.status != "timeout" and f.status == c.status
        assert f.corrected_mm == c.corrected_mm  # same nm on the wire
        assert (f.applied, f.correction_um) == (c.applied, c.correction_um)
        assert c.uncertainty_um is not None and f.uncertainty_um is not None
        for uc, uf in zip(c.uncertainty_um, f.uncertainty_um, strict=True):
            assert uc == uf or (math.isnan(uc) and math.isnan(uf))
        # the DBC (cantools, physical values) says the same as the controller read
        sig = DB.decode_message(by_seq[r.seq + 100].arbitration_id, by_seq[r.seq + 100].data)
        assert sig["Status"] == f.status
        want = pytest.approx(f.corrected_mm, abs=1e-9)  # cantools scales by 1e-6 in floats
        assert (sig["PositionX"], sig["PositionY"], sig["PositionZ"]) == want
    assert a_fd[20].status == "outside_volume" and a_fd[21].status == "invalid_reading"
    assert a_fd[1].status == "ok"


def _rest(r: RawReading) -> tuple[object, ...]:
    return (r.indicated_mm, r.travel_dir, r.probe_dir, r.valid)


def test_fd_reading_on_a_classic_bus_is_refused_by_name() -> None:
    cfg = base_config(channel(), u_grid_path())
    cfg.metrics.enabled = False
    cfg.check()
    with DaemonService(cfg, events_stream=None) as d:
        bus = can.Bus(interface="virtual", channel=cfg.can.channel, fd=True)
        try:
            with CanController(bus, answer_timeout_s=0.5, fd=True) as ctl:
                send_temps(ctl, TEMP_C)
                answer = ctl.exchange(RawReading(1, OK_POINTS_MM[0]))
        finally:
            bus.shutdown()
        faults = d.metrics.faults
    assert answer.status == "timeout"  # not answered: never a classic answer it did not ask for
    assert faults.get("fd_frame_on_classic_bus") == 1


def _fd_session_log(tmp_path: Path) -> tuple[Path, list[RawReading]]:
    """A daemon session on CAN FD (RAW_XYZ in, CORRECTED_XYZ out), logged to MCAP: the log
    and the readings the controller sent."""
    cfg = base_config(channel(), u_grid_path())
    cfg.can.fd = True
    cfg.metrics.enabled = False
    cfg.mcap.path = str(tmp_path / "fd.mcap")
    cfg.check()
    sent = [RawReading(i + 1, p) for i, p in enumerate(OK_POINTS_MM)]
    with DaemonService(cfg, events_stream=None):
        bus = can.Bus(interface="virtual", channel=cfg.can.channel, fd=True)
        try:
            with CanController(bus, answer_timeout_s=10.0, fd=True) as ctl:
                send_temps(ctl, TEMP_C)
                assert all(ctl.exchange(r).status == "ok" for r in sent)
        finally:
            bus.shutdown()
    logs = sorted(tmp_path.glob("*.mcap"))
    assert logs, "no session log written"
    return logs[0], sent


def test_fd_session_log_reads_in_foxglove_s_reader(tmp_path: Path, mcap_ts) -> None:
    """The official TypeScript reader (``@mcap/core``, indexed and stream) reads a session of
    CAN FD frames whole: one 20-byte FD frame in and one 32-byte FD frame out per reading,
    counted against what the controller sent (not against the project's Python reader)."""
    log, sent = _fd_session_log(tmp_path)
    got = mcap_ts(log, "dlc", "is_fd", "arbitration_id")
    idx, stream = got["indexed"], got["stream"]
    assert "error" not in idx, f"McapIndexedReader: {idx['error']}"
    assert "error" not in stream and stream["done"], f"McapStreamReader: {stream}"
    assert idx["values"] == stream["values"] and idx["topics"] == stream["topics"]
    assert idx["json_errors"] == 0 and idx["out_of_order"] == 0
    n = len(sent)
    assert idx["topics"]["/cmm/raw"] == idx["topics"]["/cmm/corrected"] == n
    rx, tx = idx["values"]["/cmm/can_rx"], idx["values"]["/cmm/can_tx"]
    ids = {k: str(IDS.id_of(k)) for k in (MessageKind.RAW_XYZ, MessageKind.CORRECTED_XYZ)}
    heartbeat = str(IDS.id_of(MessageKind.HEARTBEAT))
    # the temperature frames in and the heartbeats out are classic (8 bytes, not FD); each
    # reading is one 20-byte FD frame in and one 32-byte FD frame out, and nothing else is FD
    assert rx["arbitration_id"][ids[MessageKind.RAW_XYZ]] == n
    assert rx["dlc"]["20"] == rx["is_fd"]["true"] == n
    assert tx["arbitration_id"][ids[MessageKind.CORRECTED_XYZ]] == n
    assert set(tx["arbitration_id"]) == {ids[MessageKind.CORRECTED_XYZ], heartbeat}
    assert tx["dlc"]["32"] == tx["is_fd"]["true"] == n
    assert sum(tx["dlc"].values()) == sum(tx["arbitration_id"].values())
    assert set(tx["dlc"]) <= {"32", "8"} and tx["is_fd"].get("false", 0) == tx["dlc"].get("8", 0)


def test_replay_re_sends_fd_frames_as_fd_frames(tmp_path: Path) -> None:
    """A session of RAW_XYZ readings, logged to MCAP, replayed onto a fresh bus: the receiver
    gets each reading back as the same 20-byte CAN FD frame (replay used to drop ``is_fd``)."""
    log, sent = _fd_session_log(tmp_path)
    ch = channel()
    with (
        can.Bus(interface="virtual", channel=ch, fd=True) as out,
        can.Bus(interface="virtual", channel=ch, fd=True) as rx,
    ):
        report = replay_to_bus(log, out, speed=0.0)
        got = []
        while (msg := rx.recv(0.2)) is not None:
            got.append(msg)
    raw_xyz = [m for m in got if m.arbitration_id == IDS.id_of(MessageKind.RAW_XYZ)]
    assert report.sent == len(got) and len(raw_xyz) == len(sent)
    assert all(m.is_fd and len(m.data) == 20 for m in raw_xyz)
    want = [encode_message(RawReadingFrame(r.seq, nm3_from_mm(r.indicated_mm)), IDS) for r in sent]
    assert [bytes(m.data) for m in raw_xyz] == [bytes(w.data) for w in want]
