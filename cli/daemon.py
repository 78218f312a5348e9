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
        "--check",
        action="store_true",
        help="check the configuration, grid, keys, log folder, CAN bus and ports; list every "
        "problem, then exit (2 when there is one)",
    )
    add_override_flags(p)
    p.set_defaults(handler=cmd_daemon)
    _add_init_parser(p)

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


def _add_init_parser(daemon_parser: argparse.ArgumentParser) -> None:
    """``cmm-comp daemon init DIR --machine MACHINE.toml …`` under ``daemon``."""
    sub = daemon_parser.add_subparsers(dest="daemon_command", metavar="init")
    p = sub.add_parser(
        "init",
        help="make a folder the daemon runs from: grid, key pair, signature, daemon.toml",
        description="Build the correction grid of MACHINE, make an Ed25519 key pair, sign the "
        "grid and write DIR/daemon.toml bound to the machine (every path inside DIR, session "
        "logs in DIR/logs); print the command that starts the daemon. Never overwrites.",
    )
    p.add_argument("directory", metavar="DIR", type=Path, help="folder to write (created)")
    p.add_argument("--machine", required=True, type=Path, help="machine description (TOML)")
    p.add_argument(
        "--can-interface",
        dest="init_can_interface",
        default="socketcan",
        metavar="I",
        help="python-can interface (default socketcan; no hardware: udp_multicast between "
        "processes on this host, virtual inside one process)",
    )
    p.add_argument(
        "--can-channel",
        dest="init_can_channel",
        metavar="C",
        help="channel (default: can0 for socketcan, the host-local group "
        "ff11:7079:7468:6f6e:6465:6d6f:6d63:6173 for udp_multicast)",
    )
    p.add_argument(
        "--can-option",
        dest="init_can_option",
        action="append",
        default=[],
        metavar="KEY=VALUE",
        help="extra can.Bus argument (TOML value), e.g. port=43113 (repeatable)",
    )
    p.add_argument(
        "--steps",
        nargs=3,
        type=int,
        metavar=("NX", "NY", "NZ"),
        help="grid nodes per axis (default: the machine's [volume] steps)",
    )
    p.add_argument(
        "--logs",
        type=Path,
        metavar="FOLDER",
        help="session log (MCAP) folder (default DIR/logs; under systemd: /var/log/cmm-comp)",
    )
    p.set_defaults(handler=cmd_daemon_init)


def _toml_options(items: list[str]) -> dict[str, Any]:
    """``KEY=VALUE`` flags, each VALUE read as a TOML value (else kept as a string)."""
    import tomllib

    out: dict[str, Any] = {}
    for item in items:
        key, sep, value = item.partition("=")
        if not sep or not key.strip():
            raise ValueError(f"--can-option {item!r} must be KEY=VALUE")
        try:
            out[key.strip()] = tomllib.loads(f"v = {value}")["v"]
        except tomllib.TOMLDecodeError:
            out[key.strip()] = value
    return out


def cmd_daemon_init(args: argparse.Namespace) -> int:
    """``cmm-comp daemon init DIR --machine MACHINE.toml``: see :mod:`cmm_comp.cli.daemon_init`."""
    import shlex

    from cmm_comp.cli.daemon_check import preflight
    from cmm_comp.cli.daemon_init import CONFIG_NAME, init_daemon_dir
    from cmm_comp.daemon.config import load_config

    def progress(fraction: float, message: str) -> None:
        if sys.stderr.isatty():
            print(f"\rgrid build: {int(100 * fraction):3d} % {message}", end="", file=sys.stderr)

    report = init_daemon_dir(
        args.directory,
        args.machine,
        args.init_can_interface,
        args.init_can_channel,
        _toml_options(args.init_can_option),
        args.steps,
        args.logs,
        progress,
    )
    if sys.stderr.isatty():
        print(file=sys.stderr)
    d = args.directory
    print(f"wrote {d / 'machine.toml'}: a copy of {args.machine} ({report.machine_name})")
    print(
        f"wrote {d / 'machine.grid'}: steps {list(report.steps)}, sha256 "
        f"{report.grid_sha256[:16]}…, signed with key {report.key_id}"
    )
    print(
        f"wrote {d / 'keys'}/: grid-signing-key.pem (private, mode 0600: keep it, sign new "
        "grids with it) and grid-signing-key.pub.pem (the daemon's grid.public_key)"
    )
    print(
        f"wrote {d / CONFIG_NAME}: CAN {report.can_interface} {report.can_channel}, "
        f"session logs in {report.logs}"
    )
    checked = preflight(load_config(report.config))
    for line in checked.problems:
        print(f"cmm-comp: note: {line}", file=sys.stderr)
    command = shlex.join(["cmm-comp", "daemon", "--config", str(d / CONFIG_NAME)])
    print(f"start the daemon with:\n  {command}")
    return 0


def print_check(config: Any, problems: list[str], warnings: list[str], loaded: Any) -> int:
    """``--check``'s output: every warning and problem one line on stderr; the ok line (or the
    count of problems) on stdout. Exit code 2 when there is a problem."""
    for line in warnings:
        print(f"cmm-comp: warning: {line}", file=sys.stderr)
    for line in problems:
        fail(line)
    if problems or loaded is None:
        print(f"{config.source}: {len(problems)} problem(s)")
        return 2
    signed = f"signed by key {loaded.signed_by}" if loaded.signed_by else "unsigned"
    stylus = config.grid.stylus_mm
    stylus_text = (
        f"stylus {list(loaded.probe_offset_mm)} mm (the grid's probe offset)"
        if stylus is None
        else f"stylus {list(stylus)} mm (grid.stylus_mm)"
    )
    notes = f" ({len(warnings)} warning(s) above)" if warnings else ""
    print(
        f"{config.source}: ok{notes}; grid {loaded.path} sha256 {loaded.sha256} ({signed}, "
        f"machine {loaded.machine!r}); {stylus_text}"
    )
    return 0


def check_daemon(args: argparse.Namespace) -> int:
    """``cmm-comp daemon --check``: every problem of the configuration and of what it names."""
    from cmm_comp.cli.daemon_check import preflight
    from cmm_comp.daemon.config import ConfigError, load_config_and_problems

    try:
        config, problems = load_config_and_problems(args.config, args)
    except ConfigError as exc:  # not TOML at all: nothing else can be checked
        for line in exc.lines:
            fail(line)
        return 2
    checked = preflight(config, config_ok=not problems)
    warnings = config.notes + checked.warnings
    return print_check(config, problems + checked.problems, warnings, checked.loaded)


def cmd_daemon(args: argparse.Namespace) -> int:
    """Run the daemon until SIGTERM/SIGINT."""
    from cmm_comp.daemon.config import ConfigError, load_config

    if args.check:
        return check_daemon(args)
    try:
        config = load_config(args.config, args)
    except ConfigError as exc:
        for line in exc.lines:
            fail(line)
        return 2
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
    if service.grid_problem is not None:
        print(
            f"cmm-comp daemon: NOT CORRECTING: {service.grid_problem}; every answer says "
            "no_grid and carries the indicated position until a trusted grid loads (SIGHUP "
            "reloads; `cmm-comp daemon --config … --check` lists every problem)",
            file=sys.stderr,
        )
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

    from cmm_comp.cli.sessionlog.replay import ReplayError, replay_offline, replay_to_bus

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
