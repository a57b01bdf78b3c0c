"""`courtloc run SERVICE` and `courtloc router`: one stage, or the router, as this process."""
from __future__ import annotations

import argparse
import json
import logging
import os
import sys
from pathlib import Path

import zenoh

from courtloc.cli_errors import RUN_EXIT, UsageError
from courtloc.common.bus import ZenohConfig, build_zenoh_config
from courtloc.common.exposure import insecure_exposure, is_loopback, warn_while_insecure
from courtloc.common.security import router_settings
from courtloc.common.services_table import SERVICES
from courtloc.common.signals import stop_on_signals
from courtloc.recording.busargs import add_timeout_argument
from courtloc.security.acl import access_control
from courtloc.services.deployment import load_deployment

log = logging.getLogger("courtloc.stage")


def register(sub: argparse._SubParsersAction) -> None:
    run = sub.add_parser("run", help="run one stage in this process (placing it on this machine)")
    run.add_argument("service", help="camera | preprocess | infer | shooter_bridge")
    run.add_argument("--config", type=Path, default=None, help="deployment TOML (default: built-in)")
    add_timeout_argument(run)
    run.set_defaults(func=run_stage)

    router = sub.add_parser("router", help="run a Zenoh router in this process")
    add_router_arguments(router)
    router.set_defaults(func=run_router)


def add_router_arguments(router: argparse.ArgumentParser) -> None:
    """The options of `courtloc router` (also of `python -m courtloc.router_main`, the same router)."""
    router.add_argument("--listen", action="append", default=None,
                        help="endpoint to listen on, e.g. tcp/0.0.0.0:7447 (repeatable)")
    router.add_argument("--config", type=Path, default=None, help="deployment TOML: takes [router] listen")


def router_argv(listen: list[str], config: Path | None) -> list[str]:
    """The command line of a router process: `courtloc router` through its own entry point, which loads only
    the router (courtloc.router_main), so a router that died is back sooner."""
    return [sys.executable, "-m", "courtloc.router_main", *[a for ep in listen for a in ("--listen", ep)],
            *(["--config", str(config)] if config is not None else [])]


def stage_argv(name: str, config: Path | None, verbose: int = 0, timeout_s: float | None = None) -> list[str]:
    """The command line of a stage process: its own entry point, which loads only that stage."""
    return [sys.executable, "-m", f"courtloc.services.{name}", *(["-v"] * verbose),
            *(["--config", str(config)] if config is not None else []),
            *(["--timeout", f"{timeout_s:g}"] if timeout_s is not None else [])]


def run_stage(args: argparse.Namespace) -> int:
    if args.service not in SERVICES:
        raise UsageError(f"no stage {args.service!r}; available: {', '.join(SERVICES)}")
    load_deployment(args.config)  # a bad file or field raises, named: one line (the stage reads it again)
    logging.shutdown()
    sys.stdout.flush()
    sys.stderr.flush()
    # This process becomes the stage's own (a stage process never loads the CLI, the lab or other stages).
    os.execv(sys.executable, stage_argv(args.service, args.config, args.verbose, args.timeout))


def run_router(args: argparse.Namespace) -> int:
    config = load_deployment(args.config)
    listen = args.listen or config.router.listen
    exposed = [ep for ep in listen if not is_loopback(ep)]
    if exposed and config.router.secure_dir is None and not config.insecure:
        print(f"router: --listen {', '.join(exposed)} is reachable beyond this machine: set [router] secure_dir "
              "(courtloc secure init) or insecure = true in the deployment file", file=sys.stderr)
        return 2
    router_cfg = ZenohConfig(mode="router", connect=config.router.connect, listen=listen,
                             config_file=config.zenoh.config_file, shared_memory=config.zenoh.shared_memory)
    stop = stop_on_signals()
    try:
        zcfg = build_zenoh_config(router_cfg)
        if config.router.secure_dir is not None:
            for path, value in {**router_settings(config.router.secure_dir),
                                "access_control": access_control(config.robot_id)}.items():
                zcfg.insert_json5(path, json.dumps(value))
        session = zenoh.open(zcfg)
    except zenoh.ZError as exc:  # (a missing credential file is a ValueError: one line from courtloc.cli)
        reason = " ".join(str(exc).split(" at ")[0].split())
        raise UsageError(f"cannot listen on {', '.join(listen)}: {reason}", RUN_EXIT) from None
    log.info("router listening on %s", ", ".join(listen))
    print(f"router listening on {', '.join(listen)}", flush=True)
    warn_while_insecure(insecure_exposure(listen, config.router.secure_dir is not None), stop, log)
    try:
        while not stop.wait(0.5):
            pass
    finally:
        session.close()
    return 0
