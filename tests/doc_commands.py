"""The commands a document prints, run exactly as printed (issue 25: documented commands that
failed when a user ran them, while our own tests ran something else).

:func:`bash_blocks` reads the fenced ``bash`` blocks of a Markdown file and returns their command
lines (comments dropped, ``\\`` continuations joined); :func:`run_cli` runs one ``cmm-comp …``
line in this process through the CLI's own ``main()`` (the entry point the installed script
calls), from a working directory, and measures its CPU time (all threads: numba's included).
"""

from __future__ import annotations

import contextlib
import io
import os
import re
import shlex
import time
from dataclasses import dataclass
from pathlib import Path

from cmm_comp.cli.main import main as cli_main

__all__ = ["CliRun", "bash_blocks", "run_cli"]


def bash_blocks(path: Path) -> list[list[str]]:
    """The command lines of every ```` ```bash ```` block of ``path``, in order."""
    text = path.read_text(encoding="utf-8")
    blocks = []
    for body in re.findall(r"^```bash\n(.*?)^```", text, flags=re.S | re.M):
        lines: list[str] = []
        pending = ""
        for raw in body.splitlines():
            line = raw.rstrip()
            if not pending and (not line.strip() or line.lstrip().startswith("#")):
                continue
            if line.endswith("\\"):
                pending += line[:-1].strip() + " "
                continue
            lines.append((pending + line.strip()).strip())
            pending = ""
        blocks.append(lines)
    return blocks


@dataclass(frozen=True)
class CliRun:
    """What one command did: exit code, its stdout and stderr, wall and CPU seconds."""

    line: str
    code: int
    out: str
    err: str
    wall_s: float
    cpu_s: float


def run_cli(line: str, cwd: Path) -> CliRun:
    """Run the ``cmm-comp …`` command ``line`` (shell words, no pipes) in ``cwd`` in-process."""
    words = shlex.split(line)
    assert words and words[0] == "cmm-comp", f"not a cmm-comp command: {line}"
    out, err = io.StringIO(), io.StringIO()
    before = os.getcwd()
    t0, c0 = time.perf_counter(), time.process_time()
    try:
        os.chdir(cwd)
        with contextlib.redirect_stdout(out), contextlib.redirect_stderr(err):
            try:
                code = cli_main(words[1:])
            except SystemExit as exc:  # argparse: a usage error (2) or --help (0)
                code = exc.code if isinstance(exc.code, int) else 2
    finally:
        os.chdir(before)
    return CliRun(
        line, code, out.getvalue(), err.getvalue(),
        time.perf_counter() - t0, time.process_time() - c0,
    )  # fmt: skip
