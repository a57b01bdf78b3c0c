"""Per-frame time of the geometric localizer after preprocessing (hits in, pose out), tracking vs cold start.

Frames are the digital twin's: rendered at random poses and run through the robot's own preprocess code,
so the bench needs no dataset. Timed per frame, on the runtime path (`GeometricPredictor.predict`:
hits -> floor points -> fit -> Prediction): tracking = started from the true pose moved by a typical
between-frame motion; cold start = no previous pose (global search). Both paths are timed in the same
run, interleaved frame by frame so that the ratio holds on a noisy machine: the compiled one (fit_kernel.c:
table lookup + geometry + the whole fit in C, what runs when the kernel is built) and the numpy reference
(onnxruntime + numpy, the fallback without a compiler). One onnxruntime thread; pin the process to one
core (taskset -c 0) to measure "one CPU core". `--compare-sequential` also times the path that fits a
frame's starts one at a time (the pre-batching tracking path). `tracking_filtered` times what the infer
stage runs per frame: `GeometricPredictor.track`, the same fit from the motion filter's prediction plus the
filter's predict and update (a state started at the perturbed pose one frame period earlier). `global_search`
times the court search's candidates alone (search.py: the cost volume and its lowest poses), compiled
(search_kernel.c) and numpy side by side: what an acquiring frame of the infer stage runs once or twice.
`marks_search` (a court with colour marks) times what the colour-marks search adds to it on the frames showing
`search.marks_min` marks or more (marks_search.py: the marks' share over the grid and its lowest poses).
"""
from __future__ import annotations

import argparse
import json
import math
import time
from pathlib import Path

import numpy as np

from courtloc.cliargs import add_json_argument, nonnegative_float, nonnegative_int, positive_int
from courtloc.lab.eval import default_model_path
from courtloc.localizer import motion
from courtloc.localizer.fit import kernel_active, kernel_enabled
from courtloc.localizer.geometric import GeometricLocalizer
from courtloc.localizer.marks import mark_points
from courtloc.localizer.predictor import load_predictor
from courtloc.localizer.search import kernel_available as search_kernel_available
from courtloc.scan.config import PreprocessConfig
from courtloc.scan.preprocessor import Preprocessor
from courtloc.services.deployment import court_marks
from courtloc.sim.edges import scan_hits
from courtloc.sim.render import Renderer


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--package", type=Path, help="localizer package folder (default: the bundled models/default)")
    parser.add_argument("--frames", type=positive_int, default=40, help="distinct twin frames")
    parser.add_argument("--repeats", type=positive_int, default=20, help="tracking runs per frame")
    parser.add_argument("--cold-repeats", type=nonnegative_int, default=2, help="cold-start runs per frame")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--idle-ms", type=nonnegative_float, default=0.0,
                        help="sleep this long before each timed tracking call, as a stage idles between frames "
                             "(33 at 30 fps): what the caches lose while idle shows in the times")
    parser.add_argument("--compare-sequential", action="store_true",
                        help="also time the one-start-at-a-time fit path side by side (same frames, interleaved)")
    add_json_argument(parser, "the result")


def _frames(predictor, n: int, seed: int) -> list[tuple[np.ndarray, np.ndarray, np.ndarray]]:
    """(true pose, hits, colour marks) of `n` twin frames with 20 hits or more."""
    court, camera = predictor.package.court, predictor.package.camera
    renderer = Renderer(court, camera)
    marks_finder = Preprocessor(PreprocessConfig(marks=court_marks(court.name)))  # as the stage finds them
    rng = np.random.default_rng(seed)
    hx, hy = court.area_half_extent_m
    out = []
    while len(out) < n:
        pose = np.array([rng.uniform(-0.8 * hx, 0.8 * hx), rng.uniform(-0.8 * hy, 0.8 * hy), rng.uniform(-math.pi, math.pi)])
        image = renderer.render(tuple(pose))
        hits = scan_hits(image)
        if len(hits) >= 20:
            out.append((pose, hits, marks_finder.marks(image)))
    return out


def _stats(ms: list[float]) -> dict:
    a = np.asarray(ms)
    if a.size == 0:
        return {"n": 0}
    return {"n": int(a.size), "median_ms": float(np.median(a)), "p95_ms": float(np.percentile(a, 95)),
            "mean_ms": float(a.mean())}


def _timed(fn) -> tuple[float, object]:
    t0 = time.perf_counter()
    out = fn()
    return (time.perf_counter() - t0) * 1e3, out


