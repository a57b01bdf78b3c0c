"""`courtloc secure init`: everything a team needs to lock its robot's bus, in two folders.

    OUT/ca/       the CA key: keep it offline (it is needed only to issue new certificates)
    OUT/robot/    copy to the Jetson: router certificate + user dictionary, one identity per stage,
                  the monitor identity, the model-verifying public key
    OUT/pit/      stays on the laptop: the pit identity, the model-signing private key, and the
                  identities of stages placed on the laptop (`--pit-stages infer` for offload)
"""
from __future__ import annotations

import logging
import secrets
from dataclasses import dataclass
from pathlib import Path

from courtloc.common.security import PIT_IDENTITY, BundleLayout, principal
from courtloc.common.services_table import SERVICES, check_robot_id
from courtloc.common.signing import generate_signing_key
from courtloc.security import pki
from courtloc.security.acl import identities
from courtloc.security.pki import write_signing_keys

log = logging.getLogger(__name__)

LOOPBACK_NAMES = ["localhost", "127.0.0.1", "::1"]


@dataclass(frozen=True)
class Bundles:
    ca_dir: Path
    robot: BundleLayout
    pit: BundleLayout


def _write_identity(ca: pki.Issued, robot_id: str, identity: str, password: str, bundles: list[BundleLayout]) -> None:
    issued = pki.issue(ca, principal(robot_id, identity))
    for bundle in bundles:
        pki.write_certificate(issued.certificate, bundle.certificate(identity))
        pki.write_private_key(issued.key, bundle.private_key(identity))
        bundle.user_file(identity).write_text(principal(robot_id, identity) + "\n", encoding="utf-8")
        pki.write_secret(bundle.password_file(identity), (password + "\n").encode())


def init_bundles(out: Path, robot_id: str, hostnames: list[str], team: str,
                 pit_stages: list[str] | None = None) -> Bundles:
    """Create a fresh CA and every credential; refuses to overwrite an existing bundle."""
    check_robot_id(robot_id)
    pit_stages = pit_stages or []
    unknown = [s for s in pit_stages if s not in SERVICES]
    if unknown:
        raise ValueError(f"unknown stage(s) {unknown}; known: {list(SERVICES)}")
    if out.exists() and any(out.iterdir()):
        raise FileExistsError(f"{out} is not empty; choose a new folder (old keys are never overwritten)")
    bundles = Bundles(out / "ca", BundleLayout(out / "robot"), BundleLayout(out / "pit"))
    ca = pki.make_ca(team)
    pki.write_private_key(ca.key, bundles.ca_dir / "ca.key")
    for path in (bundles.ca_dir / "ca.pem", bundles.robot.ca_certificate, bundles.pit.ca_certificate):
        pki.write_certificate(ca.certificate, path)

    names = list(dict.fromkeys([*hostnames, *LOOPBACK_NAMES]))
    router = pki.issue(ca, principal(robot_id, "router"), server_names=names)
    pki.write_certificate(router.certificate, bundles.robot.router_certificate)
    pki.write_private_key(router.key, bundles.robot.router_private_key)

    users: list[str] = []
    for identity in identities():
        password = secrets.token_urlsafe(24)
        users.append(f"{principal(robot_id, identity)}:{password}")
        where = [bundles.pit] if identity == PIT_IDENTITY else [bundles.robot]
        if identity in pit_stages:
            where.append(bundles.pit)
        _write_identity(ca, robot_id, identity, password, where)
    pki.write_secret(bundles.robot.users_dictionary, ("\n".join(users) + "\n").encode())

    signing = generate_signing_key()
    write_signing_keys(signing, bundles.pit.model_private_key, bundles.pit.model_public_key)
    bundles.robot.model_public_key.write_bytes(bundles.pit.model_public_key.read_bytes())
    log.info("security bundles for %s written to %s", robot_id, out)
    return bundles
