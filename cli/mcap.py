"""``cmm-comp mcap recover``: make a session log cut by a crash whole again.

``add_parsers(subparsers)`` registers the ``mcap`` command group; ``cli/main.py`` calls it.
Handlers return the exit code: 0 success, 2 bad input (one line naming the file; never a
traceback). See docs/mcap.md ("Recovering a cut file").
"""

from __future__ import annotations

import argparse
from typing import Any

from .common import fail


def add_parsers(subparsers: Any) -> None:
    """Register ``mcap`` (with its ``recover`` subcommand) on an argparse subparsers object."""
    p = subparsers.add_parser("mcap", help="session log (MCAP) tools: recover a cut file")
    sub = p.add_subparsers(dest="mcap_command", required=True, metavar="MCAP_COMMAND")
    r = sub.add_parser(
        "recover",
        help="rewrite an MCAP file cut by a crash as a complete, indexed file",
        description="Read CUT.mcap record by record (CRCs checked) up to the first cut or "
        "corrupt record and write everything before it (schemas, channels, messages, metadata) "
        "as a complete, indexed MCAP file. Prints the messages recovered per topic and where "
        "the cut was.",
    )
    r.add_argument("source", metavar="CUT.mcap", help="the cut (or any) MCAP file")
    r.add_argument("-o", "--output", required=True, metavar="FIXED.mcap", help="file to write")
    r.add_argument("--force", action="store_true", help="replace FIXED.mcap if it exists")
    r.set_defaults(handler=cmd_recover)


def cmd_recover(args: argparse.Namespace) -> int:
    """Recover ``args.source`` into ``args.output``; print what was recovered."""
    from cmm_comp.cli.sessionlog.recover import recover

    try:
        report = recover(args.source, args.output, overwrite=args.force)
    except FileNotFoundError as exc:
        return fail(f"{exc.filename or args.source}: no such file")
    except (ValueError, FileExistsError) as exc:
        return fail(str(exc))
    if report.complete:
        where = f"{report.source}: complete ({report.size} bytes), nothing was cut"
    else:
        where = (
            f"{report.source}: cut at byte {report.cut_at} of {report.size} "
            f"({report.size - (report.cut_at or 0)} bytes unreadable: {report.error})"
        )
    print(where)
    print(f"recovered {report.messages} messages into {report.output}")
    rows = sorted(report.messages_by_topic.items())
    width = max((len(t) for t, _ in rows), default=0)
    for topic, n in rows:
        print(f"  {topic:<{width}}  {n}")
    if report.orphan_messages:
        print(f"  ({report.orphan_messages} messages on undefined channels skipped)")
    return 0
