"""An independent CAN bus listener for tests: its own process, its own python-can bus.

    python tests/can_listener.py --interface udp_multicast --channel GROUP --option port=P

Opens the bus, prints ``ready`` on a line of its own, then records the id of every frame it
sees until its standard input is closed, and prints ``{"ids": {"<id>": count, …}, "frames":
n, "errors": [...]}`` as one JSON line. It imports nothing of cmm-comp: what it counts is what
went over the bus, not what the project's code says it sent.
"""

from __future__ import annotations

import argparse
import json
import sys
import threading
from collections import Counter

import can


def main() -> int:
    ap = argparse.ArgumentParser()
    ap.add_argument("--interface", required=True)
    ap.add_argument("--channel", required=True)
    ap.add_argument("--option", action="append", default=[], metavar="KEY=INT")
    args = ap.parse_args()
    opts = {k: int(v) for k, v in (o.split("=", 1) for o in args.option)}
    bus = can.Bus(interface=args.interface, channel=args.channel, **opts)
    seen: Counter[int] = Counter()
    errors: list[str] = []
    stop = threading.Event()

    def run() -> None:
        while not stop.is_set():
            try:
                msg = bus.recv(0.05)
            except Exception as exc:  # report, never hide
                errors.append(repr(exc))
                continue
            if msg is not None:
                seen[msg.arbitration_id] += 1

    thread = threading.Thread(target=run, daemon=True)
    thread.start()
    print("ready", flush=True)
    sys.stdin.read()  # until the test closes our stdin
    stop.set()
    thread.join(5.0)
    bus.shutdown()
    out = {"ids": {str(k): v for k, v in sorted(seen.items())}, "frames": sum(seen.values())}
    print(json.dumps({**out, "errors": errors}), flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
