"""Odometry fusion on the twin: vision blackout while driving, and normal driving, with and without fusion.

`courtloc bench fusion --scenario blackout|normal`: the robot drives a loop at `--speed` (1.5 m/s);
twin frames at 30 Hz go through the robot's preprocess and the localizer package's tracker, exactly
as the infer stage runs them (`fused_track.fused_track`); the twin's MCU (`sim/odometry.py`: wheel
scale error, slip bursts, gyro bias, noise, clock offset and drift, latency) feeds the fusion the
messages that have arrived by each frame's time. In `blackout` the frames carry no hits for
`--blackout-s` (2 s) from `--blackout-at` (lens covered, a wall in view). Both runs (vision only /
fused) use the same frames, side by side.

Keys: `error_growth_m` = worst position error of the reported pose during the blackout minus the mean
error in the second before it; `valid_fraction_blackout`; `max_valid_error_m` (worst error of a pose
reported VALID, the number that must stay small); mean / p95 error over frames with vision;
`track_ms_median` (wall time of one tracked frame, hits in, pose out; odometry offered before it not
counted: compare the two runs of one invocation, not across machines).
"""
from __future__ import annotations

import argparse
import json
import math
import time
from pathlib import Path

import numpy as np

from courtloc.cliargs import JSON_STDOUT, add_json_argument, json_output
from courtloc.lab.eval import default_model_path
from courtloc.localizer import acquire
from courtloc.localizer.fused_track import fused_track
from courtloc.localizer.odometry_fusion import FusionConfig, OdometryFusion
from courtloc.localizer.predictor import load_predictor
from courtloc.sim.edges import scan_hits
from courtloc.sim.odometry import OdometrySimConfig, OdometrySimulator
from courtloc.sim.render import Renderer
from courtloc.sim.trajectory import WaypointTrajectory


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--scenario", choices=("blackout", "normal", "kidnap"), default="blackout")
    parser.add_argument("--kidnap-at", type=float, default=4.0, help="kidnap: seconds into the run")
    parser.add_argument("--package", type=Path, help="localizer package folder (default: the bundled one)")
    parser.add_argument("--speed", type=float, default=1.5, help="driving speed, m/s")
    parser.add_argument("--duration", type=float, default=8.0, help="seconds of driving")
    parser.add_argument("--blackout-at", type=float, default=4.0, help="seconds into the run")
    parser.add_argument("--blackout-s", type=float, default=2.0)
    parser.add_argument("--fps", type=float, default=30.0)
    parser.add_argument("--seed", type=int, default=0)
    add_json_argument(parser, "the result (printed as JSON without it)")


def loop_trajectory(speed: float):  # noqa: ANN201
    """A loop through the court's half with lines in view most of the time, turning while driving."""

    return WaypointTrajectory([(0.5, -2.0, 0.2), (4.5, -1.0, 0.9), (4.0, 2.5, 2.4), (0.5, 2.0, -2.6)],
                              speed=speed, yaw_rate=1.0)


