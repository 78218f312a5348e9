"""Grid trust: Ed25519 signatures (``cmm-comp grid keygen/sign``) and the daemon's checks.

Oracles: the signature is verified here with ``cryptography`` directly on a message rebuilt from
the archive members as docs/formats.md §7 describes them (not through the project's reader);
attacks are real edits of the file (header changed, SHA-256 recomputed) that the plain loader
accepts, so each refusal is shown to matter.
"""

from __future__ import annotations

import functools
import hashlib
import io
import json
import subprocess
import sys
import zipfile
from pathlib import Path

import numpy as np
import pytest
from cryptography.hazmat.primitives.asymmetric.ed25519 import Ed25519PublicKey
from cryptography.hazmat.primitives.serialization import load_pem_public_key
from test_daemon_support import NPL, ROOT, npl_machine

from cmm_comp.cli.main import main as cli_main
from cmm_comp.compensation.grid import CorrectionGrid, generate_signing_key, sign_grid
from cmm_comp.compensation.grid.file import read_grid_contents, write_grid_members
from cmm_comp.daemon.grid_slot import GridLoadError, load_grid
from cmm_comp.daemon.grid_trust import GridTrust

GEC = ROOT / "examples" / "machines" / "gec-mh2.toml"
STEPS = (6, 7, 5)


@functools.cache
def _unsigned_npl(folder: Path) -> bytes:
    path = folder / "npl.grid"
    CorrectionGrid.build(npl_machine(), steps=STEPS).save(path)
    return path.read_bytes()


@pytest.fixture(scope="module")
def keys(tmp_path_factory) -> dict[str, tuple[Path, Path]]:
    base = tmp_path_factory.mktemp("keys")
    return {name: generate_signing_key(base / name) for name in ("ours", "theirs")}


@pytest.fixture(scope="module")
def unsigned(tmp_path_factory) -> bytes:
    return _unsigned_npl(tmp_path_factory.mktemp("grid"))


def _trust(keys, **kw) -> GridTrust:
    return GridTrust(**{"public_key": str(keys["ours"][1]), "machine": str(NPL), **kw})


def _members(path: Path) -> dict[str, bytes]:
    """Raw .npy member data by name, read with zipfile + numpy (not the project's reader)."""
    out = {}
    with zipfile.ZipFile(path) as zf:
        for name in zf.namelist():
            out[name.removesuffix(".npy")] = np.load(io.BytesIO(zf.read(name)))
    return out


def test_cli_keygen_and_sign_verified_independently(tmp_path: Path, unsigned: bytes) -> None:
    grid = tmp_path / "g.grid"
    grid.write_bytes(unsigned)
    assert cli_main(["grid", "keygen", "--out", str(tmp_path / "k")]) == 0
    private, public = (
        tmp_path / "k" / "grid-signing-key.pem",
        tmp_path / "k" / "grid-signing-key.pub.pem",
    )
    assert private.stat().st_mode & 0o077 == 0  # private key readable by its owner only
    assert cli_main(["grid", "sign", str(grid), "--key", str(private)]) == 0
    m = _members(grid)
    header = m["header"].tobytes()
    sha = m["sha256"].tobytes().decode()
    # the SHA-256 as docs/formats.md §7 defines it, recomputed here
    digest = hashlib.sha256()
    for name in sorted(n for n in m if n not in ("header", "sha256", "signature")):
        arr = np.ascontiguousarray(m[name])
        digest.update(name.encode() + arr.dtype.str.encode() + repr(arr.shape).encode())
        digest.update(arr.tobytes())
    digest.update(header)
    assert digest.hexdigest() == sha
    sig = json.loads(m["signature"].tobytes())
    assert sig["algorithm"] == "Ed25519"
    key = load_pem_public_key(public.read_bytes())
    assert isinstance(key, Ed25519PublicKey)
    message = b"cmm-comp grid signature v1\n" + sha.encode() + b"\n" + header
    key.verify(bytes.fromhex(sig["signature"]), message)  # raises InvalidSignature if wrong
    # the payload and header are unchanged by signing: same SHA-256 as the unsigned file
    assert read_grid_contents(grid).sha256 == CorrectionGrid.load(tmp_path / "g.grid").sha256
    loaded = load_grid(grid, GridTrust(public_key=str(public), machine=str(NPL)))
    assert loaded.signed_by == sig["key_id"]
    # keygen never overwrites a key
    assert cli_main(["grid", "keygen", "--out", str(tmp_path / "k")]) == 2


def _tamper_volume(path: Path, upper_x_mm: float) -> None:
    """An attacker's edit: header volume changed, SHA-256 recomputed, old signature kept."""
    c = read_grid_contents(path)
    header = dict(c.header)
    header["volume"] = {
        **header["volume"],
        "upper_mm": [upper_x_mm, *header["volume"]["upper_mm"][1:]],
    }
    header_bytes = json.dumps(header, sort_keys=True, indent=1).encode()
    digest = hashlib.sha256()
    for name in sorted(c.arrays):
        arr = c.arrays[name]
        digest.update(name.encode() + arr.dtype.str.encode() + repr(arr.shape).encode())
        digest.update(arr.tobytes())
    digest.update(header_bytes)
    write_grid_members(path, header_bytes, c.arrays, digest.hexdigest(), c.signature)


