"""frames/s of the preprocess stage (mask + radial scan): fast path vs the pseudo-code reference

All paths run on the same frames in one process, alternating in rounds so a busy machine slows them alike;
the ratios are the numbers to quote. Frames: drawn lines and arcs on grey (`synthetic.line_frame`), or with
`--court NAME` the digital twin's renders of that court at random poses. `fast` is what the stage runs:
the compiled scan when it was built, else numpy; `numpy` is the numpy scan, reported beside it.
The fast path cycles through `--frames` distinct frames, so each frame comes from the shared cache, not
the core's own: the harder case (a frame the stage has just decoded is partly in the core's cache).
OpenCV is limited to one thread (numpy is single-threaded here anyway), so this is one core's speed.
Wall-clock rates (`fast_fps`, ...) suffer when other jobs share the core; the `*_cpu` rates divide by this
thread's CPU time instead, and `load_average` says how busy the machine was.
The fast path's output is checked against the reference on every reference frame first.
"""
from __future__ import annotations

import argparse
import json
import os
import platform
import time

import cv2
import numpy as np

from courtloc.cliargs import add_json_argument, json_to_stdout, positive_float, positive_int
from courtloc.scan.config import PreprocessConfig
from courtloc.scan.hsv_mask import WhiteMask
from courtloc.scan.preprocessor import Preprocessor
from courtloc.scan.radial_scan import RadialScanner
from courtloc.scan.reference_scan import reference_preprocess
from courtloc.scan.synthetic import line_frame
from courtloc.sim.render import Renderer
from courtloc.world.camera import load_camera
from courtloc.world.court import load_court


def add_arguments(parser: argparse.ArgumentParser) -> None:
    add_json_argument(parser, "the report")
    parser.add_argument("--width", type=positive_int, default=640)
    parser.add_argument("--height", type=positive_int, default=480)
    parser.add_argument("--frames", type=positive_int, default=32, help="distinct frames cycled through by the fast path")
    parser.add_argument("--reference-frames", type=positive_int, default=6, help="frames walked by the slow reference")
    parser.add_argument("--seconds", type=positive_float, default=4.0, help="approximate total measuring time")
    parser.add_argument("--rounds", type=positive_int, default=3, help="fast/reference alternations")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--court", default=None, help="use the twin's renders of this court instead of drawn lines")


class _Rate:
    """Calls, wall seconds and CPU seconds of one measured step, summed over rounds."""

    def __init__(self) -> None:
        self.calls, self.wall, self.cpu = 0, 0.0, 0.0

    def measure(self, step, items: list, min_seconds: float) -> None:  # noqa: ANN001
        """Call step on items cyclically (at least one pass) until min_seconds of wall time have passed."""
        wall0, cpu0 = time.perf_counter(), time.thread_time()
        while True:
            for item in items:
                step(item)
            self.calls += len(items)
            if time.perf_counter() - wall0 >= min_seconds:
                break
        self.wall += time.perf_counter() - wall0
        self.cpu += time.thread_time() - cpu0

    @property
    def fps(self) -> float:
        return self.calls / self.wall

    @property
    def fps_cpu(self) -> float:
        return self.calls / self.cpu


