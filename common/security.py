"""Where a process finds its credentials: the bundle layout `courtloc secure init` writes.

A bundle is a folder copied to one machine: `robot/` for the Jetson (router certificate, the user
dictionary, one identity per stage, the model-verifying public key) and `pit/` for the laptop (the
pit identity and the model-signing private key). Both hold the team's CA certificate.

On the robot the bundle stays root-only on disk; systemd hands each unit only its own identity
(`LoadCredential=` in deploy/systemd) in a private folder named by `$CREDENTIALS_DIRECTORY`. When that
variable is set, a process reads its credentials from there (one identity, flat) and nothing else.

This module only knows paths and how they become zenoh settings; making keys is
`courtloc.security`'s job (it needs the `cryptography` library, which a stage does not load).
"""
from __future__ import annotations

import os
import re
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from pydantic import BaseModel, ConfigDict, Field, field_validator

from courtloc.common.services_table import PIT

IDENTITY_PATTERN = re.compile(r"^[a-z][a-z0-9_]{0,31}$")
MONITOR_IDENTITY = "monitor"  # read-only watcher on the robot (the launcher's status line)
PIT_IDENTITY = PIT  # the team's laptop: reads everything, the only caller of model control


class SecurityConfig(BaseModel):
    """`[zenoh.security]`: this process authenticates with mTLS and a password from `dir`."""

    model_config = ConfigDict(extra="forbid")

    dir: Path = Field(description="a bundle folder written by `courtloc secure init` (robot/ or pit/)")
    identity: str = Field(default=MONITOR_IDENTITY,
                          description="whose certificate to present; a stage always uses its own name")

    @field_validator("identity")
    @classmethod
    def _identity_is_a_name(cls, value: str) -> str:
        if not IDENTITY_PATTERN.match(value):
            raise ValueError(f"identity {value!r} must match {IDENTITY_PATTERN.pattern}")
        return value


@dataclass(frozen=True)
class BundleLayout:
    root: Path

    @property
    def ca_certificate(self) -> Path:
        return self.root / "ca.pem"

    def identity_dir(self, identity: str) -> Path:
        return self.root / "identities" / identity

    def certificate(self, identity: str) -> Path:
        return self.identity_dir(identity) / "cert.pem"

    def private_key(self, identity: str) -> Path:
        return self.identity_dir(identity) / "key.pem"

    def user_file(self, identity: str) -> Path:
        return self.identity_dir(identity) / "user"

    def password_file(self, identity: str) -> Path:
        return self.identity_dir(identity) / "password"

    @property
    def router_certificate(self) -> Path:
        return self.root / "router" / "cert.pem"

    @property
    def router_private_key(self) -> Path:
        return self.root / "router" / "key.pem"

    @property
    def users_dictionary(self) -> Path:
        return self.root / "router" / "users.txt"

    @property
    def model_public_key(self) -> Path:
        return self.root / "model_signing.pub"

    @property
    def model_private_key(self) -> Path:
        return self.root / "model_signing.key"


SYSTEMD_CREDENTIALS_ENV = "CREDENTIALS_DIRECTORY"
# The flat names of one process's credentials in $CREDENTIALS_DIRECTORY (deploy/systemd loads exactly these).
CLIENT_CREDENTIALS = ("ca.pem", "cert.pem", "key.pem", "user", "password")
ROUTER_CREDENTIALS = ("ca.pem", "cert.pem", "key.pem", "users.txt")


def systemd_credentials() -> Path | None:
    """The folder systemd loaded this unit's own credentials into, when it did."""
    folder = os.environ.get(SYSTEMD_CREDENTIALS_ENV)
    return Path(folder) if folder else None


def principal(robot_id: str, identity: str) -> str:
    """The certificate common name and the user name of `identity` on `robot_id`'s bus."""
    return f"{robot_id}-{identity}"


class MissingCredential(ValueError):
    """A credential file is absent: the process stops before touching the bus."""


def _existing(path: Path) -> str:
    if not path.is_file():
        raise MissingCredential(f"credential file {path} not found (run `courtloc secure init`?)")
    return str(path)


def _read(path: Path) -> str:
    return Path(_existing(path)).read_text(encoding="utf-8").strip()


def with_identity(security: SecurityConfig | None, identity: str) -> SecurityConfig | None:
    """`security` presenting `identity` instead; raises MissingCredential when the bundle lacks it."""
    if security is None:
        return None
    chosen = security.model_copy(update={"identity": identity})
    client_settings(chosen)
    return chosen


def client_settings(security: SecurityConfig) -> dict[str, Any]:
    """Zenoh config entries (path -> value) for a client presenting `security.identity`."""
    own = systemd_credentials()
    if own is not None:  # this unit's identity only, whatever the bundle folder says
        ca, cert, key, user, password = (own / name for name in CLIENT_CREDENTIALS)
    else:
        bundle = BundleLayout(security.dir)
        name = security.identity
        ca, cert, key = bundle.ca_certificate, bundle.certificate(name), bundle.private_key(name)
        user, password = bundle.user_file(name), bundle.password_file(name)
    return {
        "transport/link/tls/root_ca_certificate": _existing(ca),
        "transport/link/tls/connect_certificate": _existing(cert),
        "transport/link/tls/connect_private_key": _existing(key),
        "transport/link/tls/enable_mtls": True,
        "transport/auth/usrpwd/user": _read(user),
        "transport/auth/usrpwd/password": _read(password),
    }


def router_settings(bundle_dir: Path) -> dict[str, Any]:
    """Zenoh config entries for the robot's router: TLS only, client certificates and passwords required."""
    own = systemd_credentials()
    if own is not None:  # the router unit's own credentials only
        ca, cert, key, users = (own / name for name in ROUTER_CREDENTIALS)
    else:
        bundle = BundleLayout(bundle_dir)
        ca, cert, key = bundle.ca_certificate, bundle.router_certificate, bundle.router_private_key
        users = bundle.users_dictionary
    return {
        "transport/link/protocols": ["tls"],
        "transport/link/tls/root_ca_certificate": _existing(ca),
        "transport/link/tls/listen_certificate": _existing(cert),
        "transport/link/tls/listen_private_key": _existing(key),
        "transport/link/tls/enable_mtls": True,
        "transport/auth/usrpwd/dictionary_file": _existing(users),
    }