def run(args: argparse.Namespace) -> int:
    package = args.package or default_model_path()
    predictor = load_predictor(package, threads=1)
    frames = _frames(predictor, args.frames, args.seed)
    rng = np.random.default_rng(args.seed + 1)
    w, h = predictor.width, predictor.height
    compiled = kernel_active()
    sequential = None
    if args.compare_sequential:
        loc = predictor.localizer
        sequential = GeometricLocalizer(loc.court, loc.camera, loc.config, field=loc.field, batch_starts=False)

    motion_cfg = predictor.localizer.config.motion
    ms: dict[str, list[float]] = {k: [] for k in ("track", "track_numpy", "cold", "cold_numpy", "onnx", "seq",
                                                 "filtered", "search", "search_numpy", "marks_search")}
    coarse = predictor.localizer.search
    marks_search, search_cfg = predictor.localizer.marks_search, predictor.localizer.config.search
    errors, path_diff, seq_diff = [], [], []

    def idle() -> None:
        if args.idle_ms > 0:
            time.sleep(args.idle_ms / 1e3)

    def numpy_predict(*a, **kw):
        with kernel_enabled(False):
            return predictor.predict(*a, **kw)

    for pose, hits, marks in frames:
        predictor.predict(hits, w, h, previous=pose)  # warm caches
        numpy_predict(hits, w, h, previous=pose)
        for _ in range(args.repeats):
            # ~0.6 m/s at 10 Hz: the previous answer is a few centimetres and a degree off.
            start = pose + np.array([rng.normal(0, 0.05), rng.normal(0, 0.05), rng.normal(0, 0.02)])
            idle()
            t, pred = _timed(lambda: predictor.predict(hits, w, h, previous=start))
            ms["track"].append(t)
            errors.append(math.hypot(pred.x - pose[0], pred.y - pose[1]))
            if compiled:
                t, ref = _timed(lambda: numpy_predict(hits, w, h, previous=start))
                ms["track_numpy"].append(t)
                path_diff.append(max(abs(ref.x - pred.x), abs(ref.y - pred.y)))
            state = motion.start(start, None, 0.0, motion_cfg)
            idle()
            ms["filtered"].append(_timed(lambda: predictor.track(hits, w, h, state, motion_cfg.frame_period_s))[0])
            ms["onnx"].append(_timed(lambda: predictor.floor_points(hits))[0])
            if sequential is not None:
                t, res = _timed(lambda: sequential.localize(predictor.projected_hits(hits), start))
                ms["seq"].append(t)
                seq_diff.append(math.hypot(res.pose[0] - pred.x, res.pose[1] - pred.y))
        projected = predictor.projected_hits(hits)
        points = mark_points(predictor.floor_table, w, marks) if marks_search is not None else None
        for _ in range(args.cold_repeats):
            ms["search"].append(_timed(lambda: coarse.candidates(projected))[0])
            if points is not None and len(points) >= search_cfg.marks_min:
                cost = coarse.costs(projected)
                ms["marks_search"].append(_timed(lambda: marks_search.candidates(cost, points, [], search_cfg))[0])
            with kernel_enabled(False):
                ms["search_numpy"].append(_timed(lambda: coarse.candidates(projected))[0])
            t, pred = _timed(lambda: predictor.predict(hits, w, h))
            ms["cold"].append(t)
            if compiled:
                t, ref = _timed(lambda: numpy_predict(hits, w, h))
                ms["cold_numpy"].append(t)
                path_diff.append(max(abs(ref.x - pred.x), abs(ref.y - pred.y)))
    result = {
        "bench": "localize", "package": str(package), "frames": len(frames), "idle_ms": args.idle_ms,
        "hits_per_frame_median": float(np.median([len(f[1]) for f in frames])),
        "marks_per_frame_median": float(np.median([len(f[2]) for f in frames])),
        "compiled_kernel": compiled,
        "tracking": _stats(ms["track"]), "tracking_filtered": _stats(ms["filtered"]), "cold_start": _stats(ms["cold"]),
        "onnx_hits_to_floor": _stats(ms["onnx"]),
        "global_search": _stats(ms["search"]), "global_search_numpy": _stats(ms["search_numpy"]),
        "compiled_search_kernel": search_kernel_available(),
        "marks_search": _stats(ms["marks_search"]), "marks_search_max_points": search_cfg.marks_max_points,
        "tracking_error_median_m": float(np.median(errors)),
    }
    if compiled:
        result["tracking_numpy"] = _stats(ms["track_numpy"])
        result["tracking_speedup_median"] = float(np.median(ms["track_numpy"]) / np.median(ms["track"]))
        if ms["cold"]:
            result["cold_start_numpy"] = _stats(ms["cold_numpy"])
            result["cold_start_speedup_median"] = float(np.median(ms["cold_numpy"]) / np.median(ms["cold"]))
        result["kernel_vs_numpy_max_diff_m"] = float(np.max(path_diff))
    if search_kernel_available() and ms["search"]:
        result["global_search_speedup_median"] = float(np.median(ms["search_numpy"]) / np.median(ms["search"]))
    if sequential is not None:
        result["tracking_sequential_starts"] = _stats(ms["seq"])
        result["sequential_vs_batched_max_diff_m"] = float(np.max(seq_diff))
    text = json.dumps(result, indent=1)
    print(text)
    if args.json:
        args.json.write_text(text)
    return 0
