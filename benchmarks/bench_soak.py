"""Soak: the daemon as a subprocess for a long run at a steady rate, with injected faults.

Run: ``.venv/bin/python benchmarks/bench_soak.py [--duration-s 3600] [--rate-hz 1000]``
(not in CI). Prints a table and writes ``benchmarks/results/soak.json``.

The daemon (``cmm-comp daemon``, MCAP on with the default writer, Modbus on) talks to a
simulated controller over python-can ``udp_multicast`` (two processes). Every round the
controller sends new temperatures (slowly drifting), then a quarter second's worth of readings
paced at ``--rate-hz``. Faults, spread over the run:

* bad frames (reserved id, wrong length, remote, error, axis field ≠ id) every 2 s;
* a repeated temperature counter carrying another value every 5 s (must be ignored);
* stale temperature: no temperatures for ``stale_s`` + 1 s once a minute;
* a SIGHUP grid reload every 30 s;
* a Modbus flood every 20 s: a connection sending garbage, then one sending 200 valid FC3 reads.

Checks, each against an oracle independent of the daemon's pipeline:

* wrong-but-ok: every ``ok`` answer equals the correction of the grid file (loaded here with
  ``CorrectionGrid.load``, corrected with ``grid.correct``) at the indicated position, the stylus
  and the temperatures this controller last sent as new samples, to ±2 nm;
* unlogged: every answer to a reading the controller received is in the MCAP (read with the
  ``mcap`` library, ``/cmm/corrected``: seq, status, position; ``incomplete_reading`` answers
  are events, not readings);
* memory: RSS of the daemon and of its MCAP writer child (``/proc``), sampled every 5 s; growth
  after the warm-up (the first half, at most 10 min) as a least-squares slope, MiB/h (a
  few minutes' run still shows warm-up steps: the 1 h run is the figure). Also the slope of
  the anonymous part alone (``RssAnon``: heap and allocator arenas, where a leak shows; the
  rest of RSS is shared-library pages faulted in as code paths first run, e.g. the first
  reload or Modbus flood).
"""

from __future__ import annotations

import argparse
import json
import math
import os
import platform
import signal
import socket
import struct
import subprocess
import sys
import tempfile
import threading
import time
from collections import Counter
from pathlib import Path
from typing import Any

import can
import numpy as np

ROOT = Path(__file__).resolve().parents[1]

from cmm_comp.compensation.grid import CorrectionGrid  # noqa: E402
from cmm_comp.compensation.machine import Machine  # noqa: E402
from cmm_comp.protocol import CanIds, TemperatureSample, encode_message  # noqa: E402
from cmm_comp.protocol.codes import NM_PER_MM  # noqa: E402
from cmm_comp.protocol.modbus_map import OUTPUT_SIZE, OUTPUT_START  # noqa: E402
from cmm_comp.sim_controller.controller import CanController, RawReading  # noqa: E402

RESULTS = ROOT / "benchmarks" / "results" / "soak.json"
GROUP = "ff11:7079:7468:6f6e:6465:6d6f:6d63:6173"
IDS = CanIds()
STYLUS = (0.0, 0.0, -120.0)
SENSORS = {0: "T_x", 1: "T_y", 2: "T_z", 3: "T_wp"}
STALE_S = 3.0
MIB = 1024.0 * 1024.0


def free_port(kind: int) -> int:
    with socket.socket(socket.AF_INET, kind) as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


def rss_mib(pid: int, field: str = "VmRSS") -> float:
    """A memory field of ``pid``'s ``/proc/PID/status``, MiB (nan when it is gone): ``VmRSS``
    (resident set), ``RssAnon`` (its anonymous part: the heap, what a leak grows) or
    ``RssFile`` (mapped files: shared libraries paged in as code paths first run)."""
    try:
        with open(f"/proc/{pid}/status") as f:
            for line in f:
                if line.startswith(field + ":"):
                    return int(line.split()[1]) / 1024.0
    except OSError:
        pass
    return math.nan


def children(pid: int) -> list[int]:
    out: list[int] = []
    try:
        for tid in os.listdir(f"/proc/{pid}/task"):
            with open(f"/proc/{pid}/task/{tid}/children") as f:
                out += [int(c) for c in f.read().split()]
    except OSError:
        pass
    return out


def slope_mib_per_h(samples: list[tuple[float, float]], warmup_s: float) -> float:
    pts = [(t, v) for t, v in samples if t >= warmup_s and math.isfinite(v)]
    if len(pts) < 3:
        return math.nan
    t = np.array([p[0] for p in pts])
    v = np.array([p[1] for p in pts])
    return float(np.polyfit(t, v, 1)[0] * 3600.0)


