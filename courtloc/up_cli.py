"""`courtloc up`: the whole pipeline on this machine."""
from __future__ import annotations

import argparse
import json
import signal
import sys
import threading
from pathlib import Path


def register(sub: argparse._SubParsersAction) -> None:
    up = sub.add_parser("up", help="start a router and every stage as separate processes")
    up.add_argument("--config", type=Path, default=None, help="deployment TOML (default: built-in sim demo)")
    up.add_argument("--duration", type=float, default=None, help="stop after S seconds")
    up.add_argument("--summary-json", type=Path, default=None, help="write the run's summary here")
    up.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    from courtloc.common.config_loader import ConfigError
    from courtloc.deployment import load_deployment
    from courtloc.launcher import LaunchError, run_up

    try:
        config = load_deployment(args.config)
    except ConfigError as exc:
        print(exc, file=sys.stderr)
        return 2
    if not config.launcher.services:
        print(f"{args.config}: [launcher] services is empty: nothing to start here "
              "(this is a pit profile: use `courtloc monitor` or `courtloc model ...`)", file=sys.stderr)
        return 2
    stop = threading.Event()
    signal.signal(signal.SIGINT, lambda *_: stop.set())
    signal.signal(signal.SIGTERM, lambda *_: stop.set())
    try:
        summary = run_up(config, args.duration, args.summary_json, stop)
    except LaunchError as exc:
        print(f"courtloc up: {exc}", file=sys.stderr)
        return 1
    e2e = summary["e2e_latency_ms"]
    print(json.dumps({k: summary[k] for k in ("poses", "solutions", "drops", "rejected", "restarts")}))
    if e2e["n"]:
        print(f"end-to-end latency ({e2e['topic']}): p50 {e2e['p50']:.2f} ms, p99 {e2e['p99']:.2f} ms, "
              f"max {e2e['max']:.2f} ms over {e2e['n']} messages")
    return 0
