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
from courtloc.sim import camera_stage as sim_camera_stage

log = logging.getLogger("courtloc.stage")

SIM_CAMERA_MODULE = sim_camera_stage.__name__  # the camera stage with the twin's simulated camera


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


def router_settings(config: DeploymentConfig, listen: list[str] | None = None,
                    zenoh_id: str | None = None) -> RouterSettings:
    """What the router process needs of a validated deployment (`listen` overrides its [router] listen;
    `zenoh_id`: the identity `courtloc up` gives the router it starts, which its stages check)."""
    return RouterSettings(robot_id=config.robot_id, listen=listen or config.router.listen,
                          connect=config.router.connect, secure_dir=config.router.secure_dir,
                          zenoh_config_file=config.zenoh.config_file, shared_memory=config.zenoh.shared_memory,
                          zenoh_id=zenoh_id)


def stage_module(name: str, config: DeploymentConfig) -> str:
    """The entry point of a stage's process: the stage's own, or for a simulated camera the twin's camera stage
    (the same service with the twin's source; the robot side never imports the twin). Its [camera.sim] table
    is checked here, so a bad one stops `courtloc up` and `courtloc run` before anything starts, naming the field."""
    if name == "camera" and config.camera.source == "sim":
        sim_camera_stage.sim_source_config(config.camera)
        return SIM_CAMERA_MODULE
    return f"courtloc.services.{name}"


def stage_argv(name: str, config_path: Path | None, config: DeploymentConfig, verbose: int = 0,
               timeout_s: float | None = None, fresh_run: bool = False,
               expect_router: str | None = None) -> list[str]:
    """The command line of a stage process: its own entry point (stage_module: `config` is the deployment read
    from `config_path`), which loads only that stage. `fresh_run`: the launcher's first start of a run (a pose
    saved by an earlier run is not resumed). `expect_router`: the zenoh id of the router `courtloc up` started;
    the stage leaves any other router it finds itself connected to."""
    return [sys.executable, "-m", stage_module(name, config), *(["-v"] * verbose),
            *(["--config", str(config_path)] if config_path is not None else []),
            *(["--timeout", f"{timeout_s:g}"] if timeout_s is not None else []),
            *(["--fresh-run"] if fresh_run else []),
            *(["--expect-router", expect_router] if expect_router is not None else [])]


def run_stage(args: argparse.Namespace) -> int:
    if args.service not in SERVICES:
        raise UsageError(f"no stage {args.service!r}; available: {', '.join(SERVICES)}")
    config = load_deployment(args.config)  # a bad file or field raises, named: one line (the stage reads it again)
    argv = stage_argv(args.service, args.config, config, args.verbose, args.timeout)  # and a bad [camera.sim]
    logging.shutdown()
    sys.stdout.flush()
    sys.stderr.flush()
    # This process becomes the stage's own (a stage process never loads the CLI, the lab or other stages).
    os.execv(sys.executable, argv)


def run_router(args: argparse.Namespace) -> int:
    config = load_deployment(args.config)
    listen = args.listen or config.router.listen
    exposed = [ep for ep in listen if not is_loopback(ep)]
    if exposed and config.router.secure_dir is None and not config.insecure:
        raise UsageError(f"--listen {', '.join(exposed)} is reachable beyond this machine: set [router] secure_dir "
                         "(courtloc secure init) or insecure = true in the deployment file")
    settings = router_settings(config, listen)
    logging.shutdown()
    sys.stdout.flush()
    sys.stderr.flush()
    # This process becomes the router's own: zenoh and the access rules, not the CLI's libraries.
    os.execv(sys.executable, router_argv(settings, args.verbose))
