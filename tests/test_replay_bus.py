"""``cmm-comp replay --to-bus`` re-sends what the controller sent, never the daemon's answers.

On ``udp_multicast`` every node receives its own frames back, so the daemon's ``/cmm/can_rx``
holds its own answers, statuses and heartbeats too. A real session (``udp_session`` in
conftest.py): the daemon as a subprocess, a controller whose bus counts every frame it sends
(the oracle: the controller's side, not our log reader). Then the documented command re-sends the log, and an independent
listener (``tests/can_listener.py``: its own process and python-can bus, no cmm-comp import)
records every frame id on the bus: it must see exactly what the controller sent, id by id.
The same for a log without the ``direction`` field (written with the ``mcap`` library from
the session, as a log of an earlier version looks): replay sorts by CAN id and says so.
"""

from __future__ import annotations

import json
import subprocess
import sys
from collections import Counter
from pathlib import Path

import pytest
from mcap.reader import make_reader
from mcap.writer import Writer
from test_daemon_support import MCAST_GROUP, free_udp_port

from cmm_comp.protocol.can_ids import CanIds

LISTENER = Path(__file__).resolve().parent / "can_listener.py"
# the session fixtures (npm ci, a daemon run of 300 readings, the demo) run inside the first
# test that uses them: more than the suite's default 120 s on a loaded 2-core machine
pytestmark = pytest.mark.timeout(900)
IDS = CanIds()


def _daemon_frames_logged(path: Path) -> int:
    """``/cmm/can_rx`` frames on the daemon's ids (read with the ``mcap`` library)."""
    with open(path, "rb") as f:
        return sum(
            json.loads(m.data)["arbitration_id"] in IDS.daemon_tx_ids()
            for _, _, m in make_reader(f).iter_messages(topics=["/cmm/can_rx"])
        )


def _replay_and_listen(path: Path) -> tuple[Counter[int], subprocess.CompletedProcess[str]]:
    """Run the documented ``replay --to-bus`` command on a fresh bus with the independent
    listener on it; returns the ids the listener saw and the replay's result."""
    port = free_udp_port()
    bus = ["--interface", "udp_multicast", "--channel", MCAST_GROUP]
    listener = subprocess.Popen(
        [sys.executable, str(LISTENER), *bus, "--option", f"port={port}"],
        stdin=subprocess.PIPE,
        stdout=subprocess.PIPE,
        text=True,
    )
    try:
        assert listener.stdout is not None and listener.stdout.readline().strip() == "ready"
        replay = subprocess.run(
            # the documented command (docs/daemon.md), on the test's bus
            [
                sys.executable,
                "-m",
                "cmm_comp.cli",
                "replay",
                str(path),
                "--to-bus",
                *bus,
                "--bus-option",
                f"port={port}",
            ],
            capture_output=True,
            text=True,
            timeout=300,
        )
        assert replay.returncode == 0, replay.stderr
        out, _ = listener.communicate("", timeout=30)  # closes its stdin: it reports
    finally:
        if listener.poll() is None:
            listener.kill()
            listener.wait(10)
    seen = json.loads(out.splitlines()[-1])
    assert seen["errors"] == []
    return Counter({int(k): v for k, v in seen["ids"].items()}), replay


def test_replay_sends_exactly_the_controllers_frames(udp_session) -> None:
    mcap, sent = udp_session.mcap, udp_session.sent
    # the bus echoed the daemon's frames and the daemon logged them: without the fix, replay
    # re-sent these (the test could fail)
    assert _daemon_frames_logged(mcap) > 4 * udp_session.readings
    seen, replay = _replay_and_listen(mcap)
    assert seen == sent
    assert f"re-sent {sum(sent.values())} frames the controller sent" in replay.stdout
    assert "note:" not in replay.stderr


def _without_direction(src: Path, dst: Path) -> int:
    """Copy ``src`` with the ``mcap`` library, dropping ``direction`` from every CAN frame
    (a log as earlier versions wrote it); returns how many frames had it."""
    dropped = 0
    with open(src, "rb") as f, open(dst, "wb") as out:
        reader = make_reader(f)
        summary = reader.get_summary()
        assert summary is not None
        w = Writer(out)
        w.start()
        schema_ids = {
            sid: w.register_schema(s.name, s.encoding, s.data) for sid, s in summary.schemas.items()
        }
        channel_ids = {
            cid: w.register_channel(c.topic, c.message_encoding, schema_ids[c.schema_id])
            for cid, c in summary.channels.items()
        }
        for _, channel, m in reader.iter_messages(log_time_order=False):
            data = m.data
            if channel.topic in ("/cmm/can_rx", "/cmm/can_tx"):
                payload = json.loads(data)
                dropped += payload.pop("direction", None) is not None
                data = json.dumps(payload).encode()
            w.add_message(channel_ids[channel.id], m.log_time, data, m.publish_time)
        w.finish()
    return dropped


def test_an_older_log_is_sorted_by_can_id_and_says_so(udp_session, tmp_path) -> None:
    mcap, sent = udp_session.mcap, udp_session.sent
    old = tmp_path / "old.mcap"
    assert _without_direction(mcap, old) > 0
    seen, replay = _replay_and_listen(old)
    assert seen == sent
    assert "carry no direction" in replay.stderr and "by CAN id" in replay.stderr
