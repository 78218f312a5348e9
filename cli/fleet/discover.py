"""Find a fleet's sessions under ROOT and key each by the content of its inputs.

Measurement sessions (``fleet diagnose``): ``ROOT/<machine>/<date>/`` holding ``machine.toml``
and ``measurements.csv``; the directory name starts with the ISO date (``2026-03-09``, or
``2026-03-09-a`` for a second session that day). A directory with neither file is not a session
(a machine's ``grid/``, a folder of logs); one with only one of them is reported as failed.

Session logs (``fleet replay``): every ``*.mcap`` under ``ROOT/<machine>/`` (any depth). The
daemon's rolled files of one session (``session-YYYYmmddTHHMMSS-NNN.mcap`` in one directory)
are one session, replayed as the glob ``…/session-YYYYmmddTHHMMSS-*.mcap``, as
``cmm-comp replay`` would be given it; any other file is a session of its own.

A session's key is the SHA-256 of the task kind, the code fingerprint
(:func:`.tasks.code_fingerprint`) and the bytes of every input: ``machine.toml``, the files its
tables name (``file = …``), ``measurements.csv``; or the log files, the source as given and the
grid named by the map (its path and bytes).
"""

from __future__ import annotations

import glob
import hashlib
import re
import tomllib
from collections.abc import Iterator, Mapping
from dataclasses import dataclass
from datetime import date
from pathlib import Path
from typing import Any

from .tasks import file_sha256

__all__ = ["Job", "diagnose_jobs", "diagnose_key", "read_grid_map", "replay_jobs", "replay_key"]

_ROLLED = re.compile(r"^(session-\d{8}T\d{6}-)\d+\.mcap$")
_DATE = re.compile(r"^(\d{4}-\d{2}-\d{2})")


@dataclass(frozen=True)
class Job:
    """One session: ``path`` relative to ROOT (POSIX), the task's arguments (absolute paths), its
    date (measurement sessions) and ``problem`` when it cannot be run (reported as failed)."""

    machine: str
    path: str
    args: tuple[str | None, ...]
    day: date | None = None
    problem: str | None = None


def _machines(root: Path) -> Iterator[Path]:
    for entry in sorted(root.iterdir()):
        if entry.is_dir() and not entry.name.startswith("."):
            yield entry


def diagnose_jobs(root: Path) -> list[Job]:
    """Every measurement session under ``root`` (module docstring), sorted by machine and path."""
    jobs: list[Job] = []
    for mdir in _machines(root):
        for sdir in sorted(p for p in mdir.iterdir() if p.is_dir()):
            toml, csv = sdir / "machine.toml", sdir / "measurements.csv"
            has = toml.is_file(), csv.is_file()
            if not any(has):
                continue
            rel = sdir.relative_to(root).as_posix()
            args = (str(toml), str(csv))
            match = _DATE.match(sdir.name)
            day = None
            problem = None
            if match:
                try:
                    day = date.fromisoformat(match.group(1))
                except ValueError:
                    problem = f"{match.group(1)} is not a date"
            else:
                problem = "the directory name must start with the session's date (YYYY-MM-DD)"
            if not all(has):
                problem = f"{'measurements.csv' if has[0] else 'machine.toml'} missing"
            jobs.append(Job(mdir.name, rel, args, day, problem))
    return jobs


def replay_jobs(root: Path, grid_map: Mapping[str, Path]) -> list[Job]:
    """Every session log under ``root`` (module docstring), each with the grid the map names
    for its machine (None: the session's own), sorted by machine and path."""
    jobs: list[Job] = []
    for mdir in _machines(root):
        grid = grid_map.get(mdir.name)
        seen: set[str] = set()
        for f in sorted(mdir.rglob("*.mcap")):
            rolled = _ROLLED.match(f.name)
            if rolled:
                source = glob.escape(str(f.parent / rolled.group(1))) + "*.mcap"
                rel = (f.parent / rolled.group(1)).relative_to(root).as_posix() + "*.mcap"
            else:
                source, rel = str(f), f.relative_to(root).as_posix()
            if source in seen:
                continue
            seen.add(source)
            jobs.append(Job(mdir.name, rel, (source, None if grid is None else str(grid))))
    return jobs


