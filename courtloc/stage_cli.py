"""`courtloc run SERVICE` and `courtloc router`: one stage, or the router, as this process."""
from __future__ import annotations

import argparse
import json
import logging
import signal
import sys
import threading
from pathlib import Path

log = logging.getLogger("courtloc.stage")


def register(sub: argparse._SubParsersAction) -> None:
    run = sub.add_parser("run", help="run one stage in this process (placing it on this machine)")
    run.add_argument("service", help="camera | preprocess | infer | shooter_bridge")
    run.add_argument("--config", type=Path, default=None, help="deployment TOML (default: built-in)")
    run.set_defaults(func=run_stage)

    router = sub.add_parser("router", help="run a Zenoh router in this process")
    router.add_argument("--listen", action="append", default=None,
                        help="endpoint to listen on, e.g. tcp/0.0.0.0:7447 (repeatable)")
    router.add_argument("--config", type=Path, default=None, help="deployment TOML: takes [router] listen")
    router.set_defaults(func=run_router)


def run_stage(args: argparse.Namespace) -> int:
    from courtloc.common.config_loader import ConfigError
    from courtloc.deployment import build_stage, load_deployment

    from courtloc.common.realtime import RealtimeError, apply_realtime

    try:
        config = load_deployment(args.config)
        stage = build_stage(args.service, config)
        applied = apply_realtime(args.service, config.realtime)
    except (ConfigError, ValueError, RealtimeError) as exc:
        print(exc, file=sys.stderr)
        return 2
    if applied:
        log.info("%s real-time settings: %s", args.service, ", ".join(applied))
    return stage.run()


def run_router(args: argparse.Namespace) -> int:
    import zenoh

    from courtloc.common.bus import ZenohConfig, build_zenoh_config
    from courtloc.common.config_loader import ConfigError
    from courtloc.deployment import load_deployment

    try:
        config = load_deployment(args.config)
    except ConfigError as exc:
        print(exc, file=sys.stderr)
        return 2
    listen = args.listen or config.router.listen
    router_cfg = ZenohConfig(mode="router", connect=config.router.connect, listen=listen,
                             config_file=config.zenoh.config_file, shared_memory=config.zenoh.shared_memory)
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
    except ValueError as exc:  # a missing credential file
        print(f"router: {exc}", file=sys.stderr)
        return 2
    except zenoh.ZError as exc:
        print(f"router: cannot listen on {listen}: {str(exc).split(' at ')[0]}", file=sys.stderr)
        return 1
    log.info("router listening on %s", ", ".join(listen))
    print(f"router listening on {', '.join(listen)}", flush=True)
    try:
        while not stop.wait(0.5):
            pass
    finally:
        session.close()
    return 0
