"""Ed25519 signatures of grid files: who built this grid, and was it changed since.

The SHA-256 of a grid file proves only integrity: anyone who edits the header can recompute it.
A signature made with a private key kept by the people who build grids proves origin. It is
stored inside the grid file as the ``signature`` member (UTF-8 JSON, :mod:`.file`)::

    {"algorithm": "Ed25519", "key_id": "<16 hex>", "signature": "<128 hex>"}

and covers :func:`signed_message` = ``SIGNATURE_CONTEXT + sha256 (hex, ASCII) + "\\n" + header
bytes``: the content hash (every payload array and the header) and, explicitly, the header
(machine sha256, volume, steps, signals …). ``key_id`` is the first 16 hex digits of the SHA-256
of the raw 32-byte public key; it names the key in messages, it proves nothing.

Keys are PEM files (PKCS#8 private key without passphrase, mode 0600; SubjectPublicKeyInfo
public key), made by :func:`generate_signing_key` (``cmm-comp grid keygen``). The
``cryptography`` package is imported on use.
"""

from __future__ import annotations

import hashlib
import json
import os
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any

from ..errors import GridSignatureError
from .file import GridContents, read_grid_contents, write_grid_members

if TYPE_CHECKING:
    from cryptography.hazmat.primitives.asymmetric.ed25519 import (
        Ed25519PrivateKey,
        Ed25519PublicKey,
    )

__all__ = [
    "PRIVATE_KEY_NAME",
    "PUBLIC_KEY_NAME",
    "SIGNATURE_ALGORITHM",
    "SIGNATURE_CONTEXT",
    "GridSignatureError",
    "SignatureInfo",
    "generate_signing_key",
    "key_id",
    "load_private_key",
    "load_public_key",
    "sign_grid",
    "signature_info",
    "signed_message",
    "verify_signature",
]

SIGNATURE_ALGORITHM = "Ed25519"
SIGNATURE_CONTEXT = b"cmm-comp grid signature v1\n"
"""Domain separation: a signature over a grid can never be mistaken for one over anything else."""
PRIVATE_KEY_NAME = "grid-signing-key.pem"
PUBLIC_KEY_NAME = "grid-signing-key.pub.pem"


@dataclass(frozen=True)
class SignatureInfo:
    """The parsed ``signature`` member of a grid file."""

    algorithm: str
    key_id: str
    signature: bytes


def signed_message(sha256_hex: str, header_bytes: bytes) -> bytes:
    """The bytes a grid signature covers: context, content SHA-256 (hex), newline, header."""
    return SIGNATURE_CONTEXT + sha256_hex.encode("ascii") + b"\n" + header_bytes


def _raw_public(public: Ed25519PublicKey) -> bytes:
    from cryptography.hazmat.primitives import serialization

    return public.public_bytes(serialization.Encoding.Raw, serialization.PublicFormat.Raw)


def key_id(public: Ed25519PublicKey) -> str:
    """First 16 hex digits of the SHA-256 of the raw public key (a name, not a proof)."""
    return hashlib.sha256(_raw_public(public)).hexdigest()[:16]


def generate_signing_key(directory: str | Path) -> tuple[Path, Path]:
    """Write a new key pair into ``directory``: ``(private, public)`` PEM paths.

    Never overwrites: GridSignatureError if either file exists. The private key is created
    with mode 0600.
    """
    from cryptography.hazmat.primitives import serialization
    from cryptography.hazmat.primitives.asymmetric.ed25519 import Ed25519PrivateKey

    folder = Path(directory)
    private_path, public_path = folder / PRIVATE_KEY_NAME, folder / PUBLIC_KEY_NAME
    for path in (private_path, public_path):
        if path.exists():
            raise GridSignatureError(f"{path}: already exists; not overwriting a key")
    folder.mkdir(parents=True, exist_ok=True)
    key = Ed25519PrivateKey.generate()
    private_pem = key.private_bytes(
        serialization.Encoding.PEM,
        serialization.PrivateFormat.PKCS8,
        serialization.NoEncryption(),
    )
    public_pem = key.public_key().public_bytes(
        serialization.Encoding.PEM, serialization.PublicFormat.SubjectPublicKeyInfo
    )
    fd = os.open(private_path, os.O_WRONLY | os.O_CREAT | os.O_EXCL, 0o600)
    with os.fdopen(fd, "wb") as fh:
        fh.write(private_pem)
    public_path.write_bytes(public_pem)
    return private_path, public_path


