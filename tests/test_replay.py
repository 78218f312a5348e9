"""Replay: re-correct a logged session offline (same grid: equal to what was sent within the
1 nm wire resolution; another grid: the differences are reported) and re-send it to a daemon."""

from __future__ import annotations

import json
import time

import can
import numpy as np
import pytest
from doc_commands import cli
from test_daemon_support import base_config, channel, daemon_and_controller, npl_grid_path

from cmm_comp.cli.sessionlog.replay import ReplayError, replay_offline, replay_to_bus
from cmm_comp.sim_controller.controller import RawReading


@pytest.fixture
def session(tmp_path):
    cfg = base_config(channel())
    cfg.mcap.path = str(tmp_path / "s.mcap")
    rng = np.random.default_rng(1)
    pts = rng.uniform([20, 20, 20], [880, 1130, 380], (60, 3))
    with daemon_and_controller(cfg) as (_d, ctl, _bus):
        ctl.send_temperatures({0: 21.0, 1: 21.5, 2: 20.5, 3: 19.5})
        time.sleep(0.02)
        for i, p in enumerate(pts):
            assert ctl.exchange(RawReading(i, tuple(p), travel_dir=(1, -1, 0))).status == "ok"
        ctl.exchange(RawReading(60, (2000.0, 10.0, 10.0)))  # outside the volume
    return tmp_path / "s.mcap"


def test_replay_same_grid_matches(session) -> None:
    report = replay_offline(session)
    assert report.readings == 61 and report.compared == 60
    assert report.max_abs_diff_um < 0.002  # 1 nm quantisation on the wire
    assert report.status_agree == 61
    assert report.grid_sha256 == report.session_grid_sha256


def test_replay_other_grid_reports_differences(session, tmp_path) -> None:
    coarse = npl_grid_path((5, 5, 4))
    report = replay_offline(session, coarse)
    assert report.grid_sha256 != report.session_grid_sha256
    assert report.compared == 60 and report.max_abs_diff_um > 0.01
    out = tmp_path / "r.json"
    proc = cli("replay", session, "--grid", coarse, "--json", out)
    assert proc.returncode == 0, proc.stderr
    assert "max |replayed − sent|" in proc.stdout
    assert json.loads(out.read_text())["compared"] == 60


def test_replay_errors_name_the_problem(tmp_path) -> None:
    with pytest.raises(ReplayError, match="no MCAP file"):
        replay_offline(tmp_path / "nothing.mcap")


def test_replay_to_bus_reaches_a_running_daemon(session) -> None:
    cfg = base_config(channel())
    with daemon_and_controller(cfg) as (d, _ctl, _bus):
        bus = can.Bus(interface="virtual", channel=cfg.can.channel)
        try:
            sent = replay_to_bus(session, bus, speed=0)
        finally:
            bus.shutdown()
        assert sent.sent >= 61 * 3 + 4
        assert sent.by_can_id == 0 and sent.note is None  # every frame carries its direction
        t0 = time.monotonic()
        while d.metrics.answered < 61 and time.monotonic() - t0 < 5:
            time.sleep(0.01)
        assert d.metrics.answers.get("ok") == 60
        assert d.metrics.answers.get("outside_volume") == 1


def test_replay_reads_a_cut_session_with_a_one_line_warning(session, tmp_path, capsys) -> None:
    """A session cut by a crash replays up to the break; the CLI says so in one line. Oracle:
    the chunk index of the complete file (the readings in the chunks before the cut)."""
    from mcap.reader import make_reader
    from mcap.records import Chunk, Message
    from mcap.stream_reader import StreamReader, breakup_chunk

    from cmm_comp.cli.main import main
    from cmm_comp.cli.sessionlog.reader import read_messages
    from cmm_comp.daemon.sessionlog.writer import SessionWriter

    small = tmp_path / "small-chunks.mcap"  # the same session in many small chunks
    with SessionWriter(small, chunk_size=3000) as lg:
        for m in read_messages(session).messages:
            lg.log(m.topic, m.payload, m.log_time_ns)
    with open(small, "rb") as f:
        indexes = sorted(
            make_reader(f).get_summary().chunk_indexes, key=lambda c: c.chunk_start_offset
        )
        f.seek(0)
        chunks = [r for r in StreamReader(f, emit_chunks=True).records if isinstance(r, Chunk)]
    assert len(chunks) >= 4
    keep = len(chunks) // 2  # cut inside chunk number `keep`
    cut_at = indexes[keep].chunk_start_offset + indexes[keep].chunk_length // 2
    corrected_ids = {
        c.id for c in breakup_chunk(chunks[0]) if getattr(c, "topic", "") == "/cmm/corrected"
    }
    expected = sum(
        isinstance(r, Message) and r.channel_id in corrected_ids
        for c in chunks[:keep]
        for r in breakup_chunk(c)
    )
    assert 0 < expected < 61
    cut = tmp_path / "cut.mcap"
    cut.write_bytes(small.read_bytes()[:cut_at])
    report = replay_offline(cut)
    assert report.truncated and report.readings == expected
    assert main(["replay", str(cut)]) == 0
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "cut by a crash" in err and f"the {expected} readings" in err


def test_replay_counts_a_logged_answer_that_is_not_a_number(session, monkeypatch, capsys) -> None:
    """A damaged log whose corrected answer holds NaN / inf (the logger never writes one) is
    not compared and is counted; the other answers compare as before, every figure finite and
    the JSON standard. Oracle: the two answers doctored here."""
    from cmm_comp.cli.main import main
    from cmm_comp.cli.sessionlog import replay as replay_mod
    from cmm_comp.cli.sessionlog.reader import read_messages

    res = read_messages(session)
    corrected = [m for m in res.messages if m.topic == "/cmm/corrected"]
    corrected[3].payload["x_mm"] = float("nan")
    corrected[7].payload["z_mm"] = float("inf")
    monkeypatch.setattr(replay_mod, "read_messages", lambda *_a, **_k: res)
    report = replay_offline(session)
    assert report.sent_not_finite == 2 and report.compared == 58
    assert report.max_abs_diff_um < 0.002 and np.isfinite(report.rms_diff_um)
    assert "2 answer(s) logged as corrected" in (report.warning or "")

    def strict(token: str) -> float:
        raise ValueError(token)

    text = json.dumps(report.as_dict())
    assert json.loads(text, parse_constant=strict)["sent_not_finite"] == 2
    assert main(["replay", str(session)]) == 0
    captured = capsys.readouterr()
    assert "not a finite number" in captured.err
