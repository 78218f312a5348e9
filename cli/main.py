"""The one command line, ``cmm-comp``: subcommands from every package are registered here.

Problems with the user's input are printed as one line ``cmm-comp: error: …`` (exit 2), never
as a traceback; nothing is written when a command fails on its input.
"""

from __future__ import annotations

import argparse
import importlib
import sys

# (module, function) pairs that add subcommands; imported lazily so a missing optional part
# cannot break the rest of the CLI.
_REGISTRARS: tuple[tuple[str, str], ...] = (
    ("cmm_comp.cli.model", "add_parsers"),
    ("cmm_comp.cli.grid", "add_parsers"),
    ("cmm_comp.cli.diagnosis", "add_parsers"),
    ("cmm_comp.cli.importing", "add_parsers"),
    ("cmm_comp.cli.daemon", "add_parsers"),
    ("cmm_comp.cli.demo", "add_parsers"),
    ("cmm_comp.cli.mcap", "add_parsers"),
    ("cmm_comp.cli.uncertainty", "add_parsers"),
    ("cmm_comp.cli.export", "add_parsers"),
)


def build_parser() -> argparse.ArgumentParser:
    from cmm_comp.compensation.models import model_table

    parser = argparse.ArgumentParser(
        prog="cmm-comp",
        description="Volumetric error compensation for coordinate measuring machines.",
        epilog="kinematic models (machine.toml: model = CODE or alias):\n"
        + "\n".join(f"  {line}" for line in model_table().splitlines())
        + "\n\nFile formats and every flag: docs/formats.md",
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    sub = parser.add_subparsers(dest="command", required=True, metavar="COMMAND")
    for module_name, func in _REGISTRARS:
        try:
            module = importlib.import_module(module_name)
        except ModuleNotFoundError as exc:
            if exc.name == module_name:
                continue
            raise
        getattr(module, func)(sub)
    return parser


def main(argv: list[str] | None = None) -> int:
    from cmm_comp.compensation import CmmCompError

    parser = build_parser()
    args = parser.parse_args(argv)
    try:
        return int(args.handler(args) or 0)
    except (CmmCompError, ValueError, OSError) as exc:
        for line in str(exc).splitlines() or [""]:  # one line per problem (a file's checks)
            print(f"cmm-comp: error: {line}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print("cmm-comp: interrupted", file=sys.stderr)
        return 130


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
