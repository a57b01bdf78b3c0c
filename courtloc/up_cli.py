"""`courtloc up`: the whole pipeline on this machine."""
from __future__ import annotations

import argparse
import json
from pathlib import Path

from courtloc.cli_errors import RUN_EXIT, UsageError
from courtloc.cliargs import json_output, positive_float
from courtloc.common.signals import stop_on_signals
from courtloc.launcher import LaunchError, run_up
from courtloc.services.deployment import load_deployment
from courtloc.services.infer.store import ModelStore


def register(sub: argparse._SubParsersAction) -> None:
    up = sub.add_parser("up", help="start a router and every stage as separate processes")
    up.add_argument("--config", type=Path, default=None, help="deployment TOML (default: built-in sim demo)")
    up.add_argument("--duration", type=positive_float, default=None, help="stop after S seconds")
    up.add_argument("--summary-json", type=json_output, default=None, metavar="FILE",
                    help="write the run's summary as JSON to FILE ('-': standard output)")
    up.add_argument("--model-store", type=Path, default=None, metavar="DIR",
                    help="the infer stage's model store (default: the config's [infer] store); "
                         "`make demo` keeps one in the checkout")
    up.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    config = load_deployment(args.config)
    if not config.launcher.services:
        raise UsageError(f"{args.config}: [launcher] services is empty: nothing to start here "
                         "(this is a pit profile: use `courtloc monitor` or `courtloc model ...`)")
    if args.model_store is not None:
        config = config.model_copy(update={"infer": config.infer.model_copy(update={"store": args.model_store.resolve()})})
    if "infer" in config.launcher.services:
        if Path(config.infer.store).exists() and not Path(config.infer.store).is_dir():
            raise UsageError(f"model store {config.infer.store} is not a folder (--model-store or [infer] store)")
        print(f"model store {config.infer.store}: serving {_active_model(config.infer.store)}", flush=True)
    stop = stop_on_signals()
    try:
        summary = run_up(config, args.duration, args.summary_json, stop)
    except LaunchError as exc:
        raise UsageError(str(exc), RUN_EXIT) from None
    pose = summary.get("last_pose")
    if pose:
        print(f"served model: {pose['model_name']} v{pose['model_version']}")
    e2e = summary["e2e_latency_ms"]
    print(json.dumps({k: summary[k] for k in ("poses", "solutions", "drops", "rejected", "restarts")}))
    if e2e["n"]:
        print(f"end-to-end latency ({e2e['topic']}): p50 {e2e['p50']:.2f} ms, p99 {e2e['p99']:.2f} ms, "
              f"max {e2e['max']:.2f} ms over {e2e['n']} messages")
    return 0


def _active_model(store: Path) -> str:
    """What the infer stage will serve from `store`, read from its active record before it starts."""

    active = ModelStore(store).record().active
    if active is None:
        return "the bundled default (models/default; a fresh store starts with it as default v1)"
    return f"{active.name} v{active.version} (the store's active model)"
