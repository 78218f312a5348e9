"""Cost of the live view (daemon/live) on the thread that feeds it, live off vs on, same run.

Run: ``.venv/bin/python benchmarks/bench_live.py [--seconds-per-case 2] [--rounds 3]``. Prints a
table and writes ``benchmarks/results/live.json``.

A feeder thread plays the CAN endpoint's bookkeeping at ``--rate-hz`` readings per second,
paced by sleeping (ECOSYSTEM.md: a spinning client steals a core): per reading one
``log_many("/cmm/raw", [record])``, one ``log_many("/cmm/corrected", [record])`` and a
``kick()``, the records in the engine's compact layout. Three cases, interleaved round by round
in one process, with the daemon's 0.5 ms GIL switch interval:

* ``off`` - a logger that does nothing (the daemon with ``[live]`` off and no MCAP);
* ``on, no client`` - ``LiveFanOut(None, LiveSink)``, nobody connected;
* ``on, subscribed`` - the same with a Foxglove WebSocket client **in another process**
  (like the Foxglove app) subscribed to every channel, ``/cmm/scene`` included.

Per reading it records the time spent in the three calls (what the reply path pays) and the
feeder's wake-up lateness after each sleep (how long a thread that wakes for the next frame
waits, e.g. for the GIL held by the sender thread), plus the process CPU time per reading
(sender thread and the SDK's server threads included). Figures are p50/p99 over all rounds and
differences against ``off`` of the same run.

``--daemon`` (once ``[live]`` is wired into the daemon's configuration): the daemon's reply
latency, as ``benchmarks/bench_daemon.py`` measures it (a simulated controller on a ``virtual``
CAN bus in the same process, 1 kHz, last raw frame → status frame, MCAP on with the default
writer), with ``[live]`` off, on with the default child-process sender (no client; the
subscribed client in another process) and on with the sender thread (subscribed): the cases
in interleaved rounds, a new daemon per round.

The feeder cases above use :class:`LiveSink` (the sender thread) directly: they show what the
thread costs the process that feeds it.
"""

from __future__ import annotations

import argparse
import json
import platform
import subprocess
import sys
import time
from pathlib import Path
from typing import Any

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
RESULTS = ROOT / "benchmarks" / "results" / "live.json"


class NullLogger:
    """The ``off`` case: takes the calls, does nothing."""

    def log_many(self, topic: str, payloads: Any, log_time_ns: int | None = None) -> int:
        return len(payloads)

    def kick(self) -> None:
        pass


def client_main(url: str) -> None:
    """The subscribed client (run in a child process): subscribe to every advertised channel,
    count Message Data frames until stdin closes, print the counts as JSON."""
    import json as _json
    import select
    import struct

    from websockets.sync.client import connect

    counts: dict[str, int] = {}
    with connect(url, subprotocols=["foxglove.sdk.v1", "foxglove.websocket.v1"]) as ws:
        channels: dict[int, str] = {}
        deadline = time.monotonic() + 5.0
        while len(channels) < 7 and time.monotonic() < deadline:
            msg = ws.recv(timeout=5.0)
            if isinstance(msg, str):
                m = _json.loads(msg)
                if m.get("op") == "advertise":
                    channels.update({c["id"]: c["topic"] for c in m["channels"]})
        subs = [{"id": i + 1, "channelId": cid} for i, cid in enumerate(channels)]
        topic_of = {i + 1: channels[cid] for i, cid in enumerate(channels)}
        ws.send(_json.dumps({"op": "subscribe", "subscriptions": subs}))
        print("subscribed", flush=True)
        while True:
            if select.select([sys.stdin], [], [], 0)[0] and not sys.stdin.readline():
                break
            try:
                frame = ws.recv(timeout=0.05)
            except TimeoutError:
                continue
            if isinstance(frame, bytes) and frame[0] == 1:
                sid = struct.unpack_from("<I", frame, 1)[0]
                counts[topic_of[sid]] = counts.get(topic_of[sid], 0) + 1
    print(_json.dumps(counts), flush=True)


