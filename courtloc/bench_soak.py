"""soak: RSS growth and latency drift of a running `courtloc up` over minutes or hours

Starts `courtloc up` as its own process (exactly what runs on the robot), watches the bus, and every
window samples each process's resident memory and the chain's end-to-end latency. The report gives
per-process RSS growth (first to last window, and a least-squares slope in MB/hour) and the drift of
the latency p50/p99 (slope in ms/hour), plus every window so a plot is one step away.
Not run in CI: it is meant for `--minutes 60` on the robot.
"""
from __future__ import annotations

import argparse
import json
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np

from courtloc.bench_procstats import child_processes, pss_kb
from courtloc.cliargs import add_json_argument, json_to_stdout, positive_float
from courtloc.common.signals import stop_on_signals
from courtloc.services.deployment import load_deployment
from courtloc.watch import BusWatcher


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--config", type=Path, default=None, help="deployment TOML (default: built-in)")
    parser.add_argument("--minutes", type=positive_float, default=10.0, help="how long to run")
    parser.add_argument("--window-s", type=positive_float, default=10.0, help="one sample of RSS and latency per window")
    add_json_argument(parser, "the report")


def rss_mb(pid: int) -> float | None:
    try:
        for line in Path(f"/proc/{pid}/status").read_text().splitlines():
            if line.startswith("VmRSS:"):
                return int(line.split()[1]) / 1024.0
    except OSError:
        return None
    return None


def _slope_per_hour(times_s: list[float], values: list[float | None]) -> float | None:
    pairs = [(t, v) for t, v in zip(times_s, values) if v is not None]
    if len(pairs) < 3:
        return None
    t, v = np.asarray(pairs, dtype=np.float64).T
    return float(np.polyfit(t / 3600.0, v, 1)[0])


def _percentile(values_ns: list[int], q: float) -> float | None:
    return float(np.percentile(np.asarray(values_ns) / 1e6, q)) if values_ns else None


def run(args: argparse.Namespace) -> int:
    config = load_deployment(args.config)
    argv = [sys.executable, "-m", "courtloc", "up", *(["--config", str(args.config)] if args.config else [])]
    up = subprocess.Popen(argv, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, stdin=subprocess.DEVNULL)
    stop = stop_on_signals()
    watcher = BusWatcher(config)
    watcher.start(stop)
    started = time.monotonic()
    windows: list[dict] = []
    seen_pids: dict[str, set[int]] = {}
    try:
        while not stop.wait(args.window_s) and up.poll() is None:
            elapsed = time.monotonic() - started
            with watcher._lock:  # noqa: SLF001 - the watcher's own lock guards its state
                # a window's latencies are taken out: the watcher's bounded deque never fills over hours
                latencies = list(watcher.state.e2e_ns)
                watcher.state.e2e_ns.clear()
            procs = {"launcher": up.pid, **child_processes(up.pid)}
            for role, pid in procs.items():
                seen_pids.setdefault(role, set()).add(pid)
            pss = {r: pss_kb(p) for r, p in procs.items()}
            window = {"t_s": round(elapsed, 1), "rss_mb": {r: rss_mb(p) for r, p in procs.items()},
                      "pss_mb": {r: round(v / 1024, 1) if v is not None else None for r, v in pss.items()},
                      "e2e_n": len(latencies), "e2e_p50_ms": _percentile(latencies, 50),
                      "e2e_p99_ms": _percentile(latencies, 99)}
            windows.append(window)
            print(json.dumps(window), file=sys.stderr, flush=True)
            if elapsed >= args.minutes * 60:
                break
    finally:
        watcher.close()
        up.send_signal(signal.SIGTERM)
        try:
            up.wait(30)
        except subprocess.TimeoutExpired:
            up.kill()
    report = summarise(windows, seen_pids, e2e_topic=watcher.e2e_topic)
    text = json.dumps(report, indent=2)
    if not json_to_stdout(args.json):  # `--json -`: printed once, by the write below
        print(text)
    if args.json is not None:
        args.json.write_text(text)
    return 0 if windows else 1


def summarise(windows: list[dict], seen_pids: dict[str, set[int]], e2e_topic: str) -> dict:
    """Growth and drift, leaving out the first window (imports, model load and caches warming up)."""
    steady = windows[1:] if len(windows) > 2 else windows
    times = [w["t_s"] for w in steady]
    roles = sorted({r for w in windows for r in w["rss_mb"]})
    rss = {}
    for role in roles:
        series = [w["rss_mb"].get(role) for w in steady]
        present = [v for v in series if v is not None]
        rss[role] = {
            "first_mb": present[0] if present else None, "last_mb": present[-1] if present else None,
            "growth_mb": (present[-1] - present[0]) if present else None,
            "slope_mb_per_h": _slope_per_hour(times, series),
            "restarts": max(0, len(seen_pids.get(role, ())) - 1),
            # RSS counts every shared page (libraries, shared-memory frames) in full in every process
            "last_pss_mb": next((w["pss_mb"].get(role) for w in reversed(steady) if w.get("pss_mb", {}).get(role)),
                                None),
        }
    return {
        "windows": len(windows), "duration_s": windows[-1]["t_s"] if windows else 0.0, "e2e_topic": e2e_topic,
        "rss": rss,
        "e2e_p50_ms": {"first": steady[0]["e2e_p50_ms"] if steady else None,
                       "last": steady[-1]["e2e_p50_ms"] if steady else None,
                       "slope_ms_per_h": _slope_per_hour(times, [w["e2e_p50_ms"] for w in steady])},
        "e2e_p99_ms": {"first": steady[0]["e2e_p99_ms"] if steady else None,
                       "last": steady[-1]["e2e_p99_ms"] if steady else None,
                       "slope_ms_per_h": _slope_per_hour(times, [w["e2e_p99_ms"] for w in steady])},
        "series": windows,
    }