def _read_key_bytes(path: str | Path, what: str) -> bytes:
    try:
        return Path(path).read_bytes()
    except FileNotFoundError:
        raise GridSignatureError(f"{path}: {what} not found") from None
    except OSError as exc:
        raise GridSignatureError(f"{path}: cannot read the {what} ({exc.strerror})") from None


def load_private_key(path: str | Path) -> Ed25519PrivateKey:
    """An Ed25519 private key from a PEM file; GridSignatureError naming the file."""
    from cryptography.hazmat.primitives import serialization
    from cryptography.hazmat.primitives.asymmetric.ed25519 import Ed25519PrivateKey

    data = _read_key_bytes(path, "private key")
    try:
        key = serialization.load_pem_private_key(data, password=None)
    except (ValueError, TypeError) as exc:
        raise GridSignatureError(
            f"{path}: not a PEM private key without passphrase ({exc})"
        ) from None
    if not isinstance(key, Ed25519PrivateKey):
        raise GridSignatureError(f"{path}: not an Ed25519 private key ({type(key).__name__})")
    return key


def load_public_key(path: str | Path) -> Ed25519PublicKey:
    """An Ed25519 public key from a PEM file; GridSignatureError naming the file."""
    from cryptography.hazmat.primitives import serialization
    from cryptography.hazmat.primitives.asymmetric.ed25519 import Ed25519PublicKey

    data = _read_key_bytes(path, "public key")
    try:
        key = serialization.load_pem_public_key(data)
    except (ValueError, TypeError) as exc:
        raise GridSignatureError(f"{path}: not a PEM public key ({exc})") from None
    if not isinstance(key, Ed25519PublicKey):
        raise GridSignatureError(f"{path}: not an Ed25519 public key ({type(key).__name__})")
    return key


def signature_info(contents: GridContents) -> SignatureInfo | None:
    """The grid's signature member parsed (None: unsigned); GridSignatureError if malformed."""
    if contents.signature is None:
        return None
    where = contents.source
    try:
        data: Any = json.loads(contents.signature.decode())
        info = SignatureInfo(
            str(data["algorithm"]), str(data["key_id"]), bytes.fromhex(data["signature"])
        )
    except (UnicodeDecodeError, ValueError, KeyError, TypeError, RecursionError):
        raise GridSignatureError(f"{where}: malformed signature member") from None
    if info.algorithm != SIGNATURE_ALGORITHM:
        raise GridSignatureError(
            f"{where}: signature algorithm {info.algorithm!r}; only {SIGNATURE_ALGORITHM}"
        )
    return info


def sign_grid(path: str | Path, private_key: str | Path | Ed25519PrivateKey) -> str:
    """Sign the grid file at ``path`` in place (atomic rewrite); return the key id.

    The file is checked first (format, SHA-256); an existing signature is replaced. Payload,
    header and SHA-256 are rewritten byte-identical.
    """
    key = private_key if not isinstance(private_key, str | Path) else load_private_key(private_key)
    contents = read_grid_contents(path)
    kid = key_id(key.public_key())
    signature = key.sign(signed_message(contents.sha256, contents.header_bytes))
    member = json.dumps(
        {"algorithm": SIGNATURE_ALGORITHM, "key_id": kid, "signature": signature.hex()},
        sort_keys=True,
    ).encode()
    write_grid_members(path, contents.header_bytes, contents.arrays, contents.sha256, member)
    return kid


def verify_signature(contents: GridContents, public_key: Ed25519PublicKey) -> str:
    """Check the grid's signature against ``public_key``; return the key id.

    GridSignatureError (one line naming the file) when unsigned, signed by another key, or the
    signature does not match the SHA-256 and header (edited after signing).
    """
    from cryptography.exceptions import InvalidSignature

    where = contents.source
    info = signature_info(contents)
    want = key_id(public_key)
    if info is None:
        raise GridSignatureError(
            f"{where}: grid is not signed (sign it with `cmm-comp grid sign`, or set "
            "grid.allow_unsigned = true)"
        )
    try:
        public_key.verify(info.signature, signed_message(contents.sha256, contents.header_bytes))
    except InvalidSignature:
        if info.key_id != want:
            raise GridSignatureError(
                f"{where}: grid signed by key {info.key_id}, not by the configured key {want}"
            ) from None
        raise GridSignatureError(
            f"{where}: signature does not verify with key {want}: the grid (header or "
            "payload) was changed after signing"
        ) from None
    return want
