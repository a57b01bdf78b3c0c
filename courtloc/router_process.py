"""`python -m courtloc.router_process --settings JSON`: the Zenoh router as a process of its own.

`courtloc router` validates the deployment and then becomes this process (as `courtloc run` becomes a
stage's): the router holds zenoh and the access rules, not the CLI with every stage's libraries, which
cost ~80 MB of robot memory (PSS 106 MB through the full CLI).
"""
from __future__ import annotations

import argparse
import json
import logging
import sys
from pathlib import Path
from typing import Optional

import zenoh
from pydantic import BaseModel, ConfigDict, field_validator

from courtloc.cli_errors import RUN_EXIT
from courtloc.common.bus import ZenohConfig, build_zenoh_config, check_zenoh_id
from courtloc.common.exposure import insecure_exposure, warn_while_insecure
from courtloc.common.security import router_settings
from courtloc.common.signals import stop_on_signals
from courtloc.security.acl import access_control

log = logging.getLogger("courtloc.router")
READY_LINE = "router listening on"
ROUTER_MODULE = "courtloc.router_process"


class RouterSettings(BaseModel):
    """What the router needs of a validated deployment (the CLI builds it; nothing here re-validates it)."""

    model_config = ConfigDict(extra="forbid")
    robot_id: str
    listen: list[str]
    connect: list[str] = []
    secure_dir: Optional[Path] = None
    zenoh_config_file: Optional[Path] = None
    shared_memory: bool = True
    # `courtloc up` gives its router a fresh id per run and tells its stages; a stage connected to a router
    # with another id (another pipeline's, on the port after ours died) leaves (runtime.Service).
    zenoh_id: Optional[str] = None

    @field_validator("zenoh_id")
    @classmethod
    def _valid_zenoh_id(cls, value: Optional[str]) -> Optional[str]:
        return None if value is None else check_zenoh_id(value)


def router_argv(settings: RouterSettings, verbose: int = 0) -> list[str]:
    return [sys.executable, "-m", ROUTER_MODULE, *(["-v"] * verbose),
            "--settings", settings.model_dump_json()]


def open_router(settings: RouterSettings) -> zenoh.Session:
    """The router's session; ValueError (one line) when it cannot listen."""
    zcfg = build_zenoh_config(ZenohConfig(mode="router", connect=settings.connect, listen=settings.listen,
                                          config_file=settings.zenoh_config_file,
                                          shared_memory=settings.shared_memory))
    if settings.zenoh_id is not None:
        zcfg.insert_json5("id", json.dumps(settings.zenoh_id))
    if settings.secure_dir is not None:
        for path, value in {**router_settings(settings.secure_dir),
                            "access_control": access_control(settings.robot_id)}.items():
            zcfg.insert_json5(path, json.dumps(value))
    try:
        return zenoh.open(zcfg)
    except zenoh.ZError as exc:
        reason = " ".join(str(exc).split(" at ")[0].split())
        raise ValueError(f"cannot listen on {', '.join(settings.listen)}: {reason}") from None


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m courtloc.router_process")
    parser.add_argument("-v", "--verbose", action="count", default=0)
    parser.add_argument("--settings", required=True, help="RouterSettings as JSON (courtloc router writes it)")
    args = parser.parse_args(argv)
    logging.basicConfig(level=logging.WARNING - 10 * min(args.verbose, 2),
                        format="%(asctime)s %(levelname)s %(name)s: %(message)s")
    stop = stop_on_signals()
    try:
        settings = RouterSettings.model_validate_json(args.settings)
        session = open_router(settings)
    except ValueError as exc:  # a bad endpoint, a port in use, a missing credential file
        print(f"router: {' '.join(str(exc).split())}", file=sys.stderr)  # one line, a pydantic error too
        return RUN_EXIT
    log.info("router listening on %s", ", ".join(settings.listen))
    print(f"{READY_LINE} {', '.join(settings.listen)}", flush=True)
    warn_while_insecure(insecure_exposure(settings.listen, settings.secure_dir is not None), stop, log)
    try:
        while not stop.wait(0.5):  # a timed wait: the signal handler runs between two
            pass
    finally:
        session.close()
    return 0


if __name__ == "__main__":
    sys.exit(main())
