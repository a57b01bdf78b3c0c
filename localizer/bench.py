"""Per-frame time of the geometric localizer after preprocessing (hits in, pose out), tracking vs cold start.

Frames are the digital twin's: rendered at random poses and run through the robot's own preprocess code,
so the bench needs no dataset. Timed per frame, on the runtime path (onnxruntime hits -> floor points,
then the numpy fit): tracking = started from the true pose moved by a typical between-frame motion;
cold start = no previous pose (global search). One onnxruntime thread; pin the process to one core
(taskset -c 0) to measure "one CPU core". `--compare-sequential` also times, interleaved frame by frame
in the same run, the path that fits a frame's starts one at a time (the pre-batching tracking path), so
the ratio holds on a noisy machine.
"""
from __future__ import annotations

import argparse
import json
import math
import time
from pathlib import Path

import numpy as np


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--package", type=Path, help="localizer package folder (default: the bundled models/default)")
    parser.add_argument("--frames", type=int, default=40, help="distinct twin frames")
    parser.add_argument("--repeats", type=int, default=20, help="tracking runs per frame")
    parser.add_argument("--cold-repeats", type=int, default=2, help="cold-start runs per frame")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--compare-sequential", action="store_true",
                        help="also time the one-start-at-a-time fit path side by side (same frames, interleaved)")
    parser.add_argument("--json", type=Path, help="also write the result here")


def _frames(predictor, n: int, seed: int) -> list[tuple[np.ndarray, np.ndarray]]:
    from courtloc.sim.edges import scan_hits
    from courtloc.sim.render import Renderer

    court, camera = predictor.package.court, predictor.package.camera
    renderer = Renderer(court, camera)
    rng = np.random.default_rng(seed)
    hx, hy = court.area_half_extent_m
    out = []
    while len(out) < n:
        pose = np.array([rng.uniform(-0.8 * hx, 0.8 * hx), rng.uniform(-0.8 * hy, 0.8 * hy), rng.uniform(-math.pi, math.pi)])
        hits = scan_hits(renderer.render(tuple(pose)))
        if len(hits) >= 20:
            out.append((pose, hits))
    return out


def _stats(ms: list[float]) -> dict:
    a = np.asarray(ms)
    return {"n": int(a.size), "median_ms": float(np.median(a)), "p95_ms": float(np.percentile(a, 95)),
            "mean_ms": float(a.mean())}


def run(args: argparse.Namespace) -> int:
    from courtloc.localizer.eval import default_model_path
    from courtloc.localizer.predictor import load_predictor

    package = args.package or default_model_path()
    predictor = load_predictor(package, threads=1)
    frames = _frames(predictor, args.frames, args.seed)
    rng = np.random.default_rng(args.seed + 1)
    w, h = predictor.width, predictor.height
    sequential = None
    if args.compare_sequential:
        from courtloc.localizer.geometric import GeometricLocalizer

        loc = predictor.localizer
        sequential = GeometricLocalizer(loc.court, loc.camera, loc.config, field=loc.field, batch_starts=False)
    track_ms, seq_ms, cold_ms, onnx_ms, errors, seq_diff = [], [], [], [], [], []
    for pose, hits in frames:
        predictor.predict(hits, w, h, previous=pose)  # warm caches
        for _ in range(args.repeats):
            # ~0.6 m/s at 10 Hz: the previous answer is a few centimetres and a degree off.
            start = pose + np.array([rng.normal(0, 0.05), rng.normal(0, 0.05), rng.normal(0, 0.02)])
            t0 = time.perf_counter()
            pred = predictor.predict(hits, w, h, previous=start)
            track_ms.append((time.perf_counter() - t0) * 1e3)
            errors.append(math.hypot(pred.x - pose[0], pred.y - pose[1]))
            t0 = time.perf_counter()
            predictor.floor_points(hits)
            onnx_ms.append((time.perf_counter() - t0) * 1e3)
            if sequential is not None:
                t0 = time.perf_counter()
                res = sequential.localize_points(predictor.floor_points(hits), start)
                seq_ms.append((time.perf_counter() - t0) * 1e3)
                seq_diff.append(math.hypot(res.pose[0] - pred.x, res.pose[1] - pred.y))
        for _ in range(args.cold_repeats):
            t0 = time.perf_counter()
            predictor.predict(hits, w, h)
            cold_ms.append((time.perf_counter() - t0) * 1e3)
    result = {
        "bench": "localize", "package": str(package), "frames": len(frames),
        "hits_per_frame_median": float(np.median([len(f[1]) for f in frames])),
        "tracking": _stats(track_ms), "cold_start": _stats(cold_ms), "onnx_hits_to_floor": _stats(onnx_ms),
        "tracking_error_median_m": float(np.median(errors)),
    }
    if sequential is not None:
        result["tracking_sequential_starts"] = _stats(seq_ms)
        result["tracking_speedup_median"] = float(np.median(seq_ms) / np.median(track_ms))
        result["sequential_vs_batched_max_diff_m"] = float(np.max(seq_diff))
    text = json.dumps(result, indent=1)
    print(text)
    if args.json:
        args.json.write_text(text)
    return 0
