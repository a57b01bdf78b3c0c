"""Paper-style comparison of ONNX pose models: accuracy, latency and peak memory, side by side in one run.

`courtloc bench paper --model NAME=FILE ... --data DIR [--recordings REC]` runs each model in its own
process (so its peak RSS is its own: session + weights + inputs), feeds every model the same frames,
and prints one JSON row per model: n, mse, mean_err_m, ..., latency ms (median, p95: session.run only,
inputs prepared beforehand), peak RSS MB, file MB. Ratios are against the first model.
Typical use: the paper network's dense vs sparse graph, and the CNN baselines.
"""
from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

from courtloc.cli_errors import RUN_EXIT, UsageError
from courtloc.cliargs import add_json_argument, nonnegative_int, positive_int
from courtloc.lab.datasets import Dataset
from courtloc.lab.eval import PaperOnnxModel
from courtloc.lab.metrics import compute_metrics


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--model", action="append", required=True, metavar="NAME=FILE",
                        help="a dense_image or sparse_hits ONNX model (repeat; the first is the reference)")
    parser.add_argument("--data", type=Path, required=True, help="dataset folder (images/ + pose_data.csv)")
    parser.add_argument("--csv", type=Path, default=None)
    parser.add_argument("--recordings", nargs="+", default=None, help="frames of these recordings only")
    parser.add_argument("--frames", type=nonnegative_int, default=300, help="evenly spaced frames to use (0 = all)")
    parser.add_argument("--threads", type=positive_int, default=1, help="onnxruntime intra-op threads")
    add_json_argument(parser, "the rows")
    parser.add_argument("--worker", action="store_true", help=argparse.SUPPRESS)


def _frames(args: argparse.Namespace):  # noqa: ANN202
    dataset = Dataset(args.data, csv_path=args.csv)
    chosen = dataset.indices_of(args.recordings) if args.recordings else np.arange(len(dataset))
    if args.frames and len(chosen) > args.frames:
        chosen = chosen[np.linspace(0, len(chosen) - 1, args.frames).round().astype(int)]
    return dataset, chosen


def _worker(args: argparse.Namespace) -> int:
    """Measure one model (args.model[0]) and print its row as JSON."""

    name, path = args.model[0].split("=", 1)
    dataset, chosen = _frames(args)
    model = PaperOnnxModel(Path(path), threads=args.threads)
    feeds = [model.predictor.dots_feed(dataset.dot_image(int(i))) for i in chosen]
    model.predictor.session.run(None, feeds[0])  # warm-up, not timed
    times, preds = [], []
    for feed in feeds:
        start = time.perf_counter()
        out = model.predictor.session.run(None, feed)[0]
        times.append(time.perf_counter() - start)
        preds.append(out.reshape(-1)[:2])
    metrics = compute_metrics(np.array(preds), dataset.xy[chosen]).as_dict()
    row = {"name": name, "model": Path(path).name, "input_kind": model.manifest.input.kind, **metrics,
           "latency_ms_median": float(np.median(times) * 1e3), "latency_ms_p95": float(np.percentile(times, 95) * 1e3),
           "file_mb": Path(path).stat().st_size / 1e6, "threads": args.threads}
    print(json.dumps(row))
    return 0


def run(args: argparse.Namespace) -> int:
    if args.worker:
        return _worker(args)
    for spec in args.model:  # said here, once, not by a worker process per model
        if "=" not in spec:
            raise UsageError(f"--model wants NAME=FILE, got {spec!r}")
        if not Path(spec.split("=", 1)[1]).is_file():
            raise UsageError(f"--model {spec}: no such file")
    _frames(args)  # a missing or malformed dataset raises here, named
    rows = []
    for spec in args.model:
        cmd = [sys.executable, "-c", "from courtloc.cli import main; main()", "bench", "paper", "--worker", "--model", spec,
               "--data", str(args.data), "--frames", str(args.frames), "--threads", str(args.threads)]
        if args.csv:
            cmd += ["--csv", str(args.csv)]
        if args.recordings:
            cmd += ["--recordings", *args.recordings]
        with tempfile.TemporaryFile("w+") as errors:  # a file, not a pipe: read after the exit, never blocks
            proc = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=errors, text=True)
            out = proc.stdout.read()
            proc.stdout.close()
            # Reap it ourselves: wait4 gives this child's own peak RSS (ru_maxrss, KiB on Linux).
            _, status, usage = os.wait4(proc.pid, 0)
            proc.returncode = os.waitstatus_to_exitcode(status)
            errors.seek(0)
            said = errors.read()
        if proc.returncode:
            last = said.strip().splitlines()[-1] if said.strip() else f"exit {proc.returncode}"
            raise UsageError(f"benchmark of {spec} failed: {last}", RUN_EXIT)
        sys.stderr.write(said)
        row = json.loads(out.strip().splitlines()[-1])
        row["peak_rss_mb"] = usage.ru_maxrss / 1024
        rows.append(row)
    ref = rows[0]
    for row in rows:
        row["latency_ratio_vs_first"] = row["latency_ms_median"] / ref["latency_ms_median"]
        if row.get("peak_rss_mb") and ref.get("peak_rss_mb"):
            row["rss_ratio_vs_first"] = row["peak_rss_mb"] / ref["peak_rss_mb"]
        print(json.dumps(row))
    if args.json:
        args.json.write_text(json.dumps(rows, indent=1) + "\n")
    return 0
