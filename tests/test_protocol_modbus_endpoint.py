"""The daemon's Modbus endpoint under garbage, wrong unit ids and idle clients; identification.

Real daemon (in process, CAN off), real sockets on 127.0.0.1. Oracles: hand-packed MBAP frames
(tests/test_protocol_modbus_support.py), the pymodbus client, the daemon's Prometheus text over
HTTP, the captured log lines, the grid file's sha256 member and pyproject.toml's version.
"""

from __future__ import annotations

import asyncio
import io
import json
import math
import signal
import struct
import threading
import time
import tomllib
import urllib.request
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path

import numpy as np
import pytest
from pymodbus.client import AsyncModbusTcpClient
from pymodbus.pdu.mei_message import ReadDeviceInformationResponse
from test_daemon_support import (
    ROOT,
    STYLUS,
    base_config,
    channel,
    npl_grid_path,
    start_daemon_cli,
    trust_toml,
)
from test_protocol_modbus_support import RawClient, frame, wait_for

from cmm_comp.daemon import DaemonService
from cmm_comp.daemon.config import ConfigError, config_from_dict

READ_INFO = struct.pack(">BHH", 3, 0, 3)
INFO_RESPONSE = bytes.fromhex("03 06 0002 434d 0010")


class Lines(io.StringIO):
    """A log stream the daemon's threads may write to while the test reads it."""

    def __init__(self) -> None:
        super().__init__()
        self._lock = threading.Lock()

    def write(self, s: str) -> int:
        with self._lock:
            return super().write(s)

    def records(self) -> list[dict[str, object]]:
        with self._lock:
            text = self.getvalue()
        return [json.loads(line) for line in text.splitlines() if line.strip()]


@contextmanager
def modbus_daemon(
    with_grid: bool = True, idle_timeout_s: float = 60.0, frame_timeout_s: float = 0.2
) -> Iterator[tuple[DaemonService, int, Lines]]:
    cfg = base_config(channel())
    if not with_grid:
        cfg.grid.path = ""
    cfg.can.enabled = False
    cfg.modbus.enabled = True
    cfg.modbus.port = 0
    cfg.modbus.device_id = 1
    cfg.modbus.idle_timeout_s = idle_timeout_s
    cfg.modbus.frame_timeout_s = frame_timeout_s
    lines = Lines()
    with DaemonService(cfg.check(), events_stream=lines) as d:
        assert d.modbus is not None
        yield d, d.modbus.port, lines


def prometheus(d: DaemonService) -> str:
    assert d.metrics_server is not None
    with urllib.request.urlopen(d.metrics_server.url, timeout=10) as resp:
        return str(resp.read().decode())


def test_flood_of_garbage_and_wrong_units_logs_a_bounded_number_of_lines(
    capfd: pytest.CaptureFixture[str],
) -> None:
    garbage = [
        frame(READ_INFO[:5], protocol_id=0x1234),
        frame(READ_INFO, length=65535),
        b"\x00\x01\x00",  # 3-byte header, then silence (frame timeout 0.2 s)
    ]
    with modbus_daemon() as (d, port, lines):
        t0 = time.monotonic()
        with RawClient(port) as raw:
            raw.send(b"".join(frame(READ_INFO, tid=i, unit=7) for i in range(200)))
            raw.send(frame(READ_INFO, tid=999, unit=1))
            assert raw.response() == (999, 0, 1, INFO_RESPONSE)  # the 200 got no response
        for i in range(30):
            with RawClient(port) as raw:
                raw.send(garbage[i % 3])
                raw.wait_eof()
        assert wait_for(lambda: d.metrics.faults.get("modbus_bad_frame", 0) == 30)
        with RawClient(port) as raw:  # still serving
            assert raw.request(READ_INFO) == INFO_RESPONSE
        elapsed_s = time.monotonic() - t0
        assert d.metrics.faults["modbus_wrong_unit"] == 200
        text = prometheus(d)
        assert 'cmm_comp_faults_total{kind="modbus_wrong_unit"} 200' in text
        assert 'cmm_comp_faults_total{kind="modbus_bad_frame"} 30' in text
        records = lines.records()
    allowed = 1 + math.ceil(elapsed_s / 10.0)  # one line per kind per 10 s
    wrong = [r for r in records if r["event"] == "modbus_wrong_unit"]
    bad = [r for r in records if r["event"] == "modbus_bad_frame"]
    assert 1 <= len(wrong) <= allowed and 1 <= len(bad) <= allowed
    assert wrong[0]["unit_id"] == 7 and wrong[0]["served"] == [0, 1, 255]
    assert sum(1 for r in records if str(r["event"]).startswith("modbus_")) <= 2 + 2 * allowed
    out, err = capfd.readouterr()
    assert "Traceback" not in out + err + json.dumps(records)


def test_idle_connection_closed_and_counted() -> None:
    with modbus_daemon(idle_timeout_s=1.0) as (d, port, lines):
        with RawClient(port) as raw:
            assert raw.request(READ_INFO) == INFO_RESPONSE
            raw.wait_eof()  # the daemon closes it: no data for 1 s
        assert wait_for(lambda: d.metrics.get("modbus_idle_closed") == 1)
        assert d.metrics.get("modbus_connections") == 1
        assert 'cmm_comp_events_total{kind="modbus_idle_closed"} 1' in prometheus(d)
        assert wait_for(lambda: any(r["event"] == "modbus_idle_closed" for r in lines.records()))