def feed(logger: Any, n: int, rate_hz: float, seq0: int) -> dict[str, np.ndarray]:
    """``n`` readings at ``rate_hz``: call cost and wake-up lateness per reading (µs)."""
    calls = np.empty(n)
    late = np.empty(n)
    period = 1.0 / rate_hz
    t0 = time.perf_counter() + period
    cpu0 = time.process_time()
    for k in range(n):
        target = t0 + k * period
        delay = target - time.perf_counter()
        if delay > 0:
            time.sleep(delay)
        woke = time.perf_counter()
        late[k] = (woke - target) * 1e6
        seq = seq0 + k
        x = 100.0 + (seq % 700)
        raw = (seq, x, 250.0, 120.0, (1, 0, 0), (True, True, True), "can", (0.0, 0.0, -120.0), None)
        corr = (
            seq,
            int(x * 1e6) + 3_000,
            250_000_000,
            120_000_000,
            "ok",
            (3.0, -1.5, 0.5),
            80.0,
            1,
            "can",
            "",
        )
        t_ns = time.time_ns()
        a = time.perf_counter_ns()
        logger.log_many("/cmm/raw", [raw], t_ns)
        logger.log_many("/cmm/corrected", [corr], t_ns)
        logger.kick()
        calls[k] = (time.perf_counter_ns() - a) / 1e3
    cpu = time.process_time() - cpu0
    return {"calls": calls, "late": late, "cpu_us": np.array([cpu / n * 1e6])}


