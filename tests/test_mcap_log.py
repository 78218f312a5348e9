"""SessionWriter + sessionlog.reader: round trip against the mcap package's own reader, rolling,
non-blocking behaviour with a slow sink, writer errors, and reading cut files."""

from __future__ import annotations

import io
import json
import shutil
import threading
import time
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from mcap.reader import make_reader

from cmm_comp.cli.sessionlog.reader import load_session, read_messages, session_files
from cmm_comp.daemon.sessionlog.writer import SessionWriter
from cmm_comp.protocol.session_topics import TOPIC_SCHEMAS, check_message, stamp_from_ns

T0_NS = 1_700_000_000_123_456_789


def sample(topic: str, i: int) -> dict[str, Any]:
    """A representative payload of ``topic`` (without stamp: the logger adds it)."""
    return {
        "/cmm/raw": {
            "seq": i,
            "x_mm": 100.0 + i * 0.25,
            "y_mm": -3.5,
            "z_mm": 1e-3 * i,
            "dir_x": 0.0,
            "dir_y": 0.0,
            "dir_z": -1.0,
            "probe": "P1",
        },
        "/cmm/temperature": {"sensor": f"pt100-{i % 3}", "role": "T_x", "temp_C": 20.0 + i / 7},
        "/cmm/corrected": {
            "seq": i,
            "x_mm": 100.001,
            "y_mm": -3.5,
            "z_mm": 0.0,
            "status": "ok",
            "dx_um": 1.5,
            "dy_um": -0.25,
            "dz_um": 0.0,
            "latency_us": 42.0 + i,
        },
        "/cmm/status": {"state": "running", "detail": f"step {i}", "grid_sha256": "ab" * 32},
        "/cmm/can_rx": {
            "arbitration_id": 0x181,
            "is_extended": False,
            "dlc": 8,
            "data": bytes(range(i % 8, i % 8 + 8)).hex(),
            "bus_stamp": stamp_from_ns(T0_NS + i),
            "channel": "vcan0",
        },
        "/cmm/can_tx": {
            "arbitration_id": 0x1ABCDEF0,
            "is_extended": True,
            "dlc": 2,
            "data": "beef",
            "bus_stamp": stamp_from_ns(T0_NS - i),
        },
        "/cmm/modbus": {
            "op": "write",
            "function_code": 16,
            "device_id": 1,
            "address": 100,
            "count": 3,
            "values": [i % 65536, 0, 65535],
            "ok": True,
        },
        "/cmm/grid": {
            "sha256": "cd" * 32,
            "machine": "demo",
            "model": "gantry",
            "steps": [20, 20, 10],
            "path": "/tmp/m.grid",
            "loaded_at": stamp_from_ns(T0_NS),
        },
        "/cmm/counters": {
            "period_s": 1.0,
            "counters": {"frames_rx": i, "answers_ok": 2 * i},
            "latency_edges_us": [0, 50, 100, 1e9],
            "latency_counts": [i, 2, 0],
        },
        "/cmm/log_error": {
            "topic": "/cmm/raw",
            "error": "ValueError: x_mm: nan is not finite",
            "payload": f"({i}, nan)",
            "log_time": stamp_from_ns(T0_NS + i),
        },
    }[topic]


def without_log_counters(topic: str, payload: dict[str, Any]) -> dict[str, Any]:
    """``payload`` without the ``mcap_*`` counters the writer adds to ``/cmm/counters`` (tested
    on their own in tests/test_mcap_overload.py)."""
    if topic != "/cmm/counters":
        return payload
    counters = {k: v for k, v in payload["counters"].items() if not k.startswith("mcap_")}
    return {**payload, "counters": counters}


