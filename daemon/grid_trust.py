"""Which grids the daemon trusts: signed by our key, built for this machine, inside its volume.

A grid's SHA-256 proves only that the file is intact; anyone can edit a header and recompute it.
Before a grid is built from a file, :meth:`GridTrust.check` (given to ``CorrectionGrid.load``
as ``verify``, so it sees exactly the bytes the grid is built from) requires:

* **signature** — an Ed25519 signature by ``grid.public_key`` over the SHA-256 and the header
  (``compensation.grid.signing``). Unsigned grids are refused unless ``grid.allow_unsigned``; a
  signature that does not verify is always refused when a key is configured;
* **machine** — the header's machine sha256 equals the one of ``grid.machine`` (the machine TOML,
  hashed by the daemon) or ``grid.expect_machine_sha256``. With neither set every grid is
  refused unless ``grid.allow_any_machine``;
* **volume** — with ``grid.machine`` set, the header volume lies inside the machine's volume
  (a header edited to a larger volume would stretch the grid over points it never saw).

Every refusal is a :class:`GridTrustError` with one line naming the file and the reason.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

import numpy as np

from cmm_comp.compensation.errors import CmmCompError, GridFileError
from cmm_comp.compensation.grid.signing import (
    load_public_key,
    signature_info,
    verify_signature,
)
from cmm_comp.compensation.grid.status import VOLUME_TOL_MM

if TYPE_CHECKING:
    from cmm_comp.compensation.grid.file import GridContents

    from .config import GridSection


NO_KEY = (
    "grid.public_key is not set, so a grid's signature cannot be verified (set it: `cmm-comp "
    "grid keygen` makes a key pair, `cmm-comp daemon init` all of it; or grid.allow_unsigned = "
    "true)"
)
NO_MACHINE = (
    "no machine bound: set grid.machine (the machine TOML) or grid.expect_machine_sha256, or "
    "grid.allow_any_machine = true"
)


class GridTrustError(GridFileError):
    """A grid is not trusted (unsigned, bad signature, other machine, volume too large)."""


@dataclass(frozen=True)
class TrustedMachine:
    """What the daemon knows of its machine: description sha256 and, if given, its volume."""

    sha256: str
    source: str
    lower_mm: tuple[float, float, float] | None = None
    upper_mm: tuple[float, float, float] | None = None


@dataclass(frozen=True)
class GridTrust:
    """The ``[grid]`` trust settings (docs/daemon.md, "Trusted grids")."""

    public_key: str = ""
    allow_unsigned: bool = False
    machine: str = ""
    expect_machine_sha256: str = ""
    allow_any_machine: bool = False

    @classmethod
    def from_section(cls, section: GridSection) -> GridTrust:
        """From the daemon configuration's ``[grid]`` section."""
        return cls(
            section.public_key,
            section.allow_unsigned,
            section.machine,
            section.expect_machine_sha256,
            section.allow_any_machine,
        )

    def resolve_machine(self) -> TrustedMachine | None:
        """Read ``machine`` (hashing its description) or take ``expect_machine_sha256``.

        GridTrustError (one line) when the machine file is unusable or disagrees with
        ``expect_machine_sha256``; None when neither is set.
        """
        if self.machine:
            from cmm_comp.compensation.machine import Machine

            try:
                m = Machine.from_toml(self.machine)
            except (CmmCompError, ValueError, OSError, RecursionError) as exc:
                lines = str(exc).splitlines() or [""]  # one line per problem of the file
                raise GridTrustError("\n".join(f"grid.machine: {x}" for x in lines)) from None
            sha = m.identity_sha256()
            if self.expect_machine_sha256 and self.expect_machine_sha256 != sha:
                raise GridTrustError(
                    f"grid.machine {self.machine} has description sha256 {sha[:12]}…, but "
                    f"grid.expect_machine_sha256 is {self.expect_machine_sha256[:12]}…"
                )
            lower = tuple(float(v) for v in m.volume.lower_mm)
            upper = tuple(float(v) for v in m.volume.upper_mm)
            return TrustedMachine(sha, self.machine, lower, upper)  # type: ignore[arg-type]
        if self.expect_machine_sha256:
            return TrustedMachine(self.expect_machine_sha256, "grid.expect_machine_sha256")
        return None

    def setting_problems(self) -> tuple[TrustedMachine | None, dict[str, str]]:
        """The machine (:meth:`resolve_machine`) and the problems of the settings themselves,
        by the check they make unusable (``"machine"``: a machine file that does not read,
        none bound; ``"signature"``: no key set, a key that does not load). Every grid would
        be refused for each; :meth:`problems` leaves such a check out."""
        found: dict[str, str] = {}
        machine = None
        try:
            machine = self.resolve_machine()
        except GridTrustError as exc:
            found["machine"] = str(exc)
        if machine is None and "machine" not in found and not self.allow_any_machine:
            found["machine"] = NO_MACHINE
        if not self.public_key and not self.allow_unsigned:
            found["signature"] = NO_KEY
        elif self.public_key:
            try:
                load_public_key(self.public_key)
            except CmmCompError as exc:
                found["signature"] = f"grid.public_key: {exc}"
        return machine, found

    def check(self, contents: GridContents, machine: TrustedMachine | None) -> str:
        """Refuse (GridTrustError) unless the grid is trusted; return the signer's key id
        (empty when unsigned grids are allowed and none was verified)."""
        signer = self._check_signature(contents)
        self._check_machine(contents, machine)
        return signer

    def problems(
        self,
        contents: GridContents,
        machine: TrustedMachine | None,
        check_signature: bool = True,
        check_machine: bool = True,
    ) -> list[str]:
        """Every reason :meth:`check` would refuse the grid, each check run on its own (one
        line each; [] when trusted). A check whose setting is already known to be unusable (a
        key file that does not load, a machine file that does not read) is left out with
        ``check_signature`` / ``check_machine`` False: its problem is the setting's."""
        out: list[str] = []
        if check_signature:
            try:
                self._check_signature(contents)
            except GridFileError as exc:
                out.append(str(exc))
        if check_machine:
            try:
                self._check_machine(contents, machine)
            except GridFileError as exc:
                out.append(str(exc))
        return out

    def _check_signature(self, contents: GridContents) -> str:
        where = contents.source
        if not self.public_key:
            if not self.allow_unsigned:
                raise GridTrustError(f"{where}: {NO_KEY}")
            signature_info(contents)  # still refuse a malformed signature member
            return ""
        key = load_public_key(self.public_key)  # GridSignatureError names the key file
        if contents.signature is None and self.allow_unsigned:
            return ""
        return verify_signature(contents, key)

    def _check_machine(self, contents: GridContents, machine: TrustedMachine | None) -> None:
        where = contents.source
        header: dict[str, Any] = contents.header
        built_for = header.get("machine")
        built_for = built_for if isinstance(built_for, dict) else {}
        if machine is None:
            if not self.allow_any_machine:
                raise GridTrustError(f"{where}: {NO_MACHINE}")
            return
        if built_for.get("sha256") != machine.sha256:
            raise GridTrustError(
                f"{where}: grid was built for machine {built_for.get('name')!r} (description "
                f"sha256 {str(built_for.get('sha256'))[:12]}…), not for {machine.source} "
                f"(sha256 {machine.sha256[:12]}…)"
            )
        if machine.lower_mm is None or machine.upper_mm is None:
            return
        try:
            volume = header["volume"]
            lo = np.asarray(volume["lower_mm"], dtype=float).reshape(3)
            hi = np.asarray(volume["upper_mm"], dtype=float).reshape(3)
        except (KeyError, TypeError, ValueError):
            raise GridTrustError(f"{where}: header volume is malformed") from None
        m_lo, m_hi = np.asarray(machine.lower_mm), np.asarray(machine.upper_mm)
        inside = (
            np.all(np.isfinite(lo))
            and np.all(np.isfinite(hi))
            and np.all(lo >= m_lo - VOLUME_TOL_MM)
            and np.all(hi <= m_hi + VOLUME_TOL_MM)
        )
        if not inside:
            raise GridTrustError(
                f"{where}: grid volume {lo.tolist()} .. {hi.tolist()} mm exceeds the machine's "
                f"{m_lo.tolist()} .. {m_hi.tolist()} mm ({machine.source})"
            )