def test_rejected_requests_count_in_the_daemon_block() -> None:
    with modbus_daemon() as (d, port, _lines), RawClient(port) as raw:
        assert raw.request(struct.pack(">BHH", 3, 0, 0)) == b"\x83\x03"
        assert raw.request(struct.pack(">BHH", 5, 0, 0xFF00)) == b"\x85\x01"
        assert raw.request(b"\x41") == b"\xc1\x01"
        out = raw.request(struct.pack(">BHH", 3, 317, 7))
        assert struct.unpack(">7H", out[2:])[6] == 3  # INPUT_ERRORS (323)
        assert d.metrics.faults["modbus_rejected_request"] == 3


def _read_identity(port: int, read_code: int) -> dict[int, bytes]:
    async def main() -> dict[int, bytes]:
        client = AsyncModbusTcpClient("127.0.0.1", port=port, timeout=5, retries=0)
        try:
            assert await client.connect()
            rr = await client.read_device_information(read_code=read_code, device_id=1)
            assert isinstance(rr, ReadDeviceInformationResponse) and rr.more_follows == 0
            return dict(rr.information)
        finally:
            client.close()

    return asyncio.run(main())


def test_device_identification_names_package_version_and_grid() -> None:
    version = tomllib.loads((ROOT / "pyproject.toml").read_text())["project"]["version"]
    with modbus_daemon() as (d, port, _lines):
        basic = _read_identity(port, 1)
        extended = _read_identity(port, 3)
        grid_file = Path(d.config.grid.path)
        assert d.grids.current is not None
        daemon_sha = d.grids.current.sha256
    assert basic == {0: b"cmm-comp project", 1: b"cmm-comp", 2: version.encode()}
    assert extended[0x04] == b"cmm-comp volumetric compensation daemon"
    assert extended[0x05] == b"Modbus register map v2"
    loaded_sha = extended[0x80].decode()
    with np.load(grid_file) as npz:  # the grid file's own sha256 member, read with numpy
        stored_sha = npz["sha256"].tobytes().decode("ascii")
    assert loaded_sha == daemon_sha == stored_sha and len(stored_sha) == 64


def test_device_identification_without_grid() -> None:
    with modbus_daemon(with_grid=False) as (_d, port, _lines):
        assert _read_identity(port, 3)[0x80] == b""


@pytest.mark.parametrize(
    ("table", "message"),
    [
        ({"idle_timeout_s": -1.0}, "modbus.idle_timeout_s = -1.0"),
        ({"idle_timeout_s": math.nan}, "modbus.idle_timeout_s = nan"),
        ({"idle_timeout_s": math.inf}, "modbus.idle_timeout_s = inf"),
        ({"frame_timeout_s": 0.0}, "modbus.frame_timeout_s = 0.0"),
        ({"frame_timeout_s": math.nan}, "modbus.frame_timeout_s = nan"),
    ],
)
def test_timeouts_validated(table: dict[str, float], message: str) -> None:
    with pytest.raises(ConfigError, match=message.replace(".", r"\.")):
        config_from_dict({"modbus": {"enabled": True, **table}})


def test_idle_timeout_zero_is_allowed() -> None:
    cfg = config_from_dict({"modbus": {"enabled": True, "idle_timeout_s": 0}})
    assert cfg.modbus.idle_timeout_s == 0.0 and cfg.modbus.frame_timeout_s == 1.0


def test_daemon_subprocess_log_stays_short_under_a_flood(tmp_path: Path) -> None:
    """The measured case: 200 wrong-unit requests once wrote 3,421 log lines (tracebacks)."""
    cfg = tmp_path / "daemon.toml"
    cfg.write_text(
        f'[grid]\npath = "{npl_grid_path()}"\nstylus_mm = {STYLUS}\n{trust_toml()}'
        "[can]\nenabled = false\n[modbus]\nenabled = true\nport = 0\nframe_timeout_s = 0.2\n"
        "[metrics]\nenabled = false\n"
    )
    log = tmp_path / "daemon.log"
    proc = start_daemon_cli(cfg, log)
    try:

        def listening() -> int:
            for line in log.read_text().splitlines():
                if '"modbus_listening"' in line:
                    return int(json.loads(line)["port"])
            assert proc.poll() is None, log.read_text()
            return 0

        assert wait_for(lambda: listening() > 0, timeout_s=60), log.read_text()
        port = listening()
        with RawClient(port) as raw:
            raw.send(b"".join(frame(READ_INFO, tid=i, unit=2) for i in range(200)))
            assert raw.request(READ_INFO) == INFO_RESPONSE
        for garbage in (frame(READ_INFO, protocol_id=9), frame(READ_INFO, length=65535), b"\0\1\0"):
            for _ in range(10):
                with RawClient(port) as raw:
                    raw.send(garbage)
                    raw.wait_eof()
        with RawClient(port) as raw:
            assert raw.request(READ_INFO) == INFO_RESPONSE
    finally:
        proc.send_signal(signal.SIGTERM)
        proc.wait(30)
    text = log.read_text()
    lines = text.splitlines()
    assert "Traceback" not in text
    assert sum('"modbus_wrong_unit"' in line for line in lines) == 1
    assert 1 <= sum('"modbus_bad_frame"' in line for line in lines) <= 4  # 1 per 10 s
    assert len(lines) < 40, text
