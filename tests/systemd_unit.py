"""A systemd unit file read the way systemd reads it, and the sandbox it asks for (no tests here).

Written from systemd.unit(5) and systemd.exec(5) of systemd 252, not from the daemon's code:

* syntax: ``[Section]`` headers, ``Key=Value`` lines, ``#``/``;`` comments, a trailing ``\\``
  continues a line; a key may repeat (``Environment=``), an empty value resets its list;
* ``Environment=`` takes space-separated ``VAR=value`` words (quotes group), specifiers expanded;
  ``%C`` is the cache root, ``/var/cache`` for the system manager;
* what the unit may write under ``ProtectSystem=strict``: ``ReadWritePaths=``, and the
  directories of ``RuntimeDirectory=`` (``/run/``), ``StateDirectory=`` (``/var/lib/``),
  ``CacheDirectory=`` (``/var/cache/``), ``LogsDirectory=`` (``/var/log/``) — "these options
  imply BindPaths=" — plus the API file systems ``/dev``, ``/proc``, ``/sys`` and, with
  ``PrivateTmp=``, ``/tmp`` and ``/var/tmp``;
* what it may not see with ``ProtectHome=true``: ``/home``, ``/root``, ``/run/user``;
* a path in ``ReadWritePaths=``/``ReadOnlyPaths=``/``InaccessiblePaths=`` without a ``-``
  prefix must exist at start, or the unit fails (status 226/NAMESPACE).
"""

from __future__ import annotations

import shlex
from dataclasses import dataclass
from pathlib import PurePosixPath

DIRECTORY_ROOTS = {
    "RuntimeDirectory": "/run",
    "StateDirectory": "/var/lib",
    "CacheDirectory": "/var/cache",
    "LogsDirectory": "/var/log",
}
SYSTEM_SPECIFIERS = {"%C": "/var/cache", "%L": "/var/log", "%S": "/var/lib", "%t": "/run"}
HOME_PATHS = ("/home", "/root", "/run/user")
API_PATHS = ("/dev", "/proc", "/sys")


@dataclass
class Unit:
    """A parsed unit: ``sections[name]`` is the list of ``(key, value)`` in file order."""

    sections: dict[str, list[tuple[str, str]]]
    header_comments: list[str]

    def values(self, section: str, key: str) -> list[str]:
        """Every value of ``key`` in ``section``, an empty assignment resetting the list."""
        out: list[str] = []
        for k, v in self.sections.get(section, []):
            if k == key:
                out = [] if v == "" else [*out, v]
        return out

    def last(self, section: str, key: str, default: str = "") -> str:
        values = self.values(section, key)
        return values[-1] if values else default

    def words(self, section: str, key: str) -> list[str]:
        """Space-separated values of every assignment of ``key`` (lists like ReadWritePaths=)."""
        return [w for v in self.values(section, key) for w in shlex.split(v)]

    def environment(self) -> dict[str, str]:
        """``Environment=`` assignments with the system manager's specifiers expanded."""
        env: dict[str, str] = {}
        for value in self.values("Service", "Environment"):
            for word in shlex.split(value):
                name, _, val = word.partition("=")
                env[name] = expand(val)
        return env

    def is_true(self, key: str) -> bool:
        return self.last("Service", key).lower() in ("1", "yes", "true", "on")

    def writable(self) -> list[str]:
        """Absolute paths the unit may write below (see the module doc)."""
        paths = [p.lstrip("-+") for p in self.words("Service", "ReadWritePaths")]
        for key, root in DIRECTORY_ROOTS.items():
            paths += [f"{root}/{name.split(':')[0]}" for name in self.words("Service", key)]
        if self.is_true("PrivateTmp"):
            paths += ["/tmp", "/var/tmp"]
        if self.last("Service", "ProtectSystem") == "strict":
            return [*paths, *API_PATHS]
        return [*paths, "/"]  # pragma: no cover - the shipped unit is strict

    def hidden(self) -> list[str]:
        """Absolute paths the unit cannot see."""
        paths = [p.lstrip("-+") for p in self.words("Service", "InaccessiblePaths")]
        if self.is_true("ProtectHome"):
            paths += list(HOME_PATHS)
        return paths

    def must_exist(self) -> list[str]:
        """Paths the unit fails to start without (listed without the ``-`` prefix)."""
        keys = ("ReadWritePaths", "ReadOnlyPaths", "InaccessiblePaths")
        return [p.lstrip("+") for k in keys for p in self.words("Service", k) if p[:1] != "-"]


def expand(value: str) -> str:
    """The system manager's directory specifiers expanded (``%%`` is a literal ``%``)."""
    out = value.replace("%%", "\0")
    for spec, root in SYSTEM_SPECIFIERS.items():
        out = out.replace(spec, root)
    return out.replace("\0", "%")


def parse_unit(text: str) -> Unit:
    """Parse a unit file (see the module doc); comments before the first section are kept."""
    sections: dict[str, list[tuple[str, str]]] = {}
    header: list[str] = []
    current: str | None = None
    pending = ""
    for raw in text.splitlines():
        line = pending + raw.strip() if pending else raw.strip()
        pending = ""
        if line.endswith("\\"):
            pending = line[:-1] + " "
            continue
        if not line or line[0] in "#;":
            if current is None and line.startswith("#"):
                header.append(line[1:].strip())
            continue
        if line.startswith("[") and line.endswith("]"):
            current = line[1:-1]
            sections.setdefault(current, [])
            continue
        if current is None or "=" not in line:
            raise ValueError(f"not a unit file line: {raw!r}")
        key, _, value = line.partition("=")
        sections[current].append((key.strip(), value.strip()))
    return Unit(sections, header)


def under(path: str, roots: list[str]) -> bool:
    """True when ``path`` is one of ``roots`` or below one (lexically, absolute paths)."""
    p = PurePosixPath(path)
    return any(p == PurePosixPath(r) or PurePosixPath(r) in p.parents for r in roots)