def test_every_topic_round_trips_against_mcap_reader(tmp_path: Path) -> None:
    path = tmp_path / "one.mcap"
    n = 50
    sent = []
    with SessionWriter(path, flush_period_s=0.05, chunk_size=2048, metadata={"machine": "demo"}):
        pass  # an empty session is a valid file too
    assert read_messages(path).messages == []
    path.unlink()
    with SessionWriter(path, flush_period_s=0.05, chunk_size=2048) as logger:
        for i in range(n):
            for topic in TOPIC_SCHEMAS:
                t_ns = T0_NS + (i * len(TOPIC_SCHEMAS) + len(sent) % 9) * 1000
                payload = sample(topic, i)
                logger.log(topic, payload, log_time_ns=t_ns)
                sent.append((topic, t_ns, {**payload, "stamp": stamp_from_ns(t_ns)}))
    assert logger.stop(1.0) and logger.error is None
    assert logger.stats().written == len(sent) and logger.stats().dropped == 0

    # oracle: the mcap package's seeking reader (needs a complete summary) + json
    with open(path, "rb") as f:
        reader = make_reader(f)
        summary = reader.get_summary()
        assert summary is not None and summary.statistics.message_count == len(sent)
        got = [
            (c.topic, m.log_time, without_log_counters(c.topic, json.loads(m.data)))
            for s, c, m in reader.iter_messages(log_time_order=False)
        ]
        assert all(s.encoding == "jsonschema" for s in summary.schemas.values())
        assert {c.message_encoding for c in summary.channels.values()} == {"json"}
        f.seek(0)
        meta = {m.name: m.metadata for m in make_reader(f).iter_metadata()}
    assert got == sent
    assert meta["session"]["file"] == "one.mcap" and "session_end" in meta
    for topic, _, payload in got:
        check_message(topic, payload)

    ours = read_messages(path)
    assert not ours.truncated and ours.error is None
    assert [
        (m.topic, m.log_time_ns, without_log_counters(m.topic, m.payload)) for m in ours.messages
    ] == sent
    raw_only = read_messages(path, topics=["/cmm/raw"]).messages
    assert [m.payload["seq"] for m in raw_only] == list(range(n))

    session = load_session(path)
    assert session.raw.xyz_mm.shape == (n, 3)
    np.testing.assert_array_equal(session.raw.seq, np.arange(n))
    np.testing.assert_allclose(session.raw.xyz_mm[:, 0], 100.0 + np.arange(n) * 0.25)
    assert list(session.corrected.status) == ["ok"] * n
    np.testing.assert_allclose(session.corrected.d_um[0], [1.5, -0.25, 0.0])
    np.testing.assert_allclose(session.temperature.temp_C, 20.0 + np.arange(n) / 7)
    assert session.raw.stamp_ns[0] == sent[0][1]


def test_rolling_by_size_keeps_every_seq_in_order(tmp_path: Path) -> None:
    n = 3000
    with SessionWriter(tmp_path, roll_bytes=16_000, chunk_size=2048, flush_period_s=0.05) as lg:
        for i in range(n):
            lg.log("/cmm/raw", sample("/cmm/raw", i))
            if i % 500 == 0:
                time.sleep(0.01)
    files = session_files(tmp_path)
    assert len(files) >= 3 and files == lg.files
    assert all(f.name.startswith("session-") and f.name.endswith(".mcap") for f in files)
    for f in files:  # every rolled file is complete on its own
        with open(f, "rb") as fh:
            assert make_reader(fh).get_summary() is not None
    res = read_messages(tmp_path)
    assert not res.truncated
    assert [m.payload["seq"] for m in res.messages] == list(range(n))
    assert len(read_messages(str(tmp_path / "session-*.mcap")).messages) == n
    np.testing.assert_array_equal(load_session(tmp_path).raw.seq, np.arange(n))


def test_session_files_orders_numerically(tmp_path: Path) -> None:
    for name in (
        "session-20250101T000000-1000.mcap",
        "session-20250101T000000-999.mcap",
        "session-20250101T000000-002.mcap",
    ):
        (tmp_path / name).write_bytes(b"")
    assert [p.name[-9:] for p in session_files(tmp_path)] == ["-002.mcap", "-999.mcap", "1000.mcap"]
    with pytest.raises(FileNotFoundError, match="no MCAP file"):
        session_files(tmp_path / "nothing-*.mcap")


def test_argument_errors(tmp_path: Path) -> None:
    with pytest.raises(ValueError, match="rolling needs a directory"):
        SessionWriter(tmp_path / "x.mcap", roll_bytes=10)
    with pytest.raises(ValueError, match="flush_period_s=0"):
        SessionWriter(tmp_path, flush_period_s=0)
    with SessionWriter(tmp_path / "y.mcap") as lg, pytest.raises(KeyError, match="/cmm/nope"):
        lg.log("/cmm/nope", {})
    first = (tmp_path / "y.mcap").read_bytes()
    with SessionWriter(tmp_path / "y.mcap") as lg2:  # never overwrites a session: rotates
        pass
    assert lg2.files == (tmp_path / "y.1.mcap",)
    assert (tmp_path / "y.mcap").read_bytes() == first


