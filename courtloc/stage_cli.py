"""`courtloc run SERVICE` and `courtloc router`: one stage, or the router, as this process."""
from __future__ import annotations

import argparse
import json
import logging
import signal
import threading
from pathlib import Path

from courtloc.cli import RUN_EXIT, UsageError
from courtloc.recording.busargs import add_timeout_argument, wait_for_router

log = logging.getLogger("courtloc.stage")


def register(sub: argparse._SubParsersAction) -> None:
    run = sub.add_parser("run", help="run one stage in this process (placing it on this machine)")
    run.add_argument("service", help="camera | preprocess | infer | shooter_bridge")
    run.add_argument("--config", type=Path, default=None, help="deployment TOML (default: built-in)")
    add_timeout_argument(run)
    run.set_defaults(func=run_stage)

    router = sub.add_parser("router", help="run a Zenoh router in this process")
    router.add_argument("--listen", action="append", default=None,
                        help="endpoint to listen on, e.g. tcp/0.0.0.0:7447 (repeatable)")
    router.add_argument("--config", type=Path, default=None, help="deployment TOML: takes [router] listen")
    router.set_defaults(func=run_router)


def run_stage(args: argparse.Namespace) -> int:
    from courtloc.deployment import build_stage, load_deployment

    config = load_deployment(args.config)  # a bad file, field or stage name raises, named: one line
    stage = build_stage(args.service, config)
    if stage.zenoh_config.mode == "client":  # a peer opens without a router; a client waits for one
        wait_for_router(stage.zenoh_config, args.timeout)
    return stage.run()


def run_router(args: argparse.Namespace) -> int:
    import zenoh

    from courtloc.common.bus import ZenohConfig, build_zenoh_config
    from courtloc.deployment import load_deployment

    config = load_deployment(args.config)
    listen = args.listen or config.router.listen
    router_cfg = ZenohConfig(mode="router", connect=config.router.connect, listen=listen,
                             config_file=config.zenoh.config_file)
    stop = threading.Event()
    signal.signal(signal.SIGINT, lambda *_: stop.set())
    signal.signal(signal.SIGTERM, lambda *_: stop.set())
    try:
        zcfg = build_zenoh_config(router_cfg)
        if config.router.secure_dir is not None:
            from courtloc.common.security import router_settings
            from courtloc.security.acl import access_control

            for path, value in {**router_settings(config.router.secure_dir),
                                "access_control": access_control(config.robot_id)}.items():
                zcfg.insert_json5(path, json.dumps(value))
        session = zenoh.open(zcfg)
    except zenoh.ZError as exc:  # (a missing credential file is a ValueError: one line from courtloc.cli)
        reason = " ".join(str(exc).split(" at ")[0].split())
        raise UsageError(f"cannot listen on {', '.join(listen)}: {reason}", RUN_EXIT) from None
    log.info("router listening on %s", ", ".join(listen))
    print(f"router listening on {', '.join(listen)}", flush=True)
    try:
        while not stop.wait(0.5):
            pass
    finally:
        session.close()
    return 0