def test_tampered_header_with_recomputed_hash_is_refused(tmp_path: Path, keys, unsigned) -> None:
    grid = tmp_path / "g.grid"
    grid.write_bytes(unsigned)
    sign_grid(grid, keys["ours"][0])
    _tamper_volume(grid, 9000.0)
    # the attack works on an unchecked loader: x = 1500 mm (outside the real 900 mm) is "ok"
    plain = CorrectionGrid.load(grid)
    ref = {g.name: g.reference for g in plain.signals if g.needed}
    temps = {k: v for k, v in ref.items() if k.startswith("T_")}
    inputs = {k: v for k, v in ref.items() if not k.startswith("T_")}
    _, status = plain.correct(np.array([[1500.0, 575.0, 200.0]]), (0, 0, 0), temps, inputs)
    assert status[0] == "ok"
    with pytest.raises(GridLoadError, match="signature does not verify") as info:
        load_grid(grid, _trust(keys))
    assert "\n" not in str(info.value)
    # unsigned grids allowed and the signature stripped: the machine's volume still refuses it
    c = read_grid_contents(grid)
    write_grid_members(grid, c.header_bytes, c.arrays, c.sha256, None)
    with pytest.raises(GridLoadError, match=r"exceeds the machine's .*900"):
        load_grid(grid, GridTrust(allow_unsigned=True, machine=str(NPL)))


def test_foreign_machine_refused(tmp_path: Path, keys) -> None:
    from cmm_comp.compensation import Machine

    grid = tmp_path / "gec.grid"
    CorrectionGrid.build(Machine.from_toml(GEC), steps=(5, 5, 4)).save(grid)
    sign_grid(grid, keys["ours"][0])  # signed by us, but for another machine
    with pytest.raises(GridLoadError, match=r"built for machine .*not for .*npl-bridge"):
        load_grid(grid, _trust(keys))
    other_sha = npl_machine().identity_sha256()
    with pytest.raises(GridLoadError, match="built for machine"):
        load_grid(grid, _trust(keys, machine="", expect_machine_sha256=other_sha))
    # no binding at all is refused too, unless explicitly allowed
    with pytest.raises(GridLoadError, match="no machine bound"):
        load_grid(grid, _trust(keys, machine=""))
    assert load_grid(grid, _trust(keys, machine="", allow_any_machine=True)).machine


def test_signature_of_another_key_refused(tmp_path: Path, keys, unsigned) -> None:
    grid = tmp_path / "g.grid"
    grid.write_bytes(unsigned)
    sign_grid(grid, keys["theirs"][0])
    with pytest.raises(GridLoadError, match=r"signed by key [0-9a-f]{16}, not by the configured"):
        load_grid(grid, _trust(keys))
    # a bad signature is refused even where unsigned grids are allowed
    with pytest.raises(GridLoadError, match="signed by key"):
        load_grid(grid, _trust(keys, allow_unsigned=True))
    sign_grid(grid, keys["ours"][0])  # re-signing replaces the signature
    assert load_grid(grid, _trust(keys)).signed_by


def test_unsigned_refused_unless_allowed(tmp_path: Path, keys, unsigned) -> None:
    grid = tmp_path / "g.grid"
    grid.write_bytes(unsigned)
    with pytest.raises(GridLoadError, match="grid is not signed"):
        load_grid(grid, _trust(keys))
    with pytest.raises(GridLoadError, match=r"grid\.public_key is not set"):
        load_grid(grid, GridTrust(machine=str(NPL)))
    assert load_grid(grid, _trust(keys, allow_unsigned=True)).signed_by == ""


@pytest.mark.parametrize(
    ("setting", "match"),
    [
        ({"public_key": "missing.pem"}, "public key not found"),
        ({"public_key": str(NPL)}, "not a PEM public key"),
        ({"machine": "missing.toml"}, r"grid\.machine: .*missing\.toml"),
    ],
)
def test_unusable_trust_files_are_one_line(tmp_path: Path, keys, unsigned, setting, match) -> None:
    grid = tmp_path / "g.grid"
    grid.write_bytes(unsigned)
    sign_grid(grid, keys["ours"][0])
    with pytest.raises(GridLoadError, match=match) as info:
        load_grid(grid, _trust(keys, **setting))
    assert "\n" not in str(info.value)


def test_deeply_nested_machine_toml_is_one_line(tmp_path: Path, keys, unsigned) -> None:
    machine = tmp_path / "m.toml"
    machine.write_text("a = " + "[" * 3000 + "]" * 3000 + "\n")
    grid = tmp_path / "g.grid"
    grid.write_bytes(unsigned)
    with pytest.raises(GridLoadError, match="nested too deeply"):
        load_grid(grid, _trust(keys, machine=str(machine)))


def test_daemon_check_refuses_unsigned_grid_in_one_line(tmp_path: Path, keys, unsigned) -> None:
    grid = tmp_path / "g.grid"
    grid.write_bytes(unsigned)
    args = [
        sys.executable, "-m", "cmm_comp.cli", "daemon", "--check",
        "--grid-path", str(grid), "--grid-machine", str(NPL),
        "--grid-public-key", str(keys["ours"][1]),
        "--can-interface", "virtual", "--metrics-port", "0",  # --check opens the bus, binds the port
    ]  # fmt: skip
    proc = subprocess.run(args, capture_output=True, text=True, timeout=120)
    assert proc.returncode == 2 and "Traceback" not in proc.stderr
    assert proc.stderr.count("\n") == 1 and "grid is not signed" in proc.stderr
    sign_grid(grid, keys["ours"][0])
    proc = subprocess.run(args, capture_output=True, text=True, timeout=120)
    assert proc.returncode == 0 and "signed by key" in proc.stdout, proc.stderr