def temperatures_at(t_s: float) -> dict[int, float]:
    """The drifting temperatures of the run (°C), rounded to the 0.001 °C the frame carries."""
    base = {0: 20.4, 1: 20.6, 2: 20.2, 3: 20.8}
    return {s: round(v + 0.3 * math.sin(t_s / 300.0 + s), 3) for s, v in base.items()}


class Faults:
    """The fault injectors (each counts what it did)."""

    def __init__(self, bus: can.BusABC, daemon: subprocess.Popen[bytes], modbus_port: int):
        self.bus, self.daemon, self.modbus_port = bus, daemon, modbus_port
        self.counts: Counter[str] = Counter()
        self.modbus_replies = 0
        self.modbus_bad_replies = 0

    def bad_frames(self) -> None:
        b = IDS.block_start
        for msg in (
            can.Message(arbitration_id=b + 0x5, data=bytes(8), is_extended_id=False),
            can.Message(arbitration_id=b + 0x0, data=bytes(5), is_extended_id=False),
            can.Message(arbitration_id=b, is_remote_frame=True, is_extended_id=False),
            can.Message(arbitration_id=b, is_error_frame=True, is_extended_id=False),
            can.Message(arbitration_id=b + 0x1, data=bytes(8), is_extended_id=False),
        ):
            self.bus.send(msg, timeout=1.0)
        self.counts["bad_frames"] += 5

    def reload(self) -> None:
        self.daemon.send_signal(signal.SIGHUP)
        self.counts["reloads"] += 1

    def modbus_flood(self) -> None:
        try:
            with socket.create_connection(("127.0.0.1", self.modbus_port), timeout=2) as s:
                s.sendall(os.urandom(300))
                s.settimeout(1.0)
                try:
                    while s.recv(4096):
                        pass
                except OSError:
                    pass
            with socket.create_connection(("127.0.0.1", self.modbus_port), timeout=2) as s:
                s.settimeout(2.0)
                for tid in range(200):
                    req = struct.pack(">HHHBBHH", tid, 0, 6, 1, 3, OUTPUT_START, OUTPUT_SIZE)
                    s.sendall(req)
                    head = _recv_exact(s, 7)
                    _, _, length, _ = struct.unpack(">HHHB", head)
                    body = _recv_exact(s, length - 1)
                    ok = struct.unpack(">H", head[:2])[0] == tid and body[0] == 3
                    self.modbus_replies += ok
                    self.modbus_bad_replies += not ok
            self.counts["modbus_floods"] += 1
        except OSError as exc:
            self.counts[f"modbus_error_{type(exc).__name__}"] += 1


def _recv_exact(s: socket.socket, n: int) -> bytes:
    buf = b""
    while len(buf) < n:
        chunk = s.recv(n - len(buf))
        if not chunk:
            raise ConnectionError("closed")
        buf += chunk
    return buf


def expected_nm(
    grid: CorrectionGrid, pts_mm: np.ndarray, temps: dict[str, float]
) -> tuple[np.ndarray, np.ndarray]:
    out, status = grid.correct(pts_mm, np.array(STYLUS), temps, None)
    return np.round(out * NM_PER_MM), status


