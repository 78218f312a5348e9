"""Every exception class of the project derives from :class:`CmmCompError`, defined here.

Messages are written for people: they name the file, key or value and what is allowed.
Errors about bad input (machine, measurement, grid and real-data files; daemon configuration)
are also ``ValueError``; the daemon's log-writer failure is also a ``RuntimeError``. The
compensation package's own errors are defined here; the daemon's are defined beside their code and
derive from :class:`CmmCompError`. (The protocol package, dependency-free codecs, keeps its two
client errors on ``RuntimeError``/``TimeoutError`` so that importing it stays light.)
"""

from __future__ import annotations

__all__ = [
    "CmmCompError",
    "ExportError",
    "GridFileError",
    "GridSignatureError",
    "MachineFileError",
    "MeasurementFileError",
    "RealDataError",
    "SchemaError",
]


class CmmCompError(Exception):
    """Base class of every exception this project defines (``except CmmCompError`` catches all)."""


class MachineFileError(CmmCompError, ValueError):
    """A machine description (TOML, CSV or seed-style file set) is malformed.

    ``where`` (a key path, a line) and ``problem`` name the first problem; ``lines`` holds one
    line per problem, each naming the file (the message is those lines joined by newlines).
    """

    def __init__(
        self, source: str, where: str, problem: str, *, lines: list[str] | None = None
    ) -> None:
        self.source = source
        self.where = where
        self.problem = problem
        location = f"{source}: {where}" if where else source
        self.lines = list(lines) if lines else [f"{location}: {problem}"]
        super().__init__("\n".join(self.lines))

    @classmethod
    def from_schema(cls, exc: SchemaError, source: str) -> MachineFileError:
        """Every problem a check of the file's values found (:class:`SchemaError`)."""
        loc = exc.locs[0] if exc.locs else ()
        where = "".join(f"[{p}]" if isinstance(p, int) else f".{p}" for p in loc).lstrip(".")
        first = exc.lines[0].removeprefix(f"{source}: ")
        return cls(source, where, first.removeprefix(where).lstrip(": "), lines=exc.lines)


class SchemaError(CmmCompError, ValueError):
    """A TOML file's values break its rules (:mod:`.toml_schema`). ``lines``: one line per
    problem, naming the file and the key path; ``locs``: the key path of each
    (``("can", "bitrate")``)."""

    def __init__(self, lines: list[str], locs: list[tuple[str | int, ...]] | None = None) -> None:
        self.lines = list(lines)
        self.locs = list(locs or [])
        super().__init__("\n".join(self.lines))


class MeasurementFileError(CmmCompError, ValueError):
    """A verification measurements file is malformed."""


class GridFileError(CmmCompError, ValueError):
    """A grid file cannot be used: the message names the file and the problem."""


class GridSignatureError(GridFileError):
    """A grid is unsigned, its Ed25519 signature does not verify, or a key file is unusable."""


class ExportError(CmmCompError, ValueError):
    """The model cannot be written in a controller's table format as asked (limits, ranges, bad
    options): the message names the format, the limit and where it comes from."""


class RealDataError(CmmCompError, ValueError):
    """A real-data file is malformed; the message names the file, the line and the problem."""
