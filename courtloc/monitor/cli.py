"""`courtloc monitor`: the robot's live state in a browser on the pit laptop."""
from __future__ import annotations

import argparse
import logging

from courtloc.cli_errors import RUN_EXIT, UsageError
from courtloc.cliargs import port_number, positive_float
from courtloc.common.bus import wait_for_router
from courtloc.common.exposure import insecure_exposure, warn_while_insecure
from courtloc.common.signals import stop_on_signals
from courtloc.monitor.app import Monitor
from courtloc.recording.busargs import add_client_arguments, client_deployment


def register(sub: argparse._SubParsersAction) -> None:
    monitor = sub.add_parser("monitor", help="serve a live web page of the robot (pose, health, camera)")
    monitor.add_argument("--port", type=port_number, default=8080, help="HTTP port (0: any free port)")
    monitor.add_argument("--host", default="127.0.0.1", help="address to serve on (0.0.0.0: the whole pit LAN)")
    monitor.add_argument("--court", default=None, help="court drawing (default: the sim camera's court)")
    monitor.add_argument("--rate", type=positive_float, default=15.0, help="page updates per second (1..60)")
    add_client_arguments(monitor)
    monitor.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    # Plain HTTP shows the robot's streams to whoever can reach it: beyond loopback only when the
    # deployment says insecure = true, and then with a warning every minute.
    exposed = insecure_exposure([f"tcp/{args.host}:{args.port}"], secured=False)
    if not 1.0 <= args.rate <= 60.0:
        raise UsageError(f"--rate must be within 1..60, got {args.rate:g}")
    config = client_deployment(args)  # a bad file or field raises, named
    if exposed and not config.insecure:
        raise UsageError(f"--host {args.host} serves the robot's data unencrypted beyond this machine; "
                         "set insecure = true in the deployment file to allow it")
    if args.timeout is not None:  # without it the page starts at once and shows "no router" until one answers
        wait_for_router(config.zenoh, args.timeout)
    try:
        monitor = Monitor(config, args.court or config.camera.sim.get("court", config.court), args.host, args.port, args.rate)
    except FileNotFoundError:
        raise
    except OSError as exc:
        raise UsageError(f"cannot serve on {args.host}:{args.port}: {exc.strerror}", RUN_EXIT) from None
    stop = stop_on_signals()
    print(f"monitor for {config.robot_id} (router {', '.join(config.zenoh.connect)}): {monitor.url}", flush=True)
    warn_while_insecure(exposed, stop, logging.getLogger("courtloc.monitor"))
    monitor.run(stop)
    return 0
