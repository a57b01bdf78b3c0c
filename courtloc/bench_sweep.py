"""Twin sweep: many walks and frame timings through the infer stage's tracker, in one process per walk.

`courtloc bench sweep --court C --scenario S,... --seeds 1-8 --seconds 30 --json OUT`: each scenario's twin walk is
rendered once per seed through the robot's own preprocess (hits and colour marks), then localised frame by frame
through the infer stage's tracker (`Tracker.step`, with the stage's start prior and off-court rule) under the frame
timings a chain gives it: every frame at the camera's rate (`all`), 5 % or 25 % of the frames lost at random with
2-3 ms of capture jitter (`drop5`, `drop25`), every second or third frame (`half`, `third`). Vision only, and fused
with the twin's wheel odometry and gyro (`sim/odometry.py`; a kidnap's teleport is not felt by the wheels, as with
the twin's MCU in `bench twin`). The infer-process kill of `outage` is not modelled here, nor is `mcu_loss` (refused).

`courtloc bench twin` runs one walk in real time through the real stages; this one runs tens of walks in minutes,
which is where a rare valid-and-wrong pose shows. Per scenario and mode: runs, n, valid_fraction, valid_mean_err_m,
valid_wrong (valid poses more than 0.5 m off), valid_wrong_runs (each such run: seed, timing, first time, worst
error), and by_timing (n, valid_fraction and valid_wrong of each timing's runs). Where the walk has kidnaps, their
recoveries as `bench twin` times them (courtloc/bench_twin_metrics.py), on capture times (no chain latency): from the
first usable view after the teleport (courtloc/bench_twin_views.py: held over a few delivered frames, showing the
side) to the first valid pose within 0.5 m, 0 when that came first; an event not recovered before the next counts
with the time it had and in events_unrecovered, one without such a view in events_without_view; recovery_wrong
counts first valid poses more than 0.5 m off. No clock is read: a run repeats exactly on one machine (another CPU's
floating point may tip a near-tie).
"""
from __future__ import annotations

import argparse
import json
import math
import os
import sys
from concurrent.futures import ProcessPoolExecutor
from dataclasses import dataclass, replace
from functools import cache
from typing import Any, Callable

import numpy as np

from courtloc.bench_twin import build_scenarios, start_config
from courtloc.bench_twin_metrics import TruthSample
from courtloc.bench_twin_views import ViewJudge, first_view
from courtloc.cli_errors import UsageError
from courtloc.cliargs import JSON_STDOUT, add_json_argument, json_output, json_to_stdout, positive_float
from courtloc.lab.metrics import WRONG_M
from courtloc.localizer.manifest import ManifestError
from courtloc.localizer.odometry_fusion import FusionConfig, OdometryFusion
from courtloc.localizer.package import bundled_package
from courtloc.localizer.predictor import load_predictor
from courtloc.localizer.tracking import Tracker
from courtloc.scan.config import PreprocessConfig
from courtloc.scan.preprocessor import Preprocessor
from courtloc.services.deployment import court_marks
from courtloc.services.infer.config import InferConfig, StartConfig
from courtloc.services.infer.service import start_prior
from courtloc.services.infer.validation import is_on_court
from courtloc.sim.odometry import OdometrySimConfig, OdometrySimulator
from courtloc.sim.scenarios import Scenario
from courtloc.sim.source import SimSource

TIMINGS = ("all", "drop5", "drop25", "half", "third")


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--court", default="seed-gazebo", help="court name (world/courts) or JSON path")
    parser.add_argument("--camera", default=None, help="camera name or JSON path (default: the court's own)")
    parser.add_argument("--scenario", default="clean,randomised,occluded,fast,kidnap,minus_x_start",
                        help="comma-separated twin scenarios (those of `bench twin`)")
    parser.add_argument("--seeds", default="1-8", help="walk seeds: 'A-B' or a comma-separated list")
    parser.add_argument("--seconds", type=positive_float, default=30.0, help="sim seconds per walk")
    parser.add_argument("--timings", default=",".join(TIMINGS), help=f"frame timings, of {', '.join(TIMINGS)}")
    parser.add_argument("--mode", choices=("vision_only", "fused", "both"), default="both")
    parser.add_argument("--jobs", type=int, default=os.cpu_count() or 1, help="walks rendered and run at once")
    add_json_argument(parser, "the report (default: printed to standard output)")


