"""``cmm-comp import camonitor``: dense measurements from a raw EPICS camonitor stream.

``cmm-comp import camonitor LOG --axis x --position PV --reference PV --out-dir DIR`` writes
``DIR/machine.toml`` (the stage's calibrated linear model), ``DIR/measurements.csv`` (one row per
reference sample, time-aligned), ``DIR/summary.json`` and ``DIR/import.png``
(compensation/formats/camonitor_stream.py, camonitor_output.py; docs/formats.md §3). A bad log
gives one line ``cmm-comp: error: …`` (exit 2) and writes nothing.
"""

from __future__ import annotations

import argparse
import sys
from typing import Any

__all__ = ["add_parsers", "cmd_import_camonitor"]


def _progress(message: str) -> None:
    print(f"cmm-comp import: {message}", file=sys.stderr, flush=True)


def _command_pv(args: argparse.Namespace) -> str | None:
    """``--command`` or, for an ecmc axis ``…-PosAct``, its ``…-PosCmd``."""
    if args.command_pv:
        return str(args.command_pv)
    if args.position.endswith("-PosAct"):
        return args.position[: -len("PosAct")] + "PosCmd"
    return None


def cmd_import_camonitor(args: argparse.Namespace) -> int:
    """Read, align, write; print the summary's key numbers."""
    from cmm_comp.compensation.formats.camonitor_output import import_summary, write_import
    from cmm_comp.compensation.formats.camonitor_stream import StreamOptions, import_camonitor

    opts = StreamOptions(
        position_pv=args.position,
        reference_pv=args.reference,
        axis=args.axis,
        test_pv=args.test or None,
        command_pv=_command_pv(args),
        encoder_pv=args.encoder,
        reference_scale=args.reference_scale,
        rest_speed_mm_s=args.rest_speed,
        max_accel_mm_s2=args.max_accel,
        max_speed_mm_s=args.max_speed,
        keep_accelerating=args.keep_accelerating,
        max_lag_s=args.max_lag,
        smooth_s=args.smooth,
        latency_s=args.latency,
    )
    aligned = import_camonitor(args.log, opts, None if args.quiet else _progress)
    paths = write_import(
        aligned, args.out_dir, str(args.log), name=args.name, plot=not args.no_plot
    )
    s = import_summary(aligned, str(args.log))
    rev = s["reversal_um"]

    def fmt(r: dict[str, Any]) -> str:
        return "n/a" if r["reversal_um"] is None else f"{r['reversal_um']:+.1f} µm"

    print(
        f"{s['rows']} rows in {s['cycles']} cycle(s) ({s['cycles_from']}); "
        f"left out: "
        + ", ".join(
            f"{k} {v}" for k, v in s["counts"].items() if not k.startswith(("kept", "ref")) and v
        )
    )
    print(
        f"reference map: {aligned.gain:.6f} mm/unit, offset {aligned.offset_mm:+.5f} mm; "
        f"latency {s['latency_ms']['value']:+.1f} ± {s['latency_ms']['sigma']:.1f} ms; "
        f"alignment error RMS {s['alignment_error_um']['rms']:.2f} µm "
        f"(max {s['alignment_error_um']['max']:.2f} µm)"
    )
    print(
        f"reversal at rest {fmt(rev['at_rest'])}, moving {fmt(rev['moving'])} "
        f"(without the latency correction {fmt(rev['moving_without_latency_correction'])})"
    )
    print("wrote " + ", ".join(str(p) for p in paths.values()))
    return 0


def add_parsers(subparsers: Any) -> None:
    """Add the ``import`` group (``import camonitor``) to an argparse subparsers object. Long on purpose: one flat list of the
    subcommand's flags, in the order ``--help`` prints them."""
    group = subparsers.add_parser("import", help="import real measurements (camonitor streams)")
    sub = group.add_subparsers(dest="import_command", required=True, metavar="SOURCE")
    p = sub.add_parser(
        "camonitor",
        help="dense, time-aligned measurements of one axis from a raw EPICS camonitor log",
        description="Align an axis position PV and a reference PV of a camonitor log (latency "
        "estimated and corrected) and write DIR/machine.toml (calibrated linear model), "
        "DIR/measurements.csv (one row per reference sample), DIR/summary.json, DIR/import.png.",
    )
    p.add_argument("log", help="camonitor log: lines 'PV date time value [alarm]'")
    p.add_argument("--axis", choices=("x", "y", "z"), default="x", help="machine axis (default x)")
    p.add_argument(
        "--position",
        required=True,
        metavar="PV",
        help="axis position PV, mm (e.g. TARGET_DU:X-PosAct)",
    )
    p.add_argument(
        "--reference",
        required=True,
        metavar="PV",
        help="reference PV (e.g. IOC_TEST:ILD_DownSample)",
    )
    p.add_argument("--out-dir", required=True, metavar="DIR", help="output folder (created)")
    p.add_argument("--name", help="machine name (default: LOG stem + axis)")
    p.add_argument(
        "--test",
        metavar="PV",
        default="IOC_TEST:TestNumber",
        help="ISO 230-2 test-number PV giving the cycles (default IOC_TEST:TestNumber; '' or "
        "absent from the log: cycles from the motion)",
    )
    p.add_argument(
        "--command",
        metavar="PV",
        dest="command_pv",
        help="commanded-position PV (default: the position PV's ...-PosCmd)",
    )
    p.add_argument(
        "--encoder",
        metavar="PV",
        help="raw encoder-count PV used as position instead (mapped onto --position)",
    )
    p.add_argument(
        "--reference-scale",
        metavar="MM_PER_UNIT",
        type=float,
        help="fixed mm per raw reference unit, sign included (default: fitted)",
    )
    p.add_argument(
        "--latency",
        type=float,
        metavar="S",
        help="latency of the reference, s (default: estimated)",
    )
    p.add_argument(
        "--max-lag",
        type=float,
        metavar="S",
        default=1.0,
        help="latency search range ± s (default 1)",
    )
    p.add_argument(
        "--smooth",
        metavar="S",
        type=float,
        default=2.0,
        help="velocity window of the latency estimate, s (default 2)",
    )
    p.add_argument(
        "--rest-speed",
        type=float,
        metavar="MM_S",
        default=1e-3,
        help="at rest below, mm/s (default 0.001)",
    )
    p.add_argument(
        "--max-accel",
        metavar="MM_S2",
        type=float,
        default=0.01,
        help="steady motion: velocity change below, mm/s² (default 0.01)",
    )
    p.add_argument(
        "--max-speed", type=float, metavar="MM_S", help="leave out samples faster than this, mm/s"
    )
    p.add_argument(
        "--keep-accelerating",
        action="store_true",
        help="keep samples taken while the axis accelerates (left out by default)",
    )
    p.add_argument("--no-plot", action="store_true", help="do not write import.png")
    p.add_argument("--quiet", action="store_true", help="no progress messages")
    p.set_defaults(handler=cmd_import_camonitor)