def run(duration_s: float, rate_hz: float, tmp: Path) -> dict[str, Any]:
    machine = Machine.from_toml(ROOT / "examples" / "machines" / "npl-bridge.toml")
    grid_path = tmp / "npl.grid"
    CorrectionGrid.build(machine, steps=machine.volume.steps).save(grid_path)
    grid = CorrectionGrid.load(grid_path)  # the oracle's own copy
    can_port, mb_port = free_port(socket.SOCK_DGRAM), free_port(socket.SOCK_STREAM)
    mcap = tmp / "soak.mcap"
    cfgf = tmp / "soak.toml"
    cfgf.write_text(
        f'[grid]\npath = "{grid_path}"\nstylus_mm = {list(STYLUS)}\n'
        "allow_unsigned = true\nallow_any_machine = true\n"
        f'[can]\ninterface = "udp_multicast"\nchannel = "{GROUP}"\n'
        f"[can.options]\nport = {can_port}\n"
        f"[modbus]\nenabled = true\nport = {mb_port}\n[metrics]\nenabled = false\n"
        f"[temperatures]\nstale_s = {STALE_S}\n"
        f'[mcap]\npath = "{mcap}"\n'
    )
    cmd = [sys.executable, "-m", "cmm_comp.cli", "daemon", "--config", str(cfgf)]
    cmd += ["--log-level", "error"]
    daemon = subprocess.Popen(cmd, cwd=ROOT, stdout=subprocess.DEVNULL)
    rss: dict[str, list[tuple[float, float]]] = {"daemon": [], "writer": []}
    anon: dict[str, list[tuple[float, float]]] = {"daemon": [], "writer": []}
    answers: list[tuple[int, str, tuple[float, float, float] | None, tuple[float, ...]]] = []
    sent_temps: dict[str, float] = {}
    wrong_ok: list[dict[str, Any]] = []
    statuses: Counter[str] = Counter()
    rng = np.random.default_rng(7)
    with can.Bus(interface="udp_multicast", channel=GROUP, port=can_port) as bus:
        ctl = CanController(bus, answer_timeout_s=2.0).start()
        faults = Faults(bus, daemon, mb_port)
        t_wait = time.monotonic()
        while ctl.heartbeat is None:
            if daemon.poll() is not None or time.monotonic() - t_wait > 60:
                raise RuntimeError("daemon did not start")
            time.sleep(0.05)
        writer_pid = next(iter(children(daemon.pid)), 0)
        counters = dict.fromkeys(SENSORS, 0)
        t0 = time.monotonic()
        seq = 0
        next_rss = next_bad = next_repeat = next_reload = next_flood = 0.0
        next_stale = 60.0
        stale_until = -1.0
        while (now := time.monotonic() - t0) < duration_s:
            if now >= next_rss:
                rss["daemon"].append((now, rss_mib(daemon.pid)))
                rss["writer"].append((now, rss_mib(writer_pid) if writer_pid else math.nan))
                anon["daemon"].append((now, rss_mib(daemon.pid, "RssAnon")))
                anon["writer"].append(
                    (now, rss_mib(writer_pid, "RssAnon") if writer_pid else math.nan)
                )
                next_rss += 5.0
            if now >= next_stale:
                stale_until, next_stale = now + STALE_S + 1.0, next_stale + 60.0
                faults.counts["stale_periods"] += 1
            if now >= stale_until:
                temps = temperatures_at(now)
                for s, v in temps.items():
                    counters[s] = (counters[s] + 1) & 0xFFFF
                    bus.send(encode_message(TemperatureSample.from_celsius(s, v, counters[s]), IDS))
                sent_temps = {SENSORS[s]: v for s, v in temps.items()}
            if now >= next_repeat:  # the previous counter again, another value: ignored
                bus.send(encode_message(TemperatureSample.from_celsius(3, 25.0, counters[3]), IDS))
                faults.counts["repeated_counters"] += 1
                next_repeat += 5.0
            if now >= next_bad:
                faults.bad_frames()
                next_bad += 2.0
            if now >= next_reload and now > 0:
                faults.reload()
            if now >= next_reload:
                next_reload += 30.0
            if now >= next_flood and now > 0:
                threading.Thread(target=faults.modbus_flood, daemon=True).start()
            if now >= next_flood:
                next_flood += 20.0
            n = max(1, int(rate_hz / 4))  # a quarter second of readings per round
            pts = rng.uniform([20, 20, 20], [880, 1130, 380], (n, 3))
            rs = []
            for p in pts:
                rs.append(RawReading(seq, (float(p[0]), float(p[1]), float(p[2]))))
                seq = (seq + 1) & 0xFFFF
            got = ctl.stream(rs, rate_hz, in_flight=8)
            sent_mm = np.array(
                [[round(c * NM_PER_MM) / NM_PER_MM for c in r.indicated_mm] for r in rs]
            )
            exp_nm, exp_status = expected_nm(grid, sent_mm, dict(sent_temps))
            for r, a, e, es in zip(rs, got, exp_nm, exp_status, strict=True):
                statuses[a.status] += 1
                if a.status == "timeout":
                    continue
                answers.append((a.seq, a.status, a.corrected_mm, r.indicated_mm))
                if a.status != "ok":
                    continue
                if a.corrected_mm is None or str(es) != "ok":
                    wrong_ok.append({"seq": a.seq, "why": f"oracle status {es}"})
                    continue
                got_nm = np.round(np.array(a.corrected_mm) * NM_PER_MM)
                if np.max(np.abs(got_nm - e)) > 2:
                    wrong_ok.append(
                        {"seq": a.seq, "got_nm": got_nm.tolist(), "expected_nm": e.tolist()}
                    )
        elapsed = time.monotonic() - t0
        ctl.stop()
        fault_counts = dict(faults.counts)
        modbus = {"replies_ok": faults.modbus_replies, "replies_bad": faults.modbus_bad_replies}
    daemon.send_signal(signal.SIGTERM)
    code = daemon.wait(60)
    logged = _logged_answers(mcap)
    unlogged = 0
    for a_seq, status, pos, _ in answers:
        if status == "incomplete_reading":  # not a reading: an event + its frames, no record
            continue
        key = (a_seq, status, _nm3(pos))
        if logged[key] > 0:
            logged[key] -= 1
        else:
            unlogged += 1
    warm = min(600.0, duration_s / 2)
    n_answers = len(answers)
    return {
        "duration_s": elapsed,
        "rate_hz": rate_hz,
        "readings": sum(statuses.values()),
        "answers": n_answers,
        "readings_per_s": sum(statuses.values()) / elapsed,
        "statuses": dict(statuses),
        "wrong_but_ok": len(wrong_ok),
        "wrong_but_ok_examples": wrong_ok[:5],
        "unlogged_answers": unlogged,
        "faults_injected": fault_counts,
        "modbus": modbus,
        "daemon_exit_code": code,
        "rss_mib": {k: [round(v, 2) for _, v in s] for k, s in rss.items()},
        "rss_growth_mib_per_h": {k: slope_mib_per_h(s, warm) for k, s in rss.items()},
        "rss_anon_mib": {k: [round(v, 2) for _, v in s] for k, s in anon.items()},
        "rss_anon_growth_mib_per_h": {k: slope_mib_per_h(s, warm) for k, s in anon.items()},
        "rss_sample_period_s": 5.0,
        "warmup_s": warm,
    }


