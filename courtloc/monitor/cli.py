"""`courtloc monitor`: the robot's live state in a browser on the pit laptop."""
from __future__ import annotations

import argparse
import logging
import signal
import sys
import threading

from courtloc.recording.busargs import add_client_arguments, client_deployment


def register(sub: argparse._SubParsersAction) -> None:
    monitor = sub.add_parser("monitor", help="serve a live web page of the robot (pose, health, camera)")
    monitor.add_argument("--port", type=int, default=8080, help="HTTP port (0: any free port)")
    monitor.add_argument("--host", default="127.0.0.1", help="address to serve on (0.0.0.0: the whole pit LAN)")
    monitor.add_argument("--court", default=None, help="court drawing (default: the sim camera's court)")
    monitor.add_argument("--rate", type=float, default=15.0, help="page updates per second")
    add_client_arguments(monitor)
    monitor.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    from courtloc.common.config_loader import ConfigError
    from courtloc.exposure import insecure_exposure, warn_while_insecure
    from courtloc.monitor.app import Monitor

    try:
        config = client_deployment(args)
    except (ConfigError, ValueError) as exc:
        print(exc, file=sys.stderr)
        return 2
    # Plain HTTP shows the robot's streams to whoever can reach it: beyond loopback only when the
    # deployment says insecure = true, and then with a warning every minute.
    exposed = insecure_exposure([f"tcp/{args.host}:{args.port}"], secured=False)
    if exposed and not config.insecure:
        print(f"monitor: --host {args.host} serves the robot's data unencrypted beyond this machine; "
              "set insecure = true in the deployment file to allow it", file=sys.stderr)
        return 2
    if not 1.0 <= args.rate <= 60.0:
        print(f"--rate must be within 1..60, got {args.rate}", file=sys.stderr)
        return 2
    try:
        monitor = Monitor(config, args.court or config.camera.sim.court, args.host, args.port, args.rate)
    except OSError as exc:
        print(f"monitor: cannot serve on {args.host}:{args.port}: {exc.strerror}", file=sys.stderr)
        return 1
    except (ValueError, FileNotFoundError) as exc:
        print(f"monitor: {exc}", file=sys.stderr)
        return 2
    stop = threading.Event()
    signal.signal(signal.SIGINT, lambda *_: stop.set())
    signal.signal(signal.SIGTERM, lambda *_: stop.set())
    print(f"monitor for {config.robot_id}: {monitor.url}", flush=True)
    warn_while_insecure(exposed, stop, logging.getLogger("courtloc.monitor"))
    monitor.run(stop)
    return 0
