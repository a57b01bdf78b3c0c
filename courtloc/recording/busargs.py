"""Command-line options shared by the pit tools that join a robot's bus as a client.

`--config` names the deployment file (robot id, zenoh endpoints); `--robot` and `--connect` override
it. A pit tool is always a zenoh client: it never listens, so it cannot become part of the robot's
routing by accident.
"""
from __future__ import annotations

import argparse
from pathlib import Path
from typing import TYPE_CHECKING

from courtloc.cliargs import positive_float
from courtloc.common.security import with_identity
from courtloc.common.services_table import check_robot_id
from courtloc.services.deployment import load_deployment

if TYPE_CHECKING:  # the CLI is built for every command: importing the deployment costs ~0.5 s
    from courtloc.services.deployment import DeploymentConfig


def add_client_arguments(parser: argparse.ArgumentParser, robot_help: str = "robot id (default: the config's)",
                         timeout_s: float | None = None) -> None:
    parser.add_argument("--config", type=Path, default=None, help="deployment TOML (default: built-in)")
    parser.add_argument("--robot", default=None, metavar="ID", help=robot_help)
    parser.add_argument("--connect", action="append", default=None, metavar="ENDPOINT",
                        help="router endpoint, e.g. tcp/robot1.local:7447 (repeatable; default: the config's)")
    add_timeout_argument(parser, timeout_s)


def add_timeout_argument(parser: argparse.ArgumentParser, timeout_s: float | None = None) -> None:
    default = "wait until it answers" if timeout_s is None else f"{timeout_s:g} s"
    parser.add_argument("--timeout", type=positive_float, default=timeout_s, metavar="S",
                        help=f"give up when no router answers within S seconds (default: {default})")


def client_deployment(args: argparse.Namespace) -> "DeploymentConfig":
    """The deployment with the command line's overrides; raises ConfigError/ValueError with the field."""

    config = load_deployment(args.config)
    update: dict[str, object] = {}
    if args.robot is not None:
        update["robot_id"] = check_robot_id(args.robot)
    zenoh_update: dict[str, object] = {"mode": "client", "listen": []}
    if args.connect:
        zenoh_update["connect"] = list(args.connect)
    security = config.zenoh.security
    # Credentials are checked now, before the bus: a missing file is named at start, not mid-run.
    zenoh_update["security"] = with_identity(security, security.identity) if security else None
    update["zenoh"] = config.zenoh.model_copy(update=zenoh_update)
    return config.model_copy(update=update)
