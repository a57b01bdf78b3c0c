"""Command-line options shared by the pit tools that join a robot's bus as a client.

`--config` names the deployment file (robot id, zenoh endpoints); `--robot` and `--connect` override
it. A pit tool is always a zenoh client: it never listens, so it cannot become part of the robot's
routing by accident.
"""
from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path
from typing import TYPE_CHECKING

import zenoh

from courtloc.cli_errors import RUN_EXIT, UsageError
from courtloc.cliargs import positive_float
from courtloc.common.bus import build_zenoh_config
from courtloc.common.security import with_identity
from courtloc.common.services_table import check_robot_id
from courtloc.services.deployment import load_deployment

if TYPE_CHECKING:  # the CLI is built for every command: importing the deployment costs ~0.5 s
    from courtloc.common.bus import ZenohConfig
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


def wait_for_router(zenoh_config: "ZenohConfig", timeout_s: float | None) -> None:
    """Return once a session to the configured endpoints opens (then closed again: the command opens its
    own); raise UsageError naming the endpoints when none answers within `timeout_s` (None: wait on).

    While it waits it says once on stderr what it waits for, on a terminal or when it may wait forever
    (a pipe with a timeout gets only the verdict: one line).
    """


    endpoints = ", ".join(zenoh_config.connect) or "any router (scouting)"
    deadline = None if timeout_s is None else time.monotonic() + timeout_s
    delay, said = zenoh_config.open_retry_s, False
    while True:
        try:
            zenoh.open(build_zenoh_config(zenoh_config)).close()
            return
        except zenoh.ZError as exc:
            reason = str(exc).split(" at ")[0]
        left = None if deadline is None else deadline - time.monotonic()
        if left is not None and left <= 0:
            raise UsageError(f"no router answered at {endpoints} within {timeout_s:g} s ({reason}); "
                             "is it running, and is --connect / the config's [zenoh] connect right?", RUN_EXIT)
        if not said and (deadline is None or sys.stderr.isatty()):
            limit = "until it answers (Ctrl-C stops; --timeout S gives up)" if deadline is None else \
                f"up to {timeout_s:g} s"
            print(f"waiting for a router at {endpoints} {limit}", file=sys.stderr, flush=True)
            said = True
        time.sleep(delay if left is None else min(delay, left))
        delay = min(delay * 2, zenoh_config.open_retry_max_s)


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
