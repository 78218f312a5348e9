"""Cost of the live view (daemon/live) on the thread that feeds it, live off vs on, same run.

Run: ``.venv/bin/python benchmarks/bench_live.py [--seconds-per-case 2] [--rounds 3]``. Prints a
table and writes ``benchmarks/results/live.json``.

A feeder thread plays the CAN endpoint's bookkeeping at ``--rate-hz`` readings per second,
paced by sleeping (ECOSYSTEM.md: a spinning client steals a core): per reading one
``log_many("/cmm/raw", [record])``, one ``log_many("/cmm/corrected", [record])`` and a
``kick()``, the records in the engine's compact layout. Three cases, interleaved round by round
in one process, with the daemon's 0.5 ms GIL switch interval:

* ``off`` - a logger that does nothing (the daemon with ``[live]`` off and no MCAP);
* ``on, no client`` - ``LiveFanOut(None, LiveProcessSink)``, nobody connected;
* ``on, subscribed`` - another one with a Foxglove WebSocket client **in another process**
  (like the Foxglove app) subscribed to every channel, ``/cmm/scene`` included.

Per reading it records the time spent in the three calls (what the reply path pays) and the
feeder's wake-up lateness after each sleep (how long a thread that wakes for the next frame
waits), plus the process CPU time per reading. Figures are p50/p99 over all rounds and
differences against ``off`` of the same run.

``--daemon``: the daemon's reply latency, as ``benchmarks/bench_daemon.py`` measures it (a
simulated controller on a ``virtual`` CAN bus in the same process, 1 kHz, last raw frame →
status frame, MCAP on with the default writer), with ``[live]`` off, off again (an A/A case:
the noise floor), on with the default process sender and no client, on with a client
subscribed to every channel in another process (at the defaults; with the view at the old
30 Hz defaults; with the client at ``SCHED_IDLE``, so that only the daemon's and the view's
own cost remains): interleaved rounds, the
order rotated each round, a new daemon per case and round; per round p50/p99, the ratio to
``live off`` of the same round (median and range over the rounds) and the difference to the
mean of the two ``off`` cases of the same round (median, its 95 % bootstrap interval, rounds
higher).
``--daemon-only`` runs only this part (``benchmarks/results/live_daemon.json``).

The feeder cases above use :class:`LiveProcessSink` directly: they show what it costs the
thread that feeds it (with this machine's cold caches after each 1 ms sleep, a call costs
several times its hot cost).
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import subprocess
import sys
import time
from dataclasses import dataclass
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


def client_main(url: str, priority: str = "normal") -> None:
    """The subscribed client (run in a child process): subscribe to every advertised channel,
    count Message Data frames until stdin closes, print the counts as JSON. ``priority``
    ``idle``: Linux ``SCHED_IDLE`` for this process, taken before any thread starts."""
    import json as _json
    import select
    import struct

    from websockets.sync.client import connect

    if priority != "normal":
        from cmm_comp.daemon.osthread import lower_priority

        lower_priority(priority)
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
    parser.add_argument("--client-priority", default="normal", help=argparse.SUPPRESS)
    parser.add_argument("--daemon", action="store_true", help="also the daemon's reply latency")
    parser.add_argument("--daemon-n", type=int, default=3000, help="readings per daemon case")
    parser.add_argument(
        "--daemon-only", action="store_true", help="only the daemon's reply latency"
    )
    parser.add_argument(
        "--out", type=Path, help="--daemon-only: the JSON file (default results/live_daemon.json)"
    )
    parser.add_argument(
        "--browser",
        metavar="CHROMIUM",
        help="also a browser as the client: Chromium (this path, e.g. /usr/bin/chromium) "
        "showing examples/live-view.html, at normal and at idle priority",
    )
    args = parser.parse_args(argv)
    if args.client:
        client_main(args.client, args.client_priority)
        return 0

    from cmm_comp.daemon.live import LiveFanOut, LiveProcessSink, LiveSection

    sys.setswitchinterval(0.0005)  # as `cmm-comp daemon` does
    if args.daemon_only:
        daemon = bench_live_daemon(args.daemon_n, args.rounds, args.rate_hz, args.browser)
        out_path = args.out or ROOT / "benchmarks" / "results" / "live_daemon.json"
        out_path.write_text(
            json.dumps({"benchmark": "bench_live --daemon-only", **(daemon or {})}, indent=2) + "\n"
        )
        print(f"wrote {out_path}")
        return 0
    n = int(args.seconds_per_case * args.rate_hz)
    idle = LiveProcessSink(LiveSection(enabled=True, port=0)).start()
    proc = LiveProcessSink(LiveSection(enabled=True, port=0)).start()
    pclient = start_client(proc.url)
    try:
        deadline = time.monotonic() + 5.0
        while proc.stats().subscriptions < 7 and time.monotonic() < deadline:
            time.sleep(0.01)
        assert proc.stats().subscriptions == 7, proc.stats()
        cases = {
            "off": NullLogger(),
            "on, no client": LiveFanOut(None, idle),
            "on, subscribed": LiveFanOut(None, proc),
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
        pcounts = stop_client(pclient)
        idle.stop()
        proc.stop()
        idle_stats, proc_stats = idle.stats(), proc.stats()

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
    print(f"client received: {pcounts}")
    print(
        f"subscribed sink: sent {proc_stats.sent}, decimated {proc_stats.decimated}, dropped "
        f"{proc_stats.dropped}, scene updates {proc_stats.scene_updates}; idle sink: not "
        f"encoded {idle_stats.not_encoded}"
    )
    daemon = (
        bench_live_daemon(args.daemon_n, args.rounds, args.rate_hz, args.browser)
        if args.daemon
        else None
    )
    result = {
        "benchmark": "bench_live",
        "python": sys.version.split()[0],
        "machine": platform.machine(),
        "rate_hz": args.rate_hz,
        "rounds": args.rounds,
        "readings_per_case_round": n,
        "cases": rows,
        "client_received": pcounts,
        "subscribed_sink": {
            "sent": proc_stats.sent,
            "dropped": proc_stats.dropped,
            "decimated": proc_stats.decimated,
            "not_encoded": proc_stats.not_encoded,
            "scene_updates": proc_stats.scene_updates,
            "scene_points": proc_stats.scene_points,
        },
        "idle_sink": {"not_encoded": idle_stats.not_encoded, "sent": idle_stats.sent},
        "daemon_reply_latency_us": daemon,
    }
    RESULTS.parent.mkdir(parents=True, exist_ok=True)
    RESULTS.write_text(json.dumps(result, indent=2) + "\n")
    print(f"wrote {RESULTS.relative_to(ROOT)}")
    return 0


@dataclass(frozen=True)
class DaemonCase:
    """One case of the daemon part: ``[live]`` on or off, the client (None: no
    client; ``normal``: at normal CPU priority, like a Foxglove app or a browser started by
    hand; ``idle``: the same client at Linux ``SCHED_IDLE``, so its own CPU never competes with
    the daemon and what remains is what the daemon and its view's process cost), and
    ``[live]`` keys changed from their defaults."""

    enabled: bool
    client: str | None = None
    live: tuple[tuple[str, float], ...] = ()


DAEMON_CASES: dict[str, DaemonCase] = {
    "live off": DaemonCase(False),
    "live off again": DaemonCase(False),  # A/A: what the machine's noise alone gives
    "live on, no client": DaemonCase(True),
    "live on, subscribed": DaemonCase(True, client="normal"),
    # the view at the rates it had by default before (30 and 20 Hz, against 10 and 10 now):
    # ~3x the client's messages and wake-ups
    "live on, subscribed, view at 30 Hz": DaemonCase(
        True, client="normal", live=(("update_rate_hz", 30.0), ("scene_rate_hz", 20.0))
    ),
    # the same client where its own CPU cannot compete: the view's cost alone
    "live on, subscribed, client at idle priority": DaemonCase(True, client="idle"),
}
BROWSER_CASES = {
    # a real viewer: headless Chromium showing examples/live-view.html (it draws 5 times a
    # second), at normal priority as started by hand, and at Linux SCHED_IDLE (`chrt -i 0`)
    "live on, Chromium showing live-view.html": DaemonCase(True, client="browser"),
    "live on, Chromium at idle priority": DaemonCase(True, client="browser-idle"),
}
"""With ``--browser PATH``: a browser as the client (the page subscribes to the 6 JSON topics)."""
BASELINES = ("live off", "live off again")
"""A case's paired difference is taken against the mean of these two, round by round."""


def start_client(url: str, priority: str = "normal") -> subprocess.Popen[str]:
    """The subscribed client in its own process (``priority``: ``normal`` or ``idle``, which it
    takes itself before it connects); returns once it has subscribed."""
    cmd = [sys.executable, __file__, "--client", url]
    if priority != "normal":
        cmd += ["--client-priority", priority]
    client = subprocess.Popen(cmd, stdin=subprocess.PIPE, stdout=subprocess.PIPE, text=True)
    assert client.stdout is not None
    line = client.stdout.readline().strip()
    if line != "subscribed":
        client.kill()
        raise RuntimeError(f"the client did not subscribe: {line!r}")
    return client


class Browsers:
    """Headless Chromium instances (one at normal priority, one at ``SCHED_IDLE``) kept open for
    the whole run on ``about:blank``; :meth:`watch` points one at ``examples/live-view.html``
    for a daemon's live view, :meth:`blank` takes it away again. Driven over the DevTools
    protocol, as ``docs/img/live_view_screenshot.py`` does for the screenshot."""

    def __init__(self, chromium: str, profile_root: Path) -> None:
        sys.path.insert(0, str(ROOT / "docs" / "img"))
        from live_view_screenshot import HeadlessChromium

        self.browsers: dict[str, Any] = {}
        for mode, prefix in (("browser", []), ("browser-idle", ["chrt", "-i", "0"])):
            (profile_root / mode).mkdir()
            self.browsers[mode] = HeadlessChromium(chromium, profile_root / mode, prefix=prefix)
        self.procs = {mode: b.proc for mode, b in self.browsers.items()}

    def watch(self, mode: str, url: str) -> None:
        page = (ROOT / "examples" / "live-view.html").as_uri()
        self.browsers[mode].call("Page.navigate", url=f"{page}?url={url}")

    def blank(self, mode: str) -> None:
        self.browsers[mode].call("Page.navigate", url="about:blank")

    def close(self) -> None:
        for b in self.browsers.values():
            b.close()


def stop_client(client: subprocess.Popen[str]) -> dict[str, int]:
    assert client.stdin is not None and client.stdout is not None
    client.stdin.close()
    line = client.stdout.readline().strip()
    client.wait(10)
    return json.loads(line) if line else {}


def median_interval(values: list[float], draws: int = 5000, seed: int = 0) -> tuple[float, float]:
    """95 % bootstrap interval of the median of ``values`` (resampled with replacement,
    seeded: the same data give the same interval)."""
    a = np.asarray(values, dtype=float)
    rng = np.random.default_rng(seed)
    medians = np.median(a[rng.integers(0, a.size, (draws, a.size))], axis=1)
    lo, hi = np.percentile(medians, [2.5, 97.5])
    return float(lo), float(hi)


def _spread(values: list[float], digits: int = 3) -> str:
    a = np.array(values)
    return f"{np.median(a):.{digits}f} ({a.min():.{digits}f}–{a.max():.{digits}f})"


def bench_live_daemon(
    n: int, rounds: int, rate_hz: float, browser: str | None = None
) -> dict[str, Any] | None:
    """The daemon's reply latency with the live view off / on idle / on with a client
    subscribed to every channel: interleaved rounds (the order rotated each round), a new
    daemon per case and round; per round p50/p99 and the ratio on/off of the same round. The
    case ``live off again`` is ``live off`` once more: its ratio to ``live off`` is what the
    machine's noise alone gives (an A/A comparison), the yardstick for the others."""
    import tempfile
    import uuid

    import can
    from bench_daemon import (
        config,
        interleaved,
        measure,
        process_cpu_s,
        readings,
        tree_cpu_s,
        wait_quiet,
    )

    from cmm_comp.compensation.grid import CorrectionGrid
    from cmm_comp.compensation.machine import Machine
    from cmm_comp.daemon.service import DaemonService
    from cmm_comp.sim_controller.controller import CanController

    cases = dict(DAEMON_CASES)
    if browser:
        cases.update(BROWSER_CASES)
    names = list(cases)
    machine = Machine.from_toml(ROOT / "examples" / "machines" / "npl-bridge.toml")
    rs = readings(n + 200, np.random.default_rng(1))
    received: dict[str, int] = {}
    live_stats: dict[str, dict[str, int]] = {}
    cpu_us: dict[str, list[float]] = {name: [] for name in names}
    child_cpu_us: dict[str, list[float]] = {name: [] for name in names}
    settle_s: dict[str, list[float]] = {}
    with tempfile.TemporaryDirectory() as tmpd:
        tmp = Path(tmpd)
        grid = tmp / "npl.grid"
        CorrectionGrid.build(machine, steps=machine.volume.steps).save(grid)
        browsers = Browsers(browser, tmp) if browser else None
        viewer_cpu_us: dict[str, list[float]] = {}

        def one_round(name: str) -> tuple[list[float], int]:
            case = cases[name]
            ch = f"bench-live-{uuid.uuid4().hex[:8]}"
            cfg = config(grid, ch, str(tmp / f"{ch}.mcap"))
            cfg.live.enabled = case.enabled
            cfg.live.port = 0
            for key, value in case.live:
                setattr(cfg.live, key, value)
            with (
                DaemonService(cfg, events_stream=None) as d,
                can.Bus(interface="virtual", channel=ch) as bus,
                CanController(bus) as ctl,
            ):
                client = None
                viewer = None  # the browser's process tree
                if case.client is not None:
                    assert d.live is not None
                    topics = 7
                    if case.client.startswith("browser"):
                        assert browsers is not None
                        browsers.watch(case.client, d.live.url)
                        viewer, topics = browsers.procs[case.client].pid, 6
                    else:
                        client = start_client(d.live.url, case.client)
                    deadline = time.monotonic() + 10.0
                    while d.live.stats().subscriptions < topics and time.monotonic() < deadline:
                        time.sleep(0.01)
                try:
                    # the steady state: the live view's process (and the MCAP writer) have
                    # finished starting — their imports are not a cost of the reply path
                    settle_s.setdefault(name, []).append(wait_quiet(os.getpid(), 20.0))
                    child = getattr(d.live, "child_pid", None)
                    cpu0 = time.process_time()
                    child0 = process_cpu_s(child) if child else 0.0
                    viewer0 = tree_cpu_s(viewer) if viewer else 0.0
                    out = measure(ctl, rs, rate_hz)
                    per = 1e6 / len(rs)
                    cpu_us[name].append((time.process_time() - cpu0) * per)
                    if viewer:
                        viewer_cpu_us.setdefault(name, []).append(
                            (tree_cpu_s(viewer) - viewer0) * per
                        )
                    if child:
                        child_cpu_us[name].append((process_cpu_s(child) - child0) * per)
                    time.sleep(0.2)  # the last answers reach the client
                    if d.live is not None:
                        st = d.live.stats()
                        acc = live_stats.setdefault(name, {})
                        for key in ("offered", "sent", "decimated", "dropped", "not_encoded"):
                            acc[key] = acc.get(key, 0) + getattr(st, key)
                        acc["up_at_end"] = acc.get("up_at_end", 0) + int(st.up)
                finally:
                    if browsers is not None and viewer is not None and case.client:
                        browsers.blank(case.client)
                        time.sleep(0.3)  # the page's connection closes
                    if client is not None:
                        for topic, k in stop_client(client).items():
                            key = f"{name}: {topic}"
                            received[key] = received.get(key, 0) + k
            return out

        print("daemon rounds …", file=sys.stderr)
        try:
            runs = interleaved(
                names,
                rounds,
                one_round,
                lambda k: print(f"daemon round {k}/{rounds} done", file=sys.stderr, flush=True),
            )
        finally:
            if browsers is not None:
                browsers.close()
    per_round = {name: runs[f"{name}_per_round"] for name in names}
    res: dict[str, Any] = {
        "rounds": rounds,
        "readings_per_case_round": n,
        "rate_hz": rate_hz,
        "settled_s_median": {k: float(np.median(v)) for k, v in settle_s.items()},
        "browser_cpu_us_per_reading": viewer_cpu_us,
    }
    for name in names:
        res[name] = {
            **runs[name],
            "lost": runs[f"{name}_lost"],
            "per_round": per_round[name],
            "cpu_us_per_reading_daemon_process": cpu_us[name],
            "cpu_us_per_reading_view_process": child_cpu_us[name],
        }
    print(f"\ndaemon reply latency (virtual CAN, {rate_hz:g} Hz, MCAP on), µs, {rounds} rounds")
    print("per round (p50 / p99):")
    print("| round | " + " | ".join(names) + " |")
    print("|---|" + "---|" * len(names))
    for k in range(rounds):
        cells = [f"{per_round[c][k]['p50']:.0f} / {per_round[c][k]['p99']:.0f}" for c in names]
        print(f"| {k + 1} | " + " | ".join(cells) + " |")
    print("\npooled, and the ratio to live off of the same round: median (min–max over rounds)")
    print("| case | p50 | p99 | p50 / off | p99 / off | lost |")
    print("|---|---|---|---|---|---|")
    for name in names:
        r = res[name]
        pairs = list(zip(per_round[name], per_round["live off"], strict=True))
        r50 = [a["p50"] / b["p50"] for a, b in pairs]
        r99 = [a["p99"] / b["p99"] for a, b in pairs]
        r["ratio_p50_per_round"], r["ratio_p99_per_round"] = r50, r99
        print(
            f"| {name} | {r['p50']:.0f} | {r['p99']:.0f} | {_spread(r50)} | {_spread(r99)} | "
            f"{r['lost']} |"
        )
    print("\npaired, round by round: the case minus the mean of live off and live off again of the")
    print("same round, µs: median over rounds (95 % bootstrap interval of the median), and in how")
    print("many rounds the case was higher")
    print("| case | p50 − baseline | rounds higher | p99 − baseline | rounds higher |")
    print("|---|---|---|---|---|")
    for name in names:
        r = res[name]
        for q in ("p50", "p99"):
            base = [np.mean([per_round[b][k][q] for b in BASELINES]) for k in range(rounds)]
            diff = [per_round[name][k][q] - base[k] for k in range(rounds)]
            r[f"{q}_minus_baseline_per_round"] = diff
            r[f"{q}_minus_baseline_median"] = float(np.median(diff))
            r[f"{q}_minus_baseline_median_ci95"] = median_interval(diff)
            r[f"{q}_rounds_higher"] = int(sum(d > 0 for d in diff))
        cells = []
        for q in ("p50", "p99"):
            lo, hi = r[f"{q}_minus_baseline_median_ci95"]
            cells.append(
                f"{r[f'{q}_minus_baseline_median']:+.0f} ({lo:+.0f} … {hi:+.0f}) | "
                f"{r[f'{q}_rounds_higher']}/{rounds}"
            )
        print(f"| {name} | " + " | ".join(cells) + " |")
    print("\nCPU µs per reading, median over rounds (min–max): the daemon's process (controller")
    print("thread included), the view's process")
    for name in names:
        view = _spread(child_cpu_us[name], 0) if child_cpu_us[name] else "-"
        print(f"| {name} | {_spread(cpu_us[name], 0)} | {view} |")
    for name, v in viewer_cpu_us.items():
        print(f"browser's processes, CPU µs per reading, {name}: {_spread(v, 0)}")
    print(f"client received (all rounds): {received}")
    print(f"settled before measuring (median s): {res['settled_s_median']}")
    print(f"live view counters at the end of each case (all rounds): {live_stats}")
    return {**res, "client_received": received, "live_stats": live_stats}


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