def run_scenario(scenario: str, package: Path | None = None, speed: float = 1.5, duration: float = 8.0,
                 blackout_at: float = 4.0, blackout_s: float = 2.0, fps: float = 30.0, seed: int = 0,
                 fusion_config=None, detail: bool = False, kidnap_at: float = 4.0,
                 kidnap: tuple[float, float, float] = (0.8, -0.4, 0.3)) -> dict:  # noqa: ANN001
    """Both runs' summaries; `detail` adds every frame's (t, blind, valid, error) under `rows`."""

    predictor = load_predictor(package or default_model_path())
    renderer = Renderer(predictor.package.court, predictor.package.camera)
    trajectory = loop_trajectory(speed)
    messages = list(OdometrySimulator(trajectory, OdometrySimConfig(), seed=seed).stream(duration + 0.5))
    times = np.arange(1, int(duration * fps)) / fps
    blind = [(scenario == "blackout" and blackout_at <= t < blackout_at + blackout_s) for t in times]
    frames = []
    def truth_at(t: float) -> tuple[float, float, float]:
        # kidnap: from kidnap_at on the robot stands displaced by `kidnap` (picked up and put down, or a
        # collision that the wheels did not feel); its odometry goes on as if nothing happened.
        x, y, yaw = trajectory.pose_at(t)
        if scenario != "kidnap" or t < kidnap_at:
            return x, y, yaw
        # The rest of the drive moved rigidly: displaced and turned about the kidnap point, so the wheels
        # and the gyro still measure exactly the motion that happens.
        x0, y0, _ = trajectory.pose_at(kidnap_at)
        c, s = math.cos(kidnap[2]), math.sin(kidnap[2])
        dx, dy = x - x0, y - y0
        return x0 + kidnap[0] + c * dx - s * dy, y0 + kidnap[1] + s * dx + c * dy, yaw + kidnap[2]

    for t, dark in zip(times, blind):
        hits = scan_hits(renderer.render(truth_at(float(t))))
        frames.append(hits[:0] if dark else hits)
    runs = {}
    for name, fusion in (("vision_only", None),
                         ("fused", OdometryFusion(fusion_config or FusionConfig(enabled=True)))):
        # The run starts at a known pose, as a team configures `[infer] start`: the evidence acquisition needs.
        start = acquire.Prior(source="start", pose=np.asarray(truth_at(float(times[0])), float), std_m=0.3,
                              yaw_std_rad=0.2)
        state, delivered, rows, cost_ms = acquire.Acquiring(prior=start), 0, [], []
        for t, hits, dark in zip(times, frames, blind):
            # Odometry that reached the host by the time this frame is processed (one frame period later).
            now = float(t) + 1.0 / fps
            while fusion is not None and delivered < len(messages) and messages[delivered].at_s <= now:
                fusion.offer(messages[delivered].message, now)
                delivered += 1
            start = time.perf_counter()
            pred, state, _ = fused_track(predictor, fusion, hits, 640, 480, state, float(t))
            cost_ms.append((time.perf_counter() - start) * 1e3)
            truth = truth_at(float(t))
            rows.append((float(t), dark, bool(pred.valid), math.hypot(pred.x - truth[0], pred.y - truth[1])))
        runs[name] = _summary(rows, blackout_at, scenario, kidnap_at)
        runs[name]["track_ms_median"] = float(np.median(cost_ms))  # per frame, hits in, pose out
        if detail:
            runs[name]["rows"] = rows
        if fusion is not None:
            runs[name]["fusion"] = fusion.health()
    return {"scenario": scenario, "speed_m_s": speed, "duration_s": duration, "fps": fps,
            "blackout": [blackout_at, blackout_at + blackout_s] if scenario == "blackout" else None,
            "kidnap": {"at_s": kidnap_at, "displacement": list(kidnap)} if scenario == "kidnap" else None,
            "package": str(package or "bundled"), **runs}


def _summary(rows: list[tuple[float, bool, bool, float]], blackout_at: float, scenario: str,
             kidnap_at: float = math.inf) -> dict:
    seen = np.array([e for t, dark, valid, e in rows if not dark and valid])
    valid_err = [e for _, _, valid, e in rows if valid]
    out = {"frames": len(rows), "valid_fraction": float(np.mean([v for _, _, v, _ in rows])),
           "mean_err_m_with_vision": float(seen.mean()) if seen.size else math.nan,
           "p95_err_m_with_vision": float(np.percentile(seen, 95)) if seen.size else math.nan,
           "max_valid_error_m": float(max(valid_err)) if valid_err else math.nan}
    if scenario == "blackout":
        dark = [(e, v) for _, d, v, e in rows if d]
        before = [e for t, d, _, e in rows if not d and blackout_at - 1.0 <= t < blackout_at]
        out["error_growth_m"] = float(max(e for e, _ in dark) - (np.mean(before) if before else 0.0))
        out["valid_fraction_blackout"] = float(np.mean([v for _, v in dark]))
        out["max_valid_error_blackout_m"] = float(max((e for e, v in dark if v), default=0.0))
    if scenario == "kidnap":
        after = [(t, v, e) for t, _, v, e in rows if t >= kidnap_at]
        first_invalid = next((t for t, v, _ in after if not v), math.inf)
        wrong_valid = [t for t, v, e in after if v and e > 0.10]
        # None: never (JSON has no infinity)
        out["kidnap_noticed_after_s"] = first_invalid - kidnap_at if math.isfinite(first_invalid) else None
        out["valid_and_wrong_after_kidnap"] = len(wrong_valid)  # valid poses more than 10 cm off
        recovered = next((t for t, v, e in after if t > first_invalid and v and e <= 0.10), math.inf)
        out["recovered_after_s"] = recovered - kidnap_at if math.isfinite(recovered) else None
    return out


def run(args: argparse.Namespace) -> int:
    result = run_scenario(args.scenario, args.package, args.speed, args.duration, args.blackout_at, args.blackout_s,
                          args.fps, args.seed, kidnap_at=args.kidnap_at)
    text = json.dumps(result, indent=1)
    (args.json or json_output(JSON_STDOUT)).write_text(text + "\n")  # the result is JSON either way
    return 0