def run(args: argparse.Namespace) -> int:
    cv2.setNumThreads(1)
    config = PreprocessConfig(frame_width=args.width, frame_height=args.height,
                              crop_top=min(200, args.height - 1))
    rng = np.random.default_rng(args.seed)
    if args.court:
        frames = _twin_frames(args.court, max(1, args.frames), rng, args.height, args.width)
    else:
        frames = [line_frame(rng, args.height, args.width) for _ in range(max(1, args.frames))]
    reference_frames = frames[: max(1, args.reference_frames)]

    preprocessor = Preprocessor(config)
    numpy_path = Preprocessor(config, native=False)
    start = time.perf_counter()
    RadialScanner(config.scan).table(args.height, args.width)
    table_build_ms = (time.perf_counter() - start) * 1e3
    hits = [preprocessor.process(f) for f in frames]  # also builds preprocessor's own table

    mismatches = sum(not np.array_equal(preprocessor.process(f), reference_preprocess(f, config))
                     or not np.array_equal(numpy_path.process(f), reference_preprocess(f, config))
                     for f in reference_frames)

    # The obvious alternative, for the record: convert the whole frame, then scan the full mask.
    white, scanner = WhiteMask(config.hsv_ranges), RadialScanner(config.scan)
    scanner.table(args.height, args.width)

    def full_frame_path(frame: np.ndarray) -> None:
        scanner.scan_mask(white.frame(frame))

    load_before = os.getloadavg()[0]
    share = args.seconds / max(1, args.rounds)
    fast, numpy_rate, reference, full, paper = _Rate(), _Rate(), _Rate(), _Rate(), _Rate()
    for _ in range(max(1, args.rounds)):
        fast.measure(preprocessor.process, frames, 0.25 * share)
        numpy_rate.measure(numpy_path.process, frames, 0.15 * share)
        full.measure(full_frame_path, frames, 0.1 * share)
        reference.measure(lambda f: reference_preprocess(f, config), reference_frames, 0.5 * share)
    paper.measure(lambda h: preprocessor.paper_image(h, args.height, args.width), hits, 0.2)

    report = {
        "fast_fps": round(fast.fps, 1),
        "reference_fps": round(reference.fps, 2),
        "ratio": round(fast.fps / reference.fps, 1),
        "fast_fps_cpu": round(fast.fps_cpu, 1),
        "reference_fps_cpu": round(reference.fps_cpu, 2),
        "ratio_cpu": round(fast.fps_cpu / reference.fps_cpu, 1),
        "fast_us_per_frame_cpu": round(1e6 / fast.fps_cpu, 1),
        "fast_is_compiled": preprocessor.native,
        "numpy_fps_cpu": round(numpy_rate.fps_cpu, 1),
        "fast_over_numpy_cpu": round(fast.fps_cpu / numpy_rate.fps_cpu, 2),
        "full_frame_mask_fps_cpu": round(full.fps_cpu, 1),
        "paper_image_fps_cpu": round(paper.fps_cpu, 1),
        "load_average": [round(load_before, 2), round(os.getloadavg()[0], 2)],
        "cpus": os.cpu_count(),
        "identical_to_reference": mismatches == 0,
        "frames_checked_against_reference": len(reference_frames),
        "frames_source": f"twin:{args.court}" if args.court else "drawn lines",
        "width": args.width,
        "height": args.height,
        "frames": len(frames),
        "hits_per_frame_mean": round(float(np.mean([len(h) for h in hits])), 1),
        "ray_table_build_ms": round(table_build_ms, 1),
        "ray_samples": int(scanner.table(args.height, args.width).sample_flat.shape[0]),
        "ray_pixels": int(scanner.table(args.height, args.width).pixels.shape[0]),
        "opencv_threads": cv2.getNumThreads(),
        "versions": {"python": platform.python_version(), "numpy": np.__version__, "opencv": cv2.__version__},
        "machine": platform.machine(),
    }
    text = json.dumps(report, indent=2)
    if not json_to_stdout(args.json):  # `--json -`: printed once, by the write below
        print(text)
    if args.json is not None:
        args.json.write_text(text + "\n")
    return 0 if mismatches == 0 else 1


def _twin_frames(court_name: str, n: int, rng, height: int, width: int) -> list:  # noqa: ANN001
    """n clean renders of the court's twin at random poses inside its robot area, as (H, W, 3) BGR."""

    court = load_court(court_name)
    camera = load_camera(court.default_camera)
    if (camera.width, camera.height) != (width, height):
        raise SystemExit(f"the {court_name} camera renders {camera.width}x{camera.height}, not {width}x{height}")
    renderer = Renderer(court, camera)
    hx, hy = court.area_half_extent_m
    return [np.ascontiguousarray(renderer.render((float(rng.uniform(-hx, hx)), float(rng.uniform(-hy, hy)),
                                                  float(rng.uniform(-np.pi, np.pi)))))
            for _ in range(n)]
