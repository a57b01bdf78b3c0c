"""Ed25519 model signatures: the pit signs a model file, the robot verifies it before loading.

The signature covers the SHA-256 of the file, so verifying a 700 MB model streams it once and keeps
memory flat. A signature file is JSON: the digest, the signature and the key's fingerprint (which
key signed, to give a clear error when the robot holds another key).
"""
from __future__ import annotations

import base64
import hashlib
from pathlib import Path

from cryptography.exceptions import InvalidSignature
from cryptography.hazmat.primitives import serialization
from cryptography.hazmat.primitives.asymmetric.ed25519 import Ed25519PrivateKey, Ed25519PublicKey
from pydantic import BaseModel, ConfigDict, ValidationError

SIGNATURE_SUFFIX = ".sig"
_DOMAIN = b"courtloc-model-v1\x00"  # a signature made for something else never verifies a model


class ModelSignatureError(ValueError):
    """The model is not the one the pit signed (or the signature cannot be read)."""


class SignatureFile(BaseModel):
    model_config = ConfigDict(extra="forbid")
    algorithm: str = "ed25519"
    sha256: str
    key_fingerprint: str
    signature: str  # base64


def generate_signing_key() -> Ed25519PrivateKey:
    return Ed25519PrivateKey.generate()


def load_private_key(path: Path) -> Ed25519PrivateKey:
    key = serialization.load_pem_private_key(Path(path).read_bytes(), password=None)
    if not isinstance(key, Ed25519PrivateKey):
        raise ModelSignatureError(f"{path} is not an ed25519 private key")
    return key


def load_public_key(path: Path) -> Ed25519PublicKey:
    try:
        key = serialization.load_pem_public_key(Path(path).read_bytes())
    except (OSError, ValueError) as exc:
        raise ModelSignatureError(f"cannot read model public key {path}: {exc}") from None
    if not isinstance(key, Ed25519PublicKey):
        raise ModelSignatureError(f"{path} is not an ed25519 public key")
    return key


def fingerprint(key: Ed25519PublicKey) -> str:
    raw = key.public_bytes(serialization.Encoding.Raw, serialization.PublicFormat.Raw)
    return hashlib.sha256(raw).hexdigest()[:16]


def file_sha256(path: Path) -> str:
    digest = hashlib.sha256()
    with Path(path).open("rb") as handle:
        for block in iter(lambda: handle.read(1 << 20), b""):
            digest.update(block)
    return digest.hexdigest()


def signature_path(model_path: Path) -> Path:
    return model_path.with_name(model_path.name + SIGNATURE_SUFFIX)


def sign_digest(sha256_hex: str, private_key: Ed25519PrivateKey) -> SignatureFile:
    signature = private_key.sign(_DOMAIN + bytes.fromhex(sha256_hex))
    return SignatureFile(sha256=sha256_hex, key_fingerprint=fingerprint(private_key.public_key()),
                         signature=base64.b64encode(signature).decode("ascii"))


def sign_model(path: Path, private_key: Ed25519PrivateKey | Path, out: Path | None = None) -> Path:
    """Write `<model>.sig` (or `out`) for the model file; returns the signature file's path."""
    key = load_private_key(private_key) if isinstance(private_key, Path) else private_key
    sig = sign_digest(file_sha256(path), key)
    target = out or signature_path(Path(path))
    target.write_text(sig.model_dump_json(indent=2) + "\n", encoding="utf-8")
    return target


def read_signature(signature: Path | bytes | str) -> SignatureFile:
    """`signature` is a .sig file's path, or its content (str/bytes) as received over the bus."""
    try:
        text = signature.read_text(encoding="utf-8") if isinstance(signature, Path) else signature
    except (OSError, UnicodeDecodeError) as exc:
        raise ModelSignatureError(f"cannot read model signature {signature}: {exc}") from None
    try:
        return SignatureFile.model_validate_json(text)
    except ValidationError as exc:
        raise ModelSignatureError(f"unreadable model signature: {exc.errors()[0]['msg']}") from None


def verify_digest(sha256_hex: str, signature: SignatureFile, public_key: Ed25519PublicKey) -> None:
    if signature.algorithm != "ed25519":
        raise ModelSignatureError(f"unsupported signature algorithm {signature.algorithm!r}")
    if signature.key_fingerprint != fingerprint(public_key):
        raise ModelSignatureError(f"signed by key {signature.key_fingerprint}, this robot trusts "
                                  f"{fingerprint(public_key)}")
    if signature.sha256 != sha256_hex:
        raise ModelSignatureError("model content does not match its signature (tampered or truncated)")
    try:
        public_key.verify(base64.b64decode(signature.signature, validate=True), _DOMAIN + bytes.fromhex(sha256_hex))
    except (InvalidSignature, ValueError):
        raise ModelSignatureError("bad signature for this model") from None


def verify_model(path: Path, signature: Path | bytes | str, public_key: Ed25519PublicKey | Path) -> str:
    """Raise ModelSignatureError unless `path` is exactly what the holder of the private key signed.

    Returns the model's SHA-256 (the store can use it as the model's id).
    """
    key = load_public_key(public_key) if isinstance(public_key, Path) else public_key
    digest = file_sha256(path)
    verify_digest(digest, read_signature(signature), key)
    return digest
