"""end-to-end latency and throughput of the running chain, from message timestamps

Runs `courtloc up` for a while on the given (or built-in) deployment and reads the timestamps the
stages stamped into each message: capture -> last stage's publish. One run reports every stage side
by side, so ratios between stages are meaningful on a noisy machine.
"""
from __future__ import annotations

import argparse
import json
import socket
import subprocess
import sys
import threading
from pathlib import Path

import numpy as np

from courtloc.bench_procstats import ProcessSampler
from courtloc.cliargs import add_json_argument, json_to_stdout, positive_float
from courtloc.common.realtime import RealtimeConfig
from courtloc.common.services_table import RELAY_HOPS
from courtloc.launcher import run_up
from courtloc.services.deployment import load_deployment


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--config", type=Path, default=None, help="deployment TOML (default: built-in)")
    parser.add_argument("--seconds", type=positive_float, default=20.0, help="measurement length")
    add_json_argument(parser, "the report")
    parser.add_argument("--relay", action="store_true",
                        help="also measure the transport baseline in the same run: a raw frame handed along "
                             "4 processes doing trivial work (in shared memory, as the chain moves frames), "
                             "and report the ratio")
    parser.add_argument("--fps", type=positive_float, default=None,
                        help="camera rate (and the relay's), overriding the deployment's [camera] fps")


def run(args: argparse.Namespace) -> int:
    config = load_deployment(args.config)
    if args.fps is not None:
        config = config.model_copy(update={"camera": config.camera.model_copy(update={"fps": args.fps})})
    fps = config.camera.fps
    sampler = ProcessSampler().start()
    try:
        summary = run_up(config, args.seconds, None, threading.Event(), status_stream=sys.stderr)
    finally:
        sampler.stop()
    e2e = summary["e2e_latency_ms"]
    processes = sampler.report(fps)
    robot_side = [role for role in processes["processes"] if role != "camera"]
    report = {
        "services": summary["services"],
        "seconds": summary["duration_s"],
        "e2e_topic": e2e["topic"],
        "e2e_latency_ms_p50": e2e["p50"],
        "e2e_latency_ms_p99": e2e["p99"],
        "e2e_latency_ms_max": e2e["max"],
        "fps": fps,
        # No backlog: the last tenth of the run as fast as the first.
        "e2e_latency_ms_p50_first_10pct": e2e["p50_first_10pct"],
        "e2e_latency_ms_p50_last_10pct": e2e["p50_last_10pct"],
        "frames_published": summary["stages"].get("camera", {}).get("frames_out", 0),
        "solutions_published": summary["messages"].get(e2e["topic"], 0),
        # The last stage's own output rate (its latest health): start-up time is not in it.
        "throughput_hz": summary["stages"].get(e2e["topic"].split("/")[0], {}).get("rate_out_hz", 0.0),
        "valid_fraction": (summary["valid_messages"].get(e2e["topic"], 0)
                           / max(summary["messages"].get(e2e["topic"], 0), 1)),
        "stages": {name: {k: s[k] for k in ("rate_out_hz", "latency_ms_p50", "latency_ms_p99", "dropped")}
                   for name, s in summary["stages"].items()},
        "drops": summary["drops"],
        "restarts": summary["restarts"],
        # CPU from each process's utime + stime between samples; memory as PSS (shared pages split fairly).
        "processes": processes["processes"],
        "robot_side_pss_mb": round(sum(processes["processes"][r]["pss_mb"] for r in robot_side), 1),
        "robot_side_processes": robot_side,
        # Stages pinned or under SCHED_FIFO ([realtime], docs/deployment.md) run differently: say so in the report.
        "realtime": config.realtime.model_dump() if config.realtime.enabled else None,
    }
    if processes["note"]:
        report["processes_note"] = processes["note"]
    if args.relay:
        relay = measure_relay(args.seconds, fps=fps, realtime=config.realtime)
        report["relay_baseline"] = relay
        if relay["e2e_latency_ms_p50"] and report["e2e_latency_ms_p50"]:
            report["chain_over_relay_p50"] = report["e2e_latency_ms_p50"] / relay["e2e_latency_ms_p50"]
    text = json.dumps(report, indent=2)
    if not json_to_stdout(args.json):  # `--json -`: printed once, by the write below
        print(text)
    if args.json is not None:
        args.json.write_text(text)
    return 0


def measure_relay(seconds: float, warmup_frames: int = 30, mode: str = "stage", fps: float = 30.0,
                  realtime: RealtimeConfig | None = None) -> dict[str, float | int | None]:
    """Router + the relay hops as processes (see courtloc/bench_relay.py); latency at the last hop. `realtime`:
    each hop runs with its stage's settings, as in the chain."""

    with socket.socket() as probe:
        probe.bind(("127.0.0.1", 0))
        port = probe.getsockname()[1]
    python = [sys.executable, "-m", "courtloc"]
    router = subprocess.Popen([*python, "router", "--listen", f"tcp/127.0.0.1:{port}"], stdout=subprocess.PIPE,
                              stderr=subprocess.DEVNULL, text=True)
    hops: list[subprocess.Popen] = []
    try:
        router.stdout.readline()  # "router listening ..."
        for hop in reversed(range(RELAY_HOPS)):  # consumers first
            hops.append(subprocess.Popen(
                [sys.executable, "-m", "courtloc.bench_relay", "--hop", str(hop), "--port", str(port),
                 "--seconds", str(seconds), "--mode", mode, "--fps", str(fps),
                 "--realtime", (realtime or RealtimeConfig()).model_dump_json()],
                stdin=subprocess.PIPE, stdout=subprocess.PIPE, stderr=subprocess.DEVNULL, text=True))
        for proc in hops:
            proc.stdout.readline()  # "ready": connected
        for proc in hops:
            proc.stdin.write("go\n")
            proc.stdin.flush()
        last = hops[0]
        out, _ = last.communicate(timeout=seconds + 60)
        spans = np.asarray(json.loads(out.strip().splitlines()[-1])[warmup_frames:])
        for proc in hops[1:]:
            proc.wait(timeout=seconds + 60)
    finally:
        for proc in [*hops, router]:
            if proc.poll() is None:
                proc.terminate()
                proc.wait(timeout=10)
    return {
        "hops": RELAY_HOPS, "mode": mode, "transport": "zenoh shared memory", "fps": fps,
        "frame_bytes": 640 * 480 * 3, "n": int(spans.size),
        "e2e_latency_ms_p50": float(np.percentile(spans, 50)) if spans.size else None,
        "e2e_latency_ms_p99": float(np.percentile(spans, 99)) if spans.size else None,
    }
