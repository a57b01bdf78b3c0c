"""Model signatures (ed25519 over the file's SHA-256) and `courtloc secure init/sign/verify`."""
from __future__ import annotations

from pathlib import Path

import pytest

from courtloc.common.security import BundleLayout
from courtloc.common.signing import (
    ModelSignatureError,
    generate_signing_key,
    sign_model,
    signature_path,
    verify_model,
)


@pytest.fixture()
def model(tmp_path: Path) -> Path:
    path = tmp_path / "pose.onnx"
    path.write_bytes(bytes(range(256)) * 1000)
    return path


def test_signed_model_verifies_and_returns_its_digest(model: Path) -> None:
    key = generate_signing_key()
    sig = sign_model(model, key)
    assert sig == signature_path(model) and sig.is_file()
    import hashlib
    assert verify_model(model, sig, key.public_key()) == hashlib.sha256(model.read_bytes()).hexdigest()


@pytest.mark.parametrize("tamper", ["flip_byte", "truncate", "append"])
def test_tampered_model_is_refused(model: Path, tamper: str) -> None:
    key = generate_signing_key()
    sig = sign_model(model, key)
    data = bytearray(model.read_bytes())
    if tamper == "flip_byte":
        data[len(data) // 2] ^= 0x01
    elif tamper == "truncate":
        data = data[:-1]
    else:
        data += b"\x00"
    model.write_bytes(bytes(data))
    with pytest.raises(ModelSignatureError, match="does not match"):
        verify_model(model, sig, key.public_key())


def test_signature_of_another_key_is_refused(model: Path) -> None:
    sig = sign_model(model, generate_signing_key())
    with pytest.raises(ModelSignatureError, match="signed by key"):
        verify_model(model, sig, generate_signing_key().public_key())


def test_forged_signature_with_matching_digest_is_refused(model: Path) -> None:
    """Someone edits the digest and fingerprint in the .sig to match: the ed25519 check still fails."""
    key = generate_signing_key()
    sig = sign_model(model, key)
    other = model.with_name("other.onnx")
    other.write_bytes(b"evil weights")
    import hashlib
    import json
    doc = json.loads(sig.read_text())
    doc["sha256"] = hashlib.sha256(other.read_bytes()).hexdigest()
    sig.write_text(json.dumps(doc))
    with pytest.raises(ModelSignatureError, match="bad signature"):
        verify_model(other, sig, key.public_key())


@pytest.mark.parametrize("content", ["", "{}", "not json", '{"sha256": "00", "key_fingerprint": "x"}'])
def test_unreadable_signature_is_refused(model: Path, content: str) -> None:
    bad = model.with_name("bad.sig")
    bad.write_text(content)
    with pytest.raises(ModelSignatureError):
        verify_model(model, bad, generate_signing_key().public_key())


def _courtloc(capsys: pytest.CaptureFixture, *args: str) -> tuple[int, str, str]:
    """The real command line, parsed and run in this process (exit code, stdout, stderr)."""
    from courtloc.cli import main

    with pytest.raises(SystemExit) as exit_info:  # main's handler: a mistake is one line and an exit code
        main(list(args))
    out = capsys.readouterr()
    return int(exit_info.value.code or 0), out.out, out.err


def test_cli_init_sign_verify_roundtrip(tmp_path: Path, model: Path, capsys: pytest.CaptureFixture) -> None:
    out = tmp_path / "secrets"
    code, _, err = _courtloc(capsys, "secure", "init", "--out", str(out), "--robot", "r2", "--hostname", "r2.arena",
                             "--pit-stages", "infer")
    assert code == 0, err
    robot, pit = BundleLayout(out / "robot"), BundleLayout(out / "pit")
    assert robot.model_public_key.is_file() and not robot.model_private_key.exists(), "the robot cannot sign"
    assert pit.model_private_key.is_file() and pit.model_private_key.stat().st_mode & 0o077 == 0
    assert pit.certificate("pit").is_file() and not robot.certificate("pit").exists()
    assert pit.certificate("infer").is_file(), "--pit-stages puts the offloaded stage's identity on the laptop"
    password = robot.password_file("camera").read_text().strip()
    assert f"r2-camera:{password}" in robot.users_dictionary.read_text().splitlines()
    code, _, err = _courtloc(capsys, "secure", "init", "--out", str(out))
    assert code == 2 and "not empty" in err, "existing keys are never overwritten"

    assert _courtloc(capsys, "secure", "sign", str(model), "--key", str(pit.model_private_key))[0] == 0
    code, stdout, _ = _courtloc(capsys, "secure", "verify", str(model), "--key", str(robot.model_public_key))
    assert code == 0 and "OK" in stdout
    model.write_bytes(model.read_bytes() + b"x")
    code, _, err = _courtloc(capsys, "secure", "verify", str(model), "--key", str(robot.model_public_key))
    assert code == 1 and "REFUSED" in err


def test_router_certificate_names_the_robot_host(tmp_path: Path) -> None:
    from cryptography import x509

    from courtloc.security.bundle import init_bundles

    bundles = init_bundles(tmp_path / "s", "robot1", ["jetson.arena", "10.0.0.7"], "team")
    cert = x509.load_pem_x509_certificate(bundles.robot.router_certificate.read_bytes())
    names = cert.extensions.get_extension_for_class(x509.SubjectAlternativeName).value
    assert {"jetson.arena", "localhost"} <= set(names.get_values_for_type(x509.DNSName))
    assert {str(a) for a in names.get_values_for_type(x509.IPAddress)} >= {"10.0.0.7", "127.0.0.1"}


def test_missing_signature_file_is_refused(model: Path) -> None:
    with pytest.raises(ModelSignatureError, match="cannot read"):
        verify_model(model, signature_path(model), generate_signing_key().public_key())