def parse_seeds(text: str) -> list[int]:
    try:
        if "-" in text.strip("-"):
            first, last = (int(v) for v in text.split("-", 1))
            seeds = list(range(first, last + 1))
        else:
            seeds = [int(v) for v in text.split(",") if v.strip()]
    except ValueError:
        raise UsageError(f"--seeds {text!r}: give 'A-B' or a comma-separated list of integers") from None
    if not seeds:
        raise UsageError(f"--seeds {text!r}: no seed given")
    return seeds


def frame_timing(n: int, fps: float, timing: str, rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
    """(indices of the frames that reach the infer stage, their capture times in seconds)."""
    idx = np.arange(n)
    keep = {"all": np.ones(n, bool), "drop5": rng.random(n) > 0.05, "drop25": rng.random(n) > 0.25,
            "half": idx % 2 == 0, "third": idx % 3 == 0}[timing]
    idx = idx[keep]
    t = idx / fps
    if timing.startswith("drop"):  # a loaded chain's capture stamps wander by a few ms
        t = t + rng.normal(0.0, 0.002, len(idx)) + rng.exponential(0.001, len(idx))
    return idx, t


@dataclass
class Walk:
    """One rendered walk: each frame's hits, colour marks and true pose; odometry as it reaches the host."""

    hits: list[np.ndarray]
    marks: list[np.ndarray]
    truth: np.ndarray  # (n, 3)
    width: int
    height: int
    odometry: list  # sim.odometry Delivered
    kidnaps_s: list[float]


def render_walk(sc: Scenario, seconds: float) -> Walk:
    pre = Preprocessor(PreprocessConfig(marks=court_marks(sc.sim.court)))
    pre.warm_up()
    hits, marks, truth = [], [], []
    with SimSource(sc.sim) as source:
        for _ in range(int(seconds * sc.sim.fps)):
            frame, pose = source.read()
            hits.append(pre.process(frame))
            marks.append(pre.marks(frame))
            truth.append(pose)
        odometry = list(OdometrySimulator(source.trajectory, OdometrySimConfig(), seed=sc.sim.seed,
                                          kidnaps_s=sc.sim.kidnaps_s).stream(seconds + 1.0))
        width, height = source.camera.width, source.camera.height
    return Walk(hits, marks, np.array(truth).reshape(-1, 3), width, height, odometry, list(sc.sim.kidnaps_s))


def localise(walk: Walk, predictor, sc: Scenario, idx: np.ndarray, times: np.ndarray,  # noqa: ANN001
             fused: bool) -> list[tuple[float, bool, float]]:
    """(time, valid, position error) of each frame of `idx`, as the infer stage answers it (off the court: not
    valid)."""
    tracker = Tracker(start=start_prior(StartConfig(**start_config(sc, "pose"))))  # as `bench twin` tells the stage
    margin = InferConfig.model_fields["on_court_margin_m"].default
    fusion = OdometryFusion(FusionConfig(enabled=True)) if fused else None
    delivered, rows = 0, []
    for i, t in zip(idx, times):
        # Odometry that reached the host by the time this frame is processed (one frame period later).
        now = float(t) + 1.0 / sc.sim.fps
        while fusion is not None and delivered < len(walk.odometry) and walk.odometry[delivered].at_s <= now:
            fusion.offer(walk.odometry[delivered].message, now)
            delivered += 1
        p = tracker.step(predictor, walk.hits[i], walk.width, walk.height, t=float(t), fusion=fusion,
                         marks=walk.marks[i])
        valid = bool(p.valid) and all(map(math.isfinite, (p.x, p.y))) and is_on_court(predictor.court, p.x, p.y,
                                                                                         margin)
        rows.append((float(t), valid, math.hypot(p.x - walk.truth[i][0], p.y - walk.truth[i][1])))
    return rows


def run_walk(sc: Scenario, seconds: float, timings: list[str], modes: list[str],
             camera: str | None) -> dict[str, list[dict[str, Any]]]:
    """Every timing and mode of one walk: per mode, one summary per timing."""
    walk = render_walk(sc, seconds)
    court = sc.sim.court
    predictor = load_predictor(bundled_package(court, camera or court))
    usable = UsableViews(walk, ViewJudge(predictor))
    out: dict[str, list[dict[str, Any]]] = {}
    for mode in modes:
        for k, timing in enumerate(timings):
            rng = np.random.default_rng([sc.sim.seed, k])
            idx, times = frame_timing(len(walk.hits), sc.sim.fps, timing, rng)
            rows = localise(walk, predictor, sc, idx, times, mode == "fused")
            out.setdefault(mode, []).append({"seed": sc.sim.seed, "timing": timing, **summarise(rows),
                                             "recoveries": recoveries(walk, sc.sim.fps, idx, rows, usable,
                                                                      usable.shows_side)})
    return out


class UsableViews:
    """Whether each frame of a walk is usable (`ViewJudge.usable`) and shows the robot's side (`tells_side`),
    judged once a frame when first asked."""

    def __init__(self, walk: Walk, judge: ViewJudge) -> None:
        self.walk, self.judge = walk, judge
        self._usable = cache(lambda i: judge.usable(walk.hits[i], self._truth(i)))
        self._shows_side = cache(lambda i: judge.tells_side(walk.marks[i], self._truth(i)))

    def __call__(self, i: int) -> bool:
        return self._usable(i)

    def shows_side(self, i: int) -> bool:
        return self._shows_side(i)

    def _truth(self, i: int) -> TruthSample:
        x, y, yaw = self.walk.truth[i]
        return TruthSample(i, i, float(x), float(y), float(yaw))


def recoveries(walk: Walk, fps: float, idx: np.ndarray, rows: list[tuple[float, bool, float]],
               usable: Callable[[int], bool], shows_side: Callable[[int], bool] | None = None) -> list[dict[str, Any]]:
    """Each kidnap's recovery in one run (module docstring): the frames delivered (`idx`, their `rows`) from the
    first frame at or after the teleport to the next one's (or the end). `shows_side`: whether a frame tells the
    robot from its twin (None: every frame does)."""
    out = []
    firsts = [math.ceil(t_s * fps - 1e-9) for t_s in walk.kidnaps_s]
    for first, end in zip(firsts, [*firsts[1:], len(walk.hits)]):
        window = [(int(i), row) for i, row in zip(idx, rows) if first <= i < end]
        if not window:
            continue
        k = first_view([i for i, _ in window], usable, shows_side)
        view = None if k is None else window[k][1][0]
        valid = next((row for _, row in window if row[1]), None)
        right = next((row for _, row in window if row[1] and row[2] <= WRONG_M), None)
        horizon = window[-1][1][0]
        event = {"event_s": window[0][1][0], "recovered": right is not None,
                 "wrong": valid is not None and bool(valid[2] > WRONG_M)}
        if right is None:
            event["recovery_s"] = None if view is None else max(horizon - view, 0.0)
        else:
            event["recovery_s"] = 0.0 if view is None or right[0] < view else right[0] - view
        out.append(event)
    return out


def summarise(rows: list[tuple[float, bool, float]]) -> dict[str, Any]:
    valid_err = [e for _, v, e in rows if v]
    wrong = [(t, e) for t, v, e in rows if v and e > WRONG_M]
    return {"n": len(rows), "valid": len(valid_err), "valid_err_sum_m": float(sum(valid_err)),
            "valid_wrong": len(wrong), "first_wrong_s": wrong[0][0] if wrong else None,
            "max_wrong_m": max(e for _, e in wrong) if wrong else None}


def combine(runs: list[dict[str, Any]]) -> dict[str, Any]:
    n, valid = sum(r["n"] for r in runs), sum(r["valid"] for r in runs)
    wrong_runs = [{k: r[k] for k in ("seed", "timing", "valid_wrong", "first_wrong_s", "max_wrong_m")}
                  for r in runs if r["valid_wrong"]]
    timings = dict.fromkeys(r["timing"] for r in runs)
    by_timing = {}
    for timing in timings:
        of = [r for r in runs if r["timing"] == timing]
        frames = sum(r["n"] for r in of)
        by_timing[timing] = {"n": frames, "valid_fraction": sum(r["valid"] for r in of) / frames if frames else None,
                             "valid_wrong": sum(r["valid_wrong"] for r in of)}
    report = {"runs": len(runs), "n": n, "valid_fraction": valid / n if n else None,
              "valid_mean_err_m": sum(r["valid_err_sum_m"] for r in runs) / valid if valid else None,
              "valid_wrong": sum(r["valid_wrong"] for r in runs), "valid_wrong_runs": wrong_runs,
              "by_timing": by_timing}
    events = [{"seed": r["seed"], "timing": r["timing"], **e} for r in runs for e in r.get("recoveries", [])]
    if events:
        times = [e["recovery_s"] for e in events if e["recovery_s"] is not None]
        slowest = max((e for e in events if e["recovery_s"] is not None), key=lambda e: e["recovery_s"], default=None)
        report.update(events=len(events), recovery_s_mean=float(np.mean(times)) if times else None,
                      recovery_s_max=None if slowest is None else slowest["recovery_s"], slowest_recovery=slowest,
                      recovery_s_p90=float(np.percentile(times, 90)) if times else None,
                      events_unrecovered=sum(not e["recovered"] for e in events),
                      events_without_view=sum(e["recovery_s"] is None for e in events),
                      recovery_wrong=sum(e["wrong"] for e in events))
    return report


def _num(value: float | None) -> float:
    return math.nan if value is None else value


def run(args: argparse.Namespace) -> int:
    names = [n.strip() for n in args.scenario.split(",") if n.strip()]
    seeds = parse_seeds(args.seeds)
    timings = [t.strip() for t in args.timings.split(",") if t.strip()]
    unknown = [t for t in timings if t not in TIMINGS]
    if unknown or not timings:
        raise UsageError(f"--timings {args.timings!r}: known timings are {', '.join(TIMINGS)}")
    if args.jobs < 1:
        raise UsageError(f"--jobs {args.jobs}: at least 1")
    modes = ["vision_only", "fused"] if args.mode == "both" else [args.mode]
    walks = [sc for seed in seeds
             for sc in build_scenarios(names, argparse.Namespace(**{**vars(args), "seed": seed}))]
    unplugged = sorted({sc.name for sc in walks if sc.mcu_silent_s is not None})
    if unplugged:
        # The bridge starts a new odometry epoch after the cable is back; the sweep's simulated stream has none.
        raise UsageError(f"--scenario: {', '.join(unplugged)} needs the twin MCU of `courtloc bench twin`; "
                         "the sweep does not model a cable out")
    court = walks[0].sim.court
    try:  # the package the infer stage would serve for this court and camera, before any walk is rendered
        bundled_package(court, args.camera or court)
    except ManifestError as exc:
        raise UsageError(f"--camera {args.camera}: {exc}" if args.camera else str(exc)) from None
    if args.camera is not None:  # the walks are seen through the team's camera, as `bench twin` renders them
        walks = [replace(sc, sim=sc.sim.model_copy(update={"camera": args.camera})) for sc in walks]
    with ProcessPoolExecutor(max_workers=min(args.jobs, len(walks))) as pool:
        results = list(pool.map(run_walk, walks, [args.seconds] * len(walks), [timings] * len(walks),
                                [modes] * len(walks), [args.camera] * len(walks)))
    report: dict[str, Any] = {}
    for sc, result in zip(walks, results):
        for mode, runs in result.items():
            report.setdefault(sc.name, {}).setdefault(mode, []).extend(runs)
    report = {name: {mode: combine(runs) for mode, runs in by_mode.items()} for name, by_mode in report.items()}
    # The table goes where the JSON does not: standard output with --json FILE, else standard error.
    table = sys.stdout if args.json is not None and not json_to_stdout(args.json) else sys.stderr
    for name, by_mode in report.items():
        for mode, r in by_mode.items():
            recovery = "" if "events" not in r else (
                f"  recovery mean {_num(r['recovery_s_mean']):.2f} max {_num(r['recovery_s_max']):.2f} s"
                f" ({r['events_unrecovered']} of {r['events']} unrecovered, {r['recovery_wrong']} wrong)")
            print(f"{name:14s} {mode:11s} runs {r['runs']:3d}  frames {r['n']:6d}  valid {r['valid_fraction']:.3f}"
                  f"  valid mean {(r['valid_mean_err_m'] or math.nan) * 100:.1f} cm  valid_wrong {r['valid_wrong']}"
                  f" in {len(r['valid_wrong_runs'])} runs{recovery}", file=table)
    report["run"] = {"court": args.court, "camera": args.camera, "seeds": seeds, "seconds": args.seconds,
                     "timings": timings, "mode": args.mode, "wrong_m": WRONG_M,
                     "command": " ".join(["courtloc", *sys.argv[1:]])}
    if args.json is not None and not json_to_stdout(args.json):
        args.json.parent.mkdir(parents=True, exist_ok=True)
    (args.json or json_output(JSON_STDOUT)).write_text(json.dumps(report, indent=1) + "\n")
    return 0