def _nm3(pos: tuple[float, float, float] | None) -> tuple[int, ...] | None:
    return None if pos is None else tuple(round(c * NM_PER_MM) for c in pos)


def _logged_answers(path: Path) -> Counter[tuple[int, str, tuple[int, ...] | None]]:
    """(seq, status, position nm) of every /cmm/corrected record, read with ``mcap`` itself
    (the non-seeking reader: a file cut by a crash is read up to the break)."""
    from mcap.exceptions import McapError
    from mcap.records import Channel, Message
    from mcap.stream_reader import StreamReader

    out: Counter[tuple[int, str, tuple[int, ...] | None]] = Counter()
    channels: dict[int, str] = {}
    with open(path, "rb") as f:
        try:
            for rec in StreamReader(f, skip_magic=False).records:
                if isinstance(rec, Channel):
                    channels[rec.id] = rec.topic
                elif isinstance(rec, Message) and channels.get(rec.channel_id) == "/cmm/corrected":
                    p = json.loads(rec.data)
                    pos = (p["x_mm"], p["y_mm"], p["z_mm"])
                    out[(p["seq"], p["status"], _nm3(pos))] += 1
        except McapError:
            pass
    return out


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--duration-s", type=float, default=3600.0)
    ap.add_argument("--rate-hz", type=float, default=1000.0)
    args = ap.parse_args()
    with tempfile.TemporaryDirectory() as tmpd:
        r = run(args.duration_s, args.rate_hz, Path(tmpd))
    r["machine"] = platform.node()
    r["python"] = platform.python_version()
    RESULTS.parent.mkdir(parents=True, exist_ok=True)
    RESULTS.write_text(json.dumps(r, indent=2) + "\n")
    g = r["rss_growth_mib_per_h"]
    ga = r["rss_anon_growth_mib_per_h"]
    rows = [
        ("duration, s", f"{r['duration_s']:.0f}"),
        ("readings sent / answered", f"{r['readings']} / {r['answers']}"),
        ("readings/s achieved", f"{r['readings_per_s']:.0f}"),
        ("statuses", ", ".join(f"{k} {v}" for k, v in sorted(r["statuses"].items()))),
        ("wrong-but-ok answers (target 0)", str(r["wrong_but_ok"])),
        ("answers missing from the MCAP (target 0)", str(r["unlogged_answers"])),
        ("faults injected", ", ".join(f"{k} {v}" for k, v in r["faults_injected"].items())),
        (
            "Modbus flood replies ok / bad",
            f"{r['modbus']['replies_ok']} / {r['modbus']['replies_bad']}",
        ),
        ("daemon RSS growth after warm-up, MiB/h", f"{g['daemon']:+.2f}"),
        ("MCAP writer RSS growth after warm-up, MiB/h", f"{g['writer']:+.2f}"),
        ("daemon anonymous RSS growth, MiB/h", f"{ga['daemon']:+.2f}"),
        ("MCAP writer anonymous RSS growth, MiB/h", f"{ga['writer']:+.2f}"),
        ("daemon exit code after SIGTERM", str(r["daemon_exit_code"])),
    ]
    for name, value in rows:
        print(f"{name:<46} {value}")
    print(f"wrote {RESULTS}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
