"""Where a process finds its credentials: the bundle layout `courtloc secure init` writes.

A bundle is a folder copied to one machine: `robot/` for the Jetson (router certificate, the user
dictionary, one identity per stage, the model-verifying public key) and `pit/` for the laptop (the
pit identity and the model-signing private key). Both hold the team's CA certificate.

This module only knows paths and how they become zenoh settings; making keys is
`courtloc.security`'s job (it needs the `cryptography` library, which a stage does not load).
"""
from __future__ import annotations

import re
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from courtloc.common.services_table import PIT
from pydantic import BaseModel, ConfigDict, Field, field_validator

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
    bundle = BundleLayout(security.dir)
    name = security.identity
    return {
        "transport/link/tls/root_ca_certificate": _existing(bundle.ca_certificate),
        "transport/link/tls/connect_certificate": _existing(bundle.certificate(name)),
        "transport/link/tls/connect_private_key": _existing(bundle.private_key(name)),
        "transport/link/tls/enable_mtls": True,
        "transport/auth/usrpwd/user": _read(bundle.user_file(name)),
        "transport/auth/usrpwd/password": _read(bundle.password_file(name)),
    }


def router_settings(bundle_dir: Path) -> dict[str, Any]:
    """Zenoh config entries for the robot's router: TLS only, client certificates and passwords required."""
    bundle = BundleLayout(bundle_dir)
    return {
        "transport/link/protocols": ["tls"],
        "transport/link/tls/root_ca_certificate": _existing(bundle.ca_certificate),
        "transport/link/tls/listen_certificate": _existing(bundle.router_certificate),
        "transport/link/tls/listen_private_key": _existing(bundle.router_private_key),
        "transport/link/tls/enable_mtls": True,
        "transport/auth/usrpwd/dictionary_file": _existing(bundle.users_dictionary),
    }
