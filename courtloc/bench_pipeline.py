"""end-to-end latency and throughput of the running chain, from message timestamps

Runs `courtloc up` for a while on the given (or built-in) deployment and reads the timestamps the
stages stamped into each message: capture -> last stage's publish. One run reports every stage side
by side, so ratios between stages are meaningful on a noisy machine.
"""
from __future__ import annotations

import argparse
import json
import sys
import threading
from pathlib import Path


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--config", type=Path, default=None, help="deployment TOML (default: built-in)")
    parser.add_argument("--seconds", type=float, default=20.0, help="measurement length")
    parser.add_argument("--json", type=Path, default=None, help="write the report here")


def run(args: argparse.Namespace) -> int:
    from courtloc.deployment import load_deployment
    from courtloc.launcher import run_up

    config = load_deployment(args.config)
    summary = run_up(config, args.seconds, None, threading.Event(), status_stream=sys.stderr)
    e2e = summary["e2e_latency_ms"]
    report = {
        "services": summary["services"],
        "seconds": summary["duration_s"],
        "e2e_topic": e2e["topic"],
        "e2e_latency_ms_p50": e2e["p50"],
        "e2e_latency_ms_p99": e2e["p99"],
        "e2e_latency_ms_max": e2e["max"],
        # The last stage's own output rate (its latest health): start-up time is not in it.
        "throughput_hz": summary["stages"].get(e2e["topic"].split("/")[0], {}).get("rate_out_hz", 0.0),
        "valid_fraction": (summary["valid_messages"].get(e2e["topic"], 0)
                           / max(summary["messages"].get(e2e["topic"], 0), 1)),
        "stages": {name: {k: s[k] for k in ("rate_out_hz", "latency_ms_p50", "latency_ms_p99", "dropped")}
                   for name, s in summary["stages"].items()},
        "drops": summary["drops"],
        "restarts": summary["restarts"],
    }
    text = json.dumps(report, indent=2)
    print(text)
    if args.json is not None:
        args.json.write_text(text)
    return 0
