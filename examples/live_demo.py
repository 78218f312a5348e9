"""Stream a simulated measuring session through the daemon's live view, without a machine.

    python examples/live_demo.py [--port 8765] [--rate-hz 20] [--seconds 0]

Then open ``ws://127.0.0.1:8765`` in Foxglove (with ``examples/foxglove-layout.json``) or
``examples/live-view.html`` in a browser. What is streamed is what the daemon streams with
``[live] enabled = true`` (docs/live.md): ``/cmm/raw``, ``/cmm/corrected``, ``/cmm/temperature``,
``/cmm/status``, ``/cmm/counters`` (JSON, the MCAP log's schemas) and ``/cmm/scene``
(``foxglove.SceneUpdate`` arrows), through the same sink as the daemon (``LiveProcessSink``: the
server in a child process) and the same compact records the daemon's engine logs.

The probe scans a raster of points through the machine's volume (default the NPL-like bridge,
``examples/machines/npl-bridge.toml``); each correction is the machine model's volumetric error
at the indicated point for the current temperatures (what a grid built from that model answers,
to within its interpolation error). Every 40th point lies outside the volume (answered
``outside_volume``, not corrected); while the Z scale's simulated sensor drifts above the valid
range (8 to 14 s of every minute) the answers are ``not_thermally_corrected`` (geometry
only). Ctrl-C stops.
"""

from __future__ import annotations

import argparse
import math
import signal
import sys
import threading
import time
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

if TYPE_CHECKING:
    from cmm_comp.compensation import Machine

HERE = Path(__file__).resolve().parent
ROLES = {0: "T_x", 1: "T_y", 2: "T_z", 3: "T_wp"}


def raster(machine: Machine, n: int) -> np.ndarray:
    """``n`` points (mm) on a serpentine raster through the volume, 5 % in from the faces."""
    lo, hi = machine.volume.lower_mm, machine.volume.upper_mm
    pad = 0.05 * (hi - lo)
    k = max(2, round(n ** (1 / 3)))
    axes = [np.linspace(lo[i] + pad[i], hi[i] - pad[i], k) for i in range(3)]
    pts = []
    for iz, z in enumerate(axes[2]):
        for iy, y in enumerate(axes[1] if iz % 2 == 0 else axes[1][::-1]):
            xs = axes[0] if (iy + iz) % 2 == 0 else axes[0][::-1]
            pts += [(x, y, z) for x in xs]
    return np.array(pts)


def temperatures(t_s: float) -> dict[str, float]:
    """Slow drifts, °C; T_z jumps above 40 °C from 8 to 14 s of every minute."""
    return {
        "T_x": 20.6 + 0.3 * math.sin(t_s / 40.0),
        "T_y": 20.9 + 0.2 * math.sin(t_s / 55.0 + 1.0),
        "T_z": 21.2 + 0.4 * math.sin(t_s / 35.0) + (20.0 if 8.0 < (t_s % 60.0) < 14.0 else 0.0),
        "T_wp": 19.8 + 0.1 * math.sin(t_s / 70.0),
    }


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--machine", default=str(HERE / "machines" / "npl-bridge.toml"))
    parser.add_argument("--host", default="127.0.0.1")
    parser.add_argument("--port", type=int, default=8765, help="0 = any free port")
    parser.add_argument("--rate-hz", type=float, default=20.0, help="readings per second")
    parser.add_argument(
        "--seconds", type=float, default=0.0, help="stop after this long; 0 = never"
    )
    args = parser.parse_args(argv)
    if not (math.isfinite(args.rate_hz) and 0 < args.rate_hz <= 5000):
        parser.error(f"--rate-hz {args.rate_hz}: allowed > 0 and <= 5000")
    from cmm_comp.compensation import Machine  # after the arguments: a bad flag answers at once
    from cmm_comp.daemon.live import LiveProcessSink, LiveSection

    machine = Machine.from_toml(args.machine)
    points = raster(machine, 2000)
    stylus = (0.0, 0.0, -120.0)
    stop = threading.Event()
    signal.signal(signal.SIGINT, lambda *_: stop.set())
    signal.signal(signal.SIGTERM, lambda *_: stop.set())
    settings = LiveSection(enabled=True, host=args.host, port=args.port, scene_keep_arrows=400)
    with LiveProcessSink(
        settings, on_error=lambda e: print(f"live: {e}", file=sys.stderr)
    ).start() as sink:
        print(f"streaming on {sink.url} (Ctrl-C stops)", flush=True)
        sink.log("/cmm/status", {"state": "ready", "detail": "demo: simulated", "grid_sha256": ""})
        sink.log(
            "/cmm/grid",
            {"sha256": "", "machine": machine.name, "model": machine.model, "steps": [],
             "path": "demo: the machine model, no grid", "loaded_at": {"sec": 0, "nsec": 0}},
        )  # fmt: skip
        t0 = time.monotonic()
        next_counters = t0
        counter, answers = 0, {"ok": 0, "outside_volume": 0, "not_thermally_corrected": 0}
        k = 0
        while not stop.is_set():
            now = time.monotonic()
            if args.seconds and now - t0 >= args.seconds:
                break
            temps = temperatures(now - t0)
            if k % max(1, round(args.rate_hz / 10)) == 0:  # temperatures at ~10 Hz
                counter += 1
                for sensor, role in ROLES.items():
                    sink.log(
                        "/cmm/temperature",
                        {"sensor": str(sensor), "role": role, "temp_C": temps[role],
                         "counter": counter, "valid": True, "fault": "", "source": "demo"},
                    )  # fmt: skip
            q = points[k % len(points)].copy()
            if k % 40 == 39:
                q[0] = machine.volume.upper_mm[0] + 25.0  # outside the volume
            hot = temps["T_z"] > 40.0
            if not machine.volume.contains(q):
                status, d = "outside_volume", (0.0, 0.0, 0.0)
            else:
                # geometry only while T_z is out of range: the thermal terms are left out
                err = machine.volumetric_error(q[None, :], stylus, None if hot else temps)[0]
                status = "not_thermally_corrected" if hot else "ok"
                d = tuple(float(v) for v in err)
            corrected_nm = tuple(
                round(float(v) * 1e6 + di * 1e3) for v, di in zip(q, d, strict=True)
            )
            raw = (k, *map(float, q), (1, 0, 0), (True, True, True), "demo", stylus, None)
            corr = (
                k,
                *corrected_nm,
                status,
                d,
                150.0,
                1 if status != "outside_volume" else 0,
                "demo",
                "",
            )
            t_ns = time.time_ns()
            sink.log_many("/cmm/raw", [raw], t_ns)
            sink.log_many("/cmm/corrected", [corr], t_ns)
            sink.kick()
            answers[status] += 1
            if now >= next_counters:
                next_counters += 1.0
                counters = {f"answers_{s}": n for s, n in answers.items()} | sink.counters()
                sink.log("/cmm/counters", {"period_s": 1.0, "counters": counters})
            k += 1
            stop.wait(max(0.0, t0 + k / args.rate_hz - time.monotonic()))
        stats = sink.stats()
    print(
        f"sent {stats.sent} messages, {stats.scene_updates} scene updates, dropped {stats.dropped}"
    )
    return 0


if __name__ == "__main__":
    sys.exit(main())