def _referenced_files(toml_path: Path) -> list[Path]:
    """Files a machine description's tables name (``file = "…"``, relative to it)."""
    try:
        data = tomllib.loads(toml_path.read_text(encoding="utf-8"))
    except (OSError, UnicodeDecodeError, tomllib.TOMLDecodeError):
        return []  # the task reports the file; its bytes are in the key anyway
    found: list[Path] = []

    def walk(node: Any) -> None:
        if isinstance(node, dict):
            for k, v in node.items():
                if k == "file" and isinstance(v, str):
                    found.append((toml_path.parent / v).resolve())
                else:
                    walk(v)
        elif isinstance(node, list):
            for v in node:
                walk(v)

    walk(data)
    return found


def _add_file(digest: Any, label: str, path: Path) -> None:
    digest.update(f"{label}\0{path.name}\0".encode())
    try:
        digest.update(file_sha256(path).encode())
    except OSError as exc:
        digest.update(f"unreadable: {exc.strerror}".encode())


def diagnose_key(job: Job, fingerprint: str) -> str:
    """Content key of a measurement session (module docstring)."""
    digest = hashlib.sha256(f"diagnose\0{fingerprint}\0".encode())
    toml, csv = (Path(str(a)) for a in job.args)
    _add_file(digest, "machine", toml)
    for ref in _referenced_files(toml):
        _add_file(digest, "table", ref)
    _add_file(digest, "measurements", csv)
    return digest.hexdigest()


def replay_key(job: Job, fingerprint: str) -> str:
    """Content key of a session log and the grid the map names (module docstring)."""
    source, grid = job.args
    digest = hashlib.sha256(f"replay\0{fingerprint}\0{source}\0".encode())
    rolled = str(source).endswith("-*.mcap")  # a daemon's rolled files (replay_jobs)
    for f in sorted(glob.glob(str(source))) if rolled else [str(source)]:
        _add_file(digest, f, Path(f))
    if grid is not None:
        _add_file(digest, f"grid {grid}", Path(grid))
    return digest.hexdigest()


def read_grid_map(path: str | Path, machines: set[str]) -> dict[str, Path]:
    """``MAP.toml``: ``[grids]`` machine = grid path (relative to the map). Raises ValueError
    naming the file and key for anything else, an unknown machine or a missing grid file."""
    path = Path(path)
    try:
        data = tomllib.loads(path.read_text(encoding="utf-8"))
    except OSError as exc:
        raise ValueError(f"{path}: cannot read the grid map ({exc.strerror})") from None
    except (UnicodeDecodeError, tomllib.TOMLDecodeError) as exc:
        raise ValueError(f"{path}: invalid TOML: {exc}") from None
    extra = sorted(set(data) - {"grids"})
    if extra:
        raise ValueError(f'{path}: unknown key {extra[0]!r}; allowed: [grids] machine = "GRID"')
    grids = data.get("grids")
    if not isinstance(grids, dict) or not grids:
        raise ValueError(f'{path}: [grids] missing or empty; write [grids] then machine = "GRID"')
    out: dict[str, Path] = {}
    for machine, value in grids.items():
        where = f"{path}: grids.{machine}"
        if machine not in machines:
            known = ", ".join(sorted(machines)) or "none"
            raise ValueError(f"{where}: no such machine under ROOT (machines: {known})")
        if not isinstance(value, str):
            raise ValueError(f"{where}: expected a grid file path (a string), got {value!r}")
        grid = (path.parent / value).resolve()
        if not grid.is_file():
            raise ValueError(f"{where}: {grid}: no such grid file")
        out[machine] = grid
    return out
