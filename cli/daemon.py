"""``cmm-comp daemon`` and ``cmm-comp replay``: the production daemon and its session logs.

``add_parsers(subparsers)`` registers the two subcommands (each sets ``handler``);
``cli/main.py`` calls it. Handlers return the exit code: 0 success, 1 run-time failure,
2 bad input (the message names the file or flag; never a traceback).
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path
from typing import Any

from .common import fail

WORKER_READY_WAIT_S = 5.0
"""How long the daemon waits at start for its grid-reload worker to finish importing, s (on a
saturated machine the worker, at SCHED_IDLE, may get no CPU: the daemon then starts anyway)."""


def add_parsers(subparsers: Any) -> None:
    """Register ``daemon`` and ``replay`` on an argparse subparsers object."""
    from cmm_comp.daemon.config import add_override_flags

    p = subparsers.add_parser(
        "daemon",
        help="run the compensation daemon (CAN and/or Modbus TCP)",
        description="Correct readings from a CMM controller over CAN and/or Modbus TCP. "
        "Every configuration key can be overridden by --<section>-<key>. "
        "SIGHUP reloads the grid; SIGTERM stops cleanly.",
    )
    p.add_argument("--config", help="daemon.toml (see examples/daemon.toml)")
    p.add_argument(
        "--check", action="store_true", help="validate the configuration and grid, then exit"
    )
    add_override_flags(p)
    p.set_defaults(handler=cmd_daemon)

    p = subparsers.add_parser(
        "replay",
        help="re-correct a logged session offline, or re-send it to a running daemon",
    )
    p.add_argument("session", metavar="SESSION", help="session .mcap file, directory or glob")
    p.add_argument("--grid", help="re-correct with this grid (default: the session's grid)")
    p.add_argument("--json", metavar="OUT", help="write the report as JSON")
    p.add_argument(
        "--to-bus",
        action="store_true",
        help="re-send the frames the controller sent (never the daemon's own) at the recorded pace",
    )
    p.add_argument("--interface", default="socketcan", help="python-can interface (--to-bus)")
    p.add_argument("--channel", default="can0", help="python-can channel (--to-bus)")
    p.add_argument(
        "--bus-option",
        action="append",
        default=[],
        metavar="KEY=VALUE",
        help="extra can.Bus argument, e.g. port=43113 (--to-bus; repeatable)",
    )
    p.add_argument("--speed", type=float, default=1.0, help="pace factor; 0 = flat out")
    p.set_defaults(handler=cmd_replay)


def cmd_daemon(args: argparse.Namespace) -> int:
    """Run the daemon until SIGTERM/SIGINT."""
    from cmm_comp.daemon.config import ConfigError, load_config
    from cmm_comp.daemon.grid_slot import GridLoadError, load_grid
    from cmm_comp.daemon.grid_trust import GridTrust

    try:
        config = load_config(args.config, args)
    except ConfigError as exc:
        for line in exc.lines:
            fail(line)
        return 2
    if args.check:
        if config.grid.path:
            try:
                loaded = load_grid(config.grid.path, GridTrust.from_section(config.grid))
            except GridLoadError as exc:
                return fail(str(exc))
            signed = f"signed by key {loaded.signed_by}" if loaded.signed_by else "unsigned"
            print(
                f"{config.source}: ok; grid {loaded.path} sha256 {loaded.sha256} ({signed}, "
                f"machine {loaded.machine!r})"
            )
        else:
            print(f"{config.source}: ok; no grid configured")
        return 0
    from cmm_comp.daemon.service import DaemonService

    # Shorter GIL switch interval: the reply thread gets the interpreter back sooner from
    # the MCAP writer thread (tail latency); process-wide, so only in the daemon's own process.
    sys.setswitchinterval(0.0005)
    # (no mallopt tuning here, unlike the MCAP writer child: measured over udp_multicast, the
    # child's settings (2 arenas, fixed 128 KiB mmap threshold) cost the reply path +130 µs p50)
    service = DaemonService(config)
    # the grid-reload worker imports the grid code (~0.6 s of CPU) before the first answer,
    # not beside it (measured: p50 462 vs 299 µs over udp_multicast in the first seconds)
    service.prewarm_reload_worker(WORKER_READY_WAIT_S)
    try:
        service.start()
    except (OSError, RuntimeError) as exc:
        print(f"cmm-comp daemon: cannot start: {exc}", file=sys.stderr)
        return 1
    return service.run_forever()


def _bus_options(items: list[str]) -> dict[str, Any]:
    out: dict[str, Any] = {}
    for item in items:
        key, sep, value = item.partition("=")
        if not sep:
            raise ValueError(f"--bus-option {item!r} must be KEY=VALUE")
        try:
            out[key] = json.loads(value)
        except json.JSONDecodeError:
            out[key] = value
    return out


def _u_known_text(report: Any) -> str:
    grid = "" if report.grid_has_uncertainty else " (the replay's grid carries no U)"
    return f"{report.sent_uncertainty_known} / {report.replayed_uncertainty_known}{grid}"


def cmd_replay(args: argparse.Namespace) -> int:
    """Re-correct a session (default) or re-send it to a bus (``--to-bus``)."""
    import can

    from cmm_comp.daemon.sessionlog.replay import ReplayError, replay_offline, replay_to_bus

    try:
        if args.to_bus:
            opts = _bus_options(args.bus_option)
            with can.Bus(interface=args.interface, channel=args.channel, **opts) as bus:
                sent = replay_to_bus(args.session, bus, args.speed)
            print(
                f"re-sent {sent.sent} frames the controller sent to "
                f"{args.interface}:{args.channel}; not re-sent: {sent.skipped_own} of the "
                f"daemon's own frames (answers, statuses, heartbeats echoed back by the bus)"
                + (
                    f", {sent.skipped_error_frames} error frames"
                    if sent.skipped_error_frames
                    else ""
                )
            )
            if sent.note:
                print(f"cmm-comp: note: {sent.note}", file=sys.stderr)
            if sent.truncated:
                print(
                    f"cmm-comp: warning: session cut by a crash: re-sent the frames read before "
                    f"the break ({sent.read_error or 'file ends without its footer'})",
                    file=sys.stderr,
                )
            return 0
        report = replay_offline(args.session, args.grid)
    except (ReplayError, ValueError, can.CanError) as exc:
        return fail(str(exc))
    if report.warning:
        print(f"cmm-comp: warning: {report.warning}", file=sys.stderr)
    rows = [
        ("session", ", ".join(report.session) + (" (cut by a crash)" if report.truncated else "")),
        ("grid", f"{report.grid_path} ({report.grid_sha256[:12]})"),
        ("session grid", report.session_grid_sha256[:12] or "-"),
        ("readings", str(report.readings)),
        ("compared (both corrected)", str(report.compared)),
        ("sent position not finite", str(report.sent_not_finite)),
        ("max |replayed − sent|", f"{report.max_abs_diff_um:.4f} µm"),
        ("RMS 3-D difference", f"{report.rms_diff_um:.4f} µm"),
        ("status agrees", f"{report.status_agree}/{report.readings}"),
        ("U known, sent / replayed", _u_known_text(report)),
        ("U compared (both known)", str(report.uncertainty_compared)),
        ("max |replayed U − sent U|", f"{report.max_abs_u_diff_um:.4f} µm"),
        ("U known by one side only", str(report.uncertainty_mismatch)),
    ]
    rows += [(f"  status {k}", str(v)) for k, v in sorted(report.status_differ.items())]
    width = max(len(k) for k, _ in rows)
    print("\n".join(f"{k:<{width}}  {v}" for k, v in rows))
    if args.json:
        Path(args.json).write_text(json.dumps(report.as_dict(), indent=2) + "\n")
    return 0
