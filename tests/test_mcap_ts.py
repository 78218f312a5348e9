"""Session logs as the real consumer reads them: the official TypeScript MCAP reader.

``@mcap/core``'s ``McapIndexedReader`` is what Foxglove and Lichtblick use to open a local
file; it threw "Encountered a chunk index without message indexes and non-zero start and end
times" on every log the daemon or the demo wrote (message indexes were switched off), although
the Python reader read them. ``McapStreamReader`` is what a stream gets. Both read here
(``tests/mcap_ts/read_mcap.mjs``, packages pinned in its ``package-lock.json``; the ``mcap_ts``
fixture runs ``npm ci`` once per session) the logs of:

* the demo, run as documented (``cmm-comp demo --mcap … --json …``, in this process through the
  CLI's own ``main()``; the recoveries too): counts against the
  demo's own summary (readings the simulated controller sent);
* the daemon, a real run (``udp_session``: the daemon as a subprocess on ``udp_multicast``):
  counts against what the controller's bus sent, frame by frame;
* recovered files (``cmm-comp mcap recover``) of that log cut at several offsets and of a
  writer killed with SIGKILL: counts against the TypeScript stream reader on the cut file.

None of the expected counts comes from the project's Python reader.
"""

from __future__ import annotations

import json
import time
from pathlib import Path
from typing import Any

import pytest
from doc_commands import cli
from test_mcap_recover import acknowledged, session_writer

from cmm_comp.daemon.sessionlog.writer import LIBRARY
from cmm_comp.protocol.session_topics import TOPIC_SCHEMAS

ROOT = Path(__file__).resolve().parents[1]
# the session fixtures (npm ci, a daemon run of 300 readings, the demo) run inside the first
# test that uses them: more than the suite's default 120 s on a loaded 2-core machine
pytestmark = pytest.mark.timeout(900)


def both_readers(read: Any, path: Path, end_metadata: str = "session_end") -> dict[str, Any]:
    """Read ``path`` with the indexed and the stream reader; both must read it whole and agree.
    Returns the indexed reader's view."""
    got = read(path, "direction")
    idx, stream = got["indexed"], got["stream"]
    assert "error" not in idx, f"McapIndexedReader: {idx['error']}"
    assert "error" not in stream and stream["done"], f"McapStreamReader: {stream}"
    for key in ("topics", "schemas", "values", "metadata", "messages"):
        assert idx[key] == stream[key], key
    assert idx["chunk_indexes"] > 0 and idx["chunk_indexes_without_message_indexes"] == 0
    assert idx["statistics_message_count"] == str(idx["messages"])
    assert idx["json_errors"] == 0 and idx["out_of_order"] == 0  # JSON.parse, log-time order
    assert idx["metadata"][0] == "session" and end_metadata in idx["metadata"]
    for topic in idx["topics"]:
        assert idx["schemas"][topic] == TOPIC_SCHEMAS[topic].name
        assert idx["schema_encodings"][topic] == "jsonschema"
        assert idx["message_encodings"][topic] == "json"
    return dict(idx)


def directions(view: dict[str, Any], topic: str) -> dict[str, int]:
    """``direction`` value → count on ``topic`` (JSON text keys: ``'"rx"'``)."""
    return dict(view["values"][topic]["direction"])


def test_demo_log_reads_in_foxglove_s_reader(mcap_ts, tmp_path) -> None:
    proc = cli("demo", "--mcap", "demo.mcap", "--json", "summary.json", cwd=tmp_path)
    assert proc.returncode == 0, proc.stderr
    readings = json.loads((tmp_path / "summary.json").read_text())["readings"]
    view = both_readers(mcap_ts, tmp_path / "demo.mcap")
    assert view["library"] == LIBRARY
    topics = view["topics"]
    assert topics["/cmm/raw"] == topics["/cmm/corrected"] == readings > 100
    # a virtual bus returns no frame to its sender: everything received is the controller's
    assert directions(view, "/cmm/can_rx") == {'"rx"': topics["/cmm/can_rx"]}
    assert topics["/cmm/can_rx"] >= 3 * readings
    assert directions(view, "/cmm/can_tx") == {'"tx"': topics["/cmm/can_tx"]}
    assert topics["/cmm/can_tx"] >= 4 * readings  # 3 corrected axes and the status, at least


def test_daemon_log_reads_in_foxglove_s_reader(mcap_ts, udp_session) -> None:
    view = both_readers(mcap_ts, udp_session.mcap)
    topics, n = view["topics"], udp_session.readings
    assert topics["/cmm/raw"] == topics["/cmm/corrected"] == n
    assert topics["/cmm/temperature"] == udp_session.temperature_samples
    rx = directions(view, "/cmm/can_rx")
    assert rx['"rx"'] == sum(udp_session.sent.values())  # exactly what the controller sent
    assert rx['"tx_echo"'] >= 4 * n  # udp_multicast returned the daemon's own answers
    assert set(rx) == {'"rx"', '"tx_echo"'}
    assert directions(view, "/cmm/can_tx") == {'"tx"': topics["/cmm/can_tx"]}


def _recover(cut: Path, fixed: Path) -> None:
    proc = cli("mcap", "recover", cut, "-o", fixed)
    assert proc.returncode == 0, proc.stderr


@pytest.mark.parametrize("fraction", [0.2, 0.55, 0.9])
def test_recovered_daemon_log_reads_in_foxglove_s_reader(
    mcap_ts, udp_session, tmp_path, fraction: float
) -> None:
    data = udp_session.mcap.read_bytes()
    cut = tmp_path / "cut.mcap"
    cut.write_bytes(data[: int(len(data) * fraction)])
    before = mcap_ts(cut, "direction")
    assert "error" in before["indexed"]  # what recover is for: no summary, no index
    assert not before["stream"]["done"]
    fixed = tmp_path / "fixed.mcap"
    _recover(cut, fixed)
    view = both_readers(mcap_ts, fixed, end_metadata="recovered")
    assert view["topics"] == before["stream"]["topics"]  # every complete chunk before the cut
    assert view["values"] == before["stream"]["values"]
    assert view["topics"].get("/cmm/can_rx", 0) > 0


def test_log_of_a_killed_writer_recovers_for_foxglove_s_reader(mcap_ts, tmp_path) -> None:
    path = tmp_path / "killed.mcap"
    with session_writer(path) as lines:  # SIGKILLed on leaving
        t0 = time.monotonic()  # generous: a loaded machine
        while acknowledged(lines) < 500 and time.monotonic() - t0 < 60:
            time.sleep(0.01)
    flushed = acknowledged(lines)
    assert flushed >= 500, lines[-5:]
    cut = mcap_ts(path)
    fixed = tmp_path / "fixed.mcap"
    _recover(path, fixed)
    view = both_readers(mcap_ts, fixed, end_metadata="recovered")
    assert view["topics"] == cut["stream"]["topics"]
    assert view["topics"]["/cmm/raw"] >= flushed  # nothing the writer reported flushed is lost
