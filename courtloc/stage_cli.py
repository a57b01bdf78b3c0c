"""`courtloc run SERVICE` and `courtloc router`: one stage, or the router, as this process."""
from __future__ import annotations

import argparse
import logging
import os
import sys
from pathlib import Path

from courtloc.cli_errors import UsageError
from courtloc.common.exposure import is_loopback
from courtloc.common.services_table import SERVICES
from courtloc.recording.busargs import add_timeout_argument
from courtloc.router_process import RouterSettings, router_argv
from courtloc.services.deployment import DeploymentConfig, load_deployment

log = logging.getLogger("courtloc.stage")


def register(sub: argparse._SubParsersAction) -> None:
    run = sub.add_parser("run", help="run one stage in this process (placing it on this machine)")
    run.add_argument("service", help="camera | preprocess | infer | shooter_bridge")
    run.add_argument("--config", type=Path, default=None, help="deployment TOML (default: built-in)")
    add_timeout_argument(run)
    run.set_defaults(func=run_stage)

    router = sub.add_parser("router", help="run a Zenoh router (as its own lean process)")
    router.add_argument("--listen", action="append", default=None,
                        help="endpoint to listen on, e.g. tcp/0.0.0.0:7447 (repeatable)")
    router.add_argument("--config", type=Path, default=None, help="deployment TOML: takes [router] listen")
    router.set_defaults(func=run_router)


def router_settings(config: DeploymentConfig, listen: list[str] | None = None) -> RouterSettings:
    """What the router process needs of a validated deployment (`listen` overrides its [router] listen)."""
    return RouterSettings(robot_id=config.robot_id, listen=listen or config.router.listen,
                          connect=config.router.connect, secure_dir=config.router.secure_dir,
                          zenoh_config_file=config.zenoh.config_file, shared_memory=config.zenoh.shared_memory)


def stage_argv(name: str, config: Path | None, verbose: int = 0, timeout_s: float | None = None,
               fresh_run: bool = False) -> list[str]:
    """The command line of a stage process: its own entry point, which loads only that stage. `fresh_run`:
    the launcher's first start of a run (a pose saved by an earlier run is not resumed)."""
    return [sys.executable, "-m", f"courtloc.services.{name}", *(["-v"] * verbose),
            *(["--config", str(config)] if config is not None else []),
            *(["--timeout", f"{timeout_s:g}"] if timeout_s is not None else []),
            *(["--fresh-run"] if fresh_run else [])]


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
    settings = router_settings(config, listen)
    logging.shutdown()
    sys.stdout.flush()
    sys.stderr.flush()
    # This process becomes the router's own: zenoh and the access rules, not the CLI's libraries.
    os.execv(sys.executable, router_argv(settings, args.verbose))
