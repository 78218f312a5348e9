"""Results stored next to OUT, keyed by content, and OUT written from them as a stream.

Each finished session is one file ``OUT.results/<k[:2]>/<key>.json`` (written atomically as soon
as its task returns, so an interrupted run keeps what it finished, and a re-run skips it):
``{"key", "kind", "machine", "path", "json": <the one-by-one command's JSON text>, …}``.
:func:`write_out` assembles OUT from them one session at a time (never the whole fleet in
memory), into a temporary file renamed over OUT at the end: a failed run leaves the previous OUT.
"""

from __future__ import annotations

import json
from collections.abc import Callable, Iterator, Sequence
from pathlib import Path
from typing import IO, Any

from cmm_comp.compensation.formats.atomic import atomic_output, write_text_atomic

from .discover import Job

__all__ = ["ResultStore", "write_out"]


class ResultStore:
    """The results of one OUT: ``<OUT>.results/`` (module docstring)."""

    def __init__(self, out: str | Path) -> None:
        out = Path(out)
        self.root = out.with_name(out.name + ".results")

    def _file(self, key: str) -> Path:
        return self.root / key[:2] / f"{key}.json"

    def get(self, key: str) -> dict[str, Any] | None:
        """The stored entry of ``key``, or None (also for an unreadable, half-written file)."""
        try:
            entry = json.loads(self._file(key).read_text(encoding="utf-8"))
        except (OSError, ValueError):
            return None
        return entry if isinstance(entry, dict) and entry.get("key") == key else None

    def put(self, key: str, entry: dict[str, Any]) -> None:
        """Store ``entry`` under ``key`` (atomically)."""
        path = self._file(key)
        path.parent.mkdir(parents=True, exist_ok=True)
        write_text_atomic(path, json.dumps({**entry, "key": key}) + "\n")


def _write_sessions(
    fh: IO[str], jobs: Sequence[Job], keys: dict[str, str], store: ResultStore, field: str
) -> None:
    fh.write('{\n"sessions": [')
    first = True
    for job in jobs:
        key = keys.get(job.path)
        entry = store.get(key) if key else None
        if entry is None:
            continue
        head = json.dumps({"machine": job.machine, "path": job.path})[:-1]
        fh.write(("\n" if first else ",\n") + f'{head}, "{field}": {entry["json"]}}}')
        first = False
    fh.write("\n],\n")


def stored_by_machine(
    jobs: Sequence[Job], keys: dict[str, str], store: ResultStore
) -> Iterator[tuple[str, list[tuple[Job, dict[str, Any]]]]]:
    """Per machine (in order), its jobs with a stored result and that result (parsed): one
    machine in memory at a time."""
    machine: str | None = None
    group: list[tuple[Job, dict[str, Any]]] = []
    for job in [*jobs, None]:
        if job is None or job.machine != machine:
            if machine is not None:
                yield machine, group
            if job is None:
                return
            machine, group = job.machine, []
        key = keys.get(job.path)
        entry = store.get(key) if key else None
        if entry is not None:
            group.append((job, json.loads(entry["json"])))


def write_out(
    out: str | Path,
    field: str,
    jobs: Sequence[Job],
    keys: dict[str, str],
    store: ResultStore,
    machine_section: Callable[[str, list[tuple[Job, dict[str, Any]]]], dict[str, Any]],
    extra: dict[str, Any],
) -> None:
    """Write OUT: ``sessions`` (one line each: machine, path, ``field``: the stored JSON),
    ``machines`` (``machine_section`` of each machine's stored results), then ``extra``."""
    with atomic_output(out) as fh:
        _write_sessions(fh, jobs, keys, store, field)
        fh.write('"machines": {')
        for i, (machine, group) in enumerate(stored_by_machine(jobs, keys, store)):
            section = json.dumps(machine_section(machine, group), allow_nan=False)
            fh.write(("\n" if i == 0 else ",\n") + f"{json.dumps(machine)}: {section}")
        fh.write("\n}")
        for k, v in extra.items():
            fh.write(f",\n{json.dumps(k)}: {json.dumps(v, allow_nan=False)}")
        fh.write("\n}\n")