def main(argv: list[str]) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--seconds-per-case", type=float, default=2.0)
    parser.add_argument("--rounds", type=int, default=3)
    parser.add_argument("--rate-hz", type=float, default=1000.0)
    parser.add_argument("--client", help=argparse.SUPPRESS)
    parser.add_argument("--daemon", action="store_true", help="also the daemon's reply latency")
    parser.add_argument("--daemon-n", type=int, default=3000, help="readings per daemon case")
    args = parser.parse_args(argv)
    if args.client:
        client_main(args.client)
        return 0

    from cmm_comp.daemon.live import LiveFanOut, LiveSection, LiveSink

    sys.setswitchinterval(0.0005)  # as `cmm-comp daemon` does
    n = int(args.seconds_per_case * args.rate_hz)
    idle = LiveSink(LiveSection(enabled=True, port=0)).start()
    busy = LiveSink(LiveSection(enabled=True, port=0)).start()
    client = subprocess.Popen(
        [sys.executable, __file__, "--client", busy.url],
        stdin=subprocess.PIPE,
        stdout=subprocess.PIPE,
        text=True,
    )
    assert client.stdout is not None and client.stdin is not None
    try:
        assert client.stdout.readline().strip() == "subscribed"
        deadline = time.monotonic() + 5.0
        while busy.stats().subscriptions < 7 and time.monotonic() < deadline:
            time.sleep(0.01)
        assert busy.stats().subscriptions == 7, busy.stats()
        cases = {
            "off": NullLogger(),
            "on, no client": LiveFanOut(None, idle),
            "on, subscribed": LiveFanOut(None, busy),
        }
        feed(cases["off"], 200, args.rate_hz, 0)  # warm-up
        data: dict[str, dict[str, list[np.ndarray]]] = {
            c: {"calls": [], "late": [], "cpu_us": []} for c in cases
        }
        seq = 0
        for r in range(args.rounds):
            for name, logger in cases.items():
                out = feed(logger, n, args.rate_hz, seq)
                seq += n
                for key, arr in out.items():
                    data[name][key].append(arr)
            print(f"round {r + 1}/{args.rounds} done", file=sys.stderr, flush=True)
        time.sleep(0.2)  # let the sender and the client finish
    finally:
        client.stdin.close()
        received = client.stdout.readline().strip()
        client.wait(10)
        idle_stats, busy_stats = idle.stats(), busy.stats()
        idle.stop()
        busy.stop()
    counts = json.loads(received) if received else {}

    rows = {}
    base: dict[str, float] = {}
    for name in cases:
        calls = np.concatenate(data[name]["calls"])
        late = np.concatenate(data[name]["late"])
        cpu = float(np.mean(np.concatenate(data[name]["cpu_us"])))
        row = {
            "readings": int(calls.size),
            "call_p50_us": float(np.percentile(calls, 50)),
            "call_p99_us": float(np.percentile(calls, 99)),
            "call_max_us": float(calls.max()),
            "wake_late_p50_us": float(np.percentile(late, 50)),
            "wake_late_p99_us": float(np.percentile(late, 99)),
            "cpu_per_reading_us": cpu,
        }
        if name == "off":
            base = row
        row["call_p99_minus_off_us"] = row["call_p99_us"] - base["call_p99_us"]
        row["wake_late_p99_minus_off_us"] = row["wake_late_p99_us"] - base["wake_late_p99_us"]
        row["cpu_minus_off_us"] = row["cpu_per_reading_us"] - base["cpu_per_reading_us"]
        rows[name] = row

    print(
        f"\nlive view cost on the feeding thread, {args.rate_hz:g} readings/s "
        f"(2 messages each), {args.rounds} interleaved rounds x {n} readings per case"
    )
    head = (
        "| case | call p50 µs | call p99 µs | p99 − off | wake-up late p50 µs | p99 µs | "
        "p99 − off | CPU µs/reading | − off |"
    )
    print(head)
    print("|" + "---|" * 9)
    for name, r in rows.items():
        print(
            f"| {name} | {r['call_p50_us']:.2f} | {r['call_p99_us']:.2f} | "
            f"{r['call_p99_minus_off_us']:+.2f} | {r['wake_late_p50_us']:.0f} | "
            f"{r['wake_late_p99_us']:.0f} | {r['wake_late_p99_minus_off_us']:+.0f} | "
            f"{r['cpu_per_reading_us']:.1f} | {r['cpu_minus_off_us']:+.1f} |"
        )
    print(f"client received: {counts}")
    print(
        f"subscribed sink: sent {busy_stats.sent}, dropped {busy_stats.dropped}, "
        f"scene updates {busy_stats.scene_updates}; idle sink: not encoded "
        f"{idle_stats.not_encoded}, sent {idle_stats.sent}"
    )
    daemon = bench_live_daemon(args.daemon_n, args.rounds, args.rate_hz) if args.daemon else None
    result = {
        "benchmark": "bench_live",
        "python": sys.version.split()[0],
        "machine": platform.machine(),
        "rate_hz": args.rate_hz,
        "rounds": args.rounds,
        "readings_per_case_round": n,
        "cases": rows,
        "client_received": counts,
        "subscribed_sink": {
            "sent": busy_stats.sent,
            "dropped": busy_stats.dropped,
            "not_encoded": busy_stats.not_encoded,
            "scene_updates": busy_stats.scene_updates,
            "scene_points": busy_stats.scene_points,
        },
        "idle_sink": {"not_encoded": idle_stats.not_encoded, "sent": idle_stats.sent},
        "daemon_reply_latency_us": daemon,
    }
    RESULTS.parent.mkdir(parents=True, exist_ok=True)
    RESULTS.write_text(json.dumps(result, indent=2) + "\n")
    print(f"wrote {RESULTS.relative_to(ROOT)}")
    return 0


DAEMON_CASES: dict[str, tuple[bool, str, bool]] = {  # name: live enabled, sender, client
    "live off": (False, "process", False),
    "live on (process), no client": (True, "process", False),
    "live on (process), subscribed": (True, "process", True),
    "live on (thread), subscribed": (True, "thread", True),
}