class SlowStream(io.RawIOBase):
    """A file sink whose every write takes ``delay_s`` (a stalled disk or NFS)."""

    def __init__(self, path: Path, delay_s: float, fail_after: int | None = None) -> None:
        self._f = open(path, "xb")  # noqa: SIM115 - closed by close()
        self._delay_s, self._fail_after, self._writes = delay_s, fail_after, 0

    def writable(self) -> bool:
        return True

    def write(self, b: Any) -> int:
        self._writes += 1
        if self._fail_after is not None and self._writes > self._fail_after:
            raise OSError(28, "No space left on device (simulated)")
        time.sleep(self._delay_s)
        return self._f.write(b)

    def tell(self) -> int:
        return self._f.tell()

    def close(self) -> None:
        self._f.close()
        super().close()


def test_writer_errors_reach_on_error_and_status(tmp_path: Path) -> None:
    seen: list[BaseException] = []
    got_error = threading.Event()

    def on_error(exc: BaseException) -> None:
        seen.append(exc)
        got_error.set()

    lg = SessionWriter(
        tmp_path / "full.mcap",
        chunk_size=256,
        flush_period_s=0.01,
        on_error=on_error,
        opener=lambda p: SlowStream(p, 0.0, fail_after=6),
    )
    for i in range(2000):
        lg.log("/cmm/raw", sample("/cmm/raw", i))
    assert got_error.wait(2.0)
    assert lg.stop(2.0)
    assert isinstance(seen[0], OSError) and lg.error is seen[0] and not lg.healthy
    assert lg.log("/cmm/raw", sample("/cmm/raw", 1)) is False
    # an unencodable payload is reported and counted, and the logger carries on
    seen.clear()
    with SessionWriter(tmp_path / "nan.mcap", on_error=seen.append) as lg2:
        lg2.log("/cmm/raw", {"seq": 0, "x_mm": float("nan"), "y_mm": 0.0, "z_mm": 0.0})
        lg2.log("/cmm/raw", sample("/cmm/raw", 1))
    assert lg2.stats().encode_errors == 1 and lg2.stats().written == 1
    assert "not JSON-encodable" in str(seen[0])


def test_cut_anywhere_reads_a_prefix_and_never_raises(tmp_path: Path) -> None:
    full = tmp_path / "full.mcap"
    with SessionWriter(full, chunk_size=600, flush_period_s=10.0) as lg:
        for i in range(300):
            lg.log("/cmm/raw", sample("/cmm/raw", i), log_time_ns=T0_NS + i)
    seqs = [m.payload["seq"] for m in read_messages(full).messages]
    assert seqs == list(range(300))
    data = full.read_bytes()
    cut = tmp_path / "cut.mcap"
    best = 0
    for size in [*range(0, 64), *range(64, len(data) - 1, 173), len(data) - 1]:
        cut.write_bytes(data[:size])
        res = read_messages(cut)
        got = [m.payload["seq"] for m in res.messages]
        assert res.truncated and res.error is not None, size
        assert got == seqs[: len(got)], size  # a prefix, nothing invented
        assert len(got) >= best, size  # more bytes never give fewer messages
        best = len(got)
    assert best > 250  # only the tail chunk(s) are lost
    shutil.copy(full, cut)
    assert not read_messages(cut).truncated


def test_rolling_by_time(tmp_path: Path) -> None:
    with SessionWriter(tmp_path, roll_s=0.1, flush_period_s=0.05) as lg:
        for i in range(40):
            lg.log("/cmm/raw", sample("/cmm/raw", i))
            time.sleep(0.01)
    assert len(lg.files) >= 2
    res = read_messages(tmp_path)
    assert [m.payload["seq"] for m in res.messages] == list(range(40)) and not res.truncated
    indexes = [int(meta["file_index"]) for name, meta in res.metadata if name == "session"]
    assert indexes == list(range(len(lg.files)))
