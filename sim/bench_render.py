"""Renderer speed: frames per second of the twin, clean and domain-randomised, side by side."""
from __future__ import annotations

import argparse
import json
import time

import numpy as np
from scipy.spatial import cKDTree

from courtloc.cliargs import add_json_argument, nonnegative_int, positive_int
from courtloc.sim.edges import scan_hits
from courtloc.sim.render import Renderer, RenderOptions
from courtloc.world.camera import load_camera
from courtloc.world.court import load_court


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--court", default="seed-gazebo", help="court name or JSON path")
    parser.add_argument("--camera", default=None, help="camera name or JSON path (default: the court's)")
    parser.add_argument("--frames", type=positive_int, default=300, help="frames per variant")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--realism-frames", type=nonnegative_int, default=50,
                        help="frames run through the preprocess stage to count hits on the court's white edges")
    add_json_argument(parser, "the results")


def run(args: argparse.Namespace) -> int:
    court = load_court(args.court)
    camera = load_camera(args.camera or court.default_camera)
    renderer = Renderer(court, camera)
    rng = np.random.default_rng(args.seed)
    hx, hy = court.area_half_extent_m
    poses = [(float(rng.uniform(-hx, hx)), float(rng.uniform(-hy, hy)), float(rng.uniform(-np.pi, np.pi)))
             for _ in range(args.frames)]
    results = {"court": court.name, "camera": camera.name, "frames": args.frames}
    for name, options in (("clean", RenderOptions()), ("randomised", RenderOptions.randomised())):
        frame_rng = np.random.default_rng(args.seed)
        for pose in poses[:10]:  # warm the caches (texture variants, noise banks) outside the timing
            renderer.render(pose, options, frame_rng)
        start, cpu_start = time.perf_counter(), time.process_time()
        for pose in poses:
            renderer.render(pose, options, frame_rng)
        elapsed = time.perf_counter() - start
        # CPU time too: on a shared machine the wall clock also counts other processes' turns.
        results[f"{name}_cpu_ms_per_frame"] = round(1000 * (time.process_time() - cpu_start) / args.frames, 3)
        results[f"{name}_fps"] = round(args.frames / elapsed, 1)
        results[f"{name}_ms_per_frame"] = round(1000 * elapsed / args.frames, 3)
        if args.realism_frames:
            hits, on_edge = _realism(renderer, court, poses[: args.realism_frames], options, args.seed)
            results[f"{name}_hits_per_frame"] = round(hits, 1)
            results[f"{name}_hits_within_10cm_of_white_edge"] = round(on_edge, 3)
    text = json.dumps(results, indent=1)
    print(text)
    if args.json is not None:
        args.json.write_text(text + "\n")
    return 0


def _realism(renderer, court, poses, options, seed: int) -> tuple[float, float]:
    """Mean hits per frame of the real preprocess stage, and the fraction that back-project to within
    10 cm of a white edge of the court (far-away hits span more than 10 cm per pixel, so even a perfect
    twin stays below 1)."""

    tree = cKDTree(court.white_edges(0.01)[0])
    counts, fractions = [], []
    for k, pose in enumerate(poses):
        hits = scan_hits(renderer.render(pose, options, np.random.default_rng([seed, k])))
        counts.append(len(hits))
        if len(hits):
            floor = renderer.camera.pixel_to_court(hits[:, [1, 0]].astype(float), pose)
            fractions.append(float(np.mean(tree.query(np.nan_to_num(floor, nan=1e3))[0] < 0.1)))
    return float(np.mean(counts)), float(np.mean(fractions)) if fractions else 0.0