def start_client(url: str) -> subprocess.Popen[str]:
    """The subscribed client in its own process; returns once it has subscribed."""
    client = subprocess.Popen(
        [sys.executable, __file__, "--client", url],
        stdin=subprocess.PIPE,
        stdout=subprocess.PIPE,
        text=True,
    )
    assert client.stdout is not None
    line = client.stdout.readline().strip()
    if line != "subscribed":
        client.kill()
        raise RuntimeError(f"the client did not subscribe: {line!r}")
    return client


def stop_client(client: subprocess.Popen[str]) -> dict[str, int]:
    assert client.stdin is not None and client.stdout is not None
    client.stdin.close()
    line = client.stdout.readline().strip()
    client.wait(10)
    return json.loads(line) if line else {}


def bench_live_daemon(n: int, rounds: int, rate_hz: float) -> dict[str, Any] | None:
    """The daemon's reply latency with the live view off / on idle / on with a client."""
    import tempfile
    import uuid

    import can
    from bench_daemon import config, interleaved, measure, readings

    from cmm_comp.compensation.grid import CorrectionGrid
    from cmm_comp.compensation.machine import Machine
    from cmm_comp.daemon.config import DaemonConfig
    from cmm_comp.daemon.service import DaemonService
    from cmm_comp.sim_controller.controller import CanController

    if not hasattr(DaemonConfig(), "live"):
        print("daemon: [live] is not wired into the daemon yet; skipped", file=sys.stderr)
        return None
    machine = Machine.from_toml(ROOT / "examples" / "machines" / "npl-bridge.toml")
    rs = readings(n + 200, np.random.default_rng(1))
    received: dict[str, int] = {}
    live_stats: dict[str, dict[str, int]] = {}
    with tempfile.TemporaryDirectory() as tmpd:
        tmp = Path(tmpd)
        grid = tmp / "npl.grid"
        CorrectionGrid.build(machine, steps=machine.volume.steps).save(grid)

        def one_round(name: str) -> tuple[list[float], int]:
            enabled, sender, subscribed = DAEMON_CASES[name]
            ch = f"bench-live-{uuid.uuid4().hex[:8]}"
            cfg = config(grid, "virtual", ch, str(tmp / f"{ch}.mcap"))
            cfg.live.enabled = enabled
            cfg.live.sender = sender
            cfg.live.port = 0
            with (
                DaemonService(cfg, events_stream=None) as d,
                can.Bus(interface="virtual", channel=ch) as bus,
                CanController(bus) as ctl,
            ):
                client = None
                if subscribed:
                    assert d.live is not None
                    client = start_client(d.live.url)
                    deadline = time.monotonic() + 5.0
                    while d.live.stats().subscriptions < 7 and time.monotonic() < deadline:
                        time.sleep(0.01)
                try:
                    out = measure(ctl, rs, rate_hz)
                    time.sleep(0.1)  # the last answers reach the client
                    if d.live is not None:
                        st = d.live.stats()
                        acc = live_stats.setdefault(name, {"sent": 0, "dropped": 0})
                        acc["sent"] += st.sent
                        acc["dropped"] += st.dropped
                finally:
                    if client is not None:
                        for topic, k in stop_client(client).items():
                            key = f"{name}: {topic}"
                            received[key] = received.get(key, 0) + k
            return out

        print("daemon rounds …", file=sys.stderr)
        res = interleaved(list(DAEMON_CASES), rounds, one_round)
    off = res["live off"]
    print(f"\ndaemon reply latency (virtual CAN, {rate_hz:g} Hz, MCAP on), µs, {rounds} rounds")
    print("| case | p50 | p99 | p50 − off | p99 − off | lost |")
    print("|---|---|---|---|---|---|")
    for name in DAEMON_CASES:
        r = res[name]
        print(
            f"| {name} | {r['p50']:.0f} | {r['p99']:.0f} | {r['p50'] - off['p50']:+.0f} | "
            f"{r['p99'] - off['p99']:+.0f} | {res[f'{name}_lost']} |"
        )
    print(f"client received (all rounds): {received}")
    print(f"live view counters at the end of each case (all rounds): {live_stats}")
    return {**res, "client_received": received, "live_stats": live_stats}


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
