"""Named twin scenarios for `courtloc bench twin`: what the simulated camera shows, and what goes wrong.

A scenario is a `SimSourceConfig` (trajectory, rendering, kidnaps, outages) plus the events the bench
causes itself (an infer-process kill). Times scale with the run length so a short development run and a
long one exercise the same things. Everything is deterministic for a seed. A fusion scenario (`fusion`)
is run by default twice, vision only and with the twin's MCU odometry fused (`bench twin --fusion`).
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Callable, Optional

from courtloc.sim.render import OccluderOptions, RenderOptions
from courtloc.sim.source import SimSourceConfig

WALK_SPEED_MPS = 1.5
WALK_YAW_RATE_RPS = 1.5
FAST_SPEED_MPS = 2.5
FAST_YAW_RATE_RPS = 3.0
# Indoor arena light: a 10 ms shutter (at 3 rad/s the view turns by ~11 px during it).
FAST_SHUTTER_S = 0.010
# A start pose in the +x half (the side the bundled localizer assumes), facing the far court.
PLUS_X_START = [3.0, -1.0, 2.6]
MINUS_X_START = [-3.0, 1.0, -0.5]
# The fusion scenarios' loop through the +x half with lines in view most of the time, turning while
# driving at up to 1.5 m/s (the loop of `courtloc bench fusion`, sim/fusion_bench.py).
FUSION_LOOP = [[0.5, -2.0, 0.2], [4.5, -1.0, 0.9], [4.0, 2.5, 2.4], [0.5, 2.0, -2.6]]
FUSION_YAW_RATE_RPS = 1.0
BLACKOUT_S = 2.0
# Where on the loop the blackout starts and the kidnap happens: on its second leg, driving at 1.5 m/s and
# turning, with the track settled. (Later, at the loop's corner near (0.5, 2.0) about 7.4 s in, a vision
# fix ~0.2 m off makes the fused tracker suspect a kidnap: the `drive` scenario shows that on its own.)
LOOP_EVENT_S = 3.0


@dataclass(frozen=True)
class Scenario:
    name: str
    description: str
    sim: SimSourceConfig
    infer_kill_at_s: Optional[float] = None  # sim time at which the bench kills the infer process (SIGKILL)
    fusion: bool = False  # run vision only and fused by default
    blackout_s: Optional[tuple[float, float]] = None  # [start, end) of the vision blackout the metrics look at
    mcu_silent_s: Optional[tuple[float, float]] = None  # [start, end) in which the twin MCU's cable is out (fused runs)

    @property
    def start_pose(self) -> tuple[float, float, float]:
        if self.sim.trajectory == "waypoints" and len(self.sim.waypoints[0]) == 3:
            start = self.sim.waypoints[0]
        else:
            start = self.sim.start or [0.0, 0.0, 0.0]
        return float(start[0]), float(start[1]), float(start[2])


def randomised_light() -> RenderOptions:
    """Randomised exposure, light gradients, noise and blur, floor texture; no occluders."""
    return RenderOptions.randomised().model_copy(update={"occluders": OccluderOptions(max_count=0)})


def occluded() -> RenderOptions:
    """Randomised light plus up to four robots, people and balls, some close enough to hide half the view."""
    return RenderOptions.randomised().model_copy(
        update={"occluders": OccluderOptions(max_count=4, distance_m=(0.6, 5.0))})


def _walk(court: str, seed: int, render: RenderOptions, **extra) -> SimSourceConfig:
    fields = {"court": court, "trajectory": "random_walk", "seed": seed, "speed_mps": WALK_SPEED_MPS,
              "yaw_rate_rps": WALK_YAW_RATE_RPS, "start": PLUS_X_START, "render": render, **extra}
    return SimSourceConfig(**fields)


def _clean(court: str, seconds: float, seed: int) -> Scenario:
    return Scenario("clean", "random walk at 1.5 m/s, clean frames", _walk(court, seed, RenderOptions()))


def _randomised(court: str, seconds: float, seed: int) -> Scenario:
    return Scenario("randomised", "random walk at 1.5 m/s; randomised exposure, light gradients, noise, blur",
                    _walk(court, seed, randomised_light()))


def _occluded(court: str, seconds: float, seed: int) -> Scenario:
    return Scenario("occluded", "as randomised, plus up to 4 robots/people/balls in view from 0.6 m (partial views)",
                    _walk(court, seed, occluded()))


def _fast(court: str, seconds: float, seed: int) -> Scenario:
    render = randomised_light().model_copy(update={"motion_blur_s": FAST_SHUTTER_S})
    return Scenario("fast", "random walk at 2.5 m/s and 3 rad/s, randomised light, 10 ms motion blur",
                    _walk(court, seed, render, speed_mps=FAST_SPEED_MPS, yaw_rate_rps=FAST_YAW_RATE_RPS))


def _kidnap(court: str, seconds: float, seed: int) -> Scenario:
    times = [round(seconds / 3, 3), round(2 * seconds / 3, 3)]
    return Scenario("kidnap", f"as randomised; teleported within its half at {times} s",
                    _walk(court, seed, randomised_light(), kidnaps_s=times))


def _minus_x_start(court: str, seconds: float, seed: int) -> Scenario:
    return Scenario("minus_x_start", f"as randomised, starting in the -x half at {MINUS_X_START}",
                    _walk(court, seed, randomised_light(), start=MINUS_X_START))


def _outage(court: str, seconds: float, seed: int) -> Scenario:
    start = round(0.3 * seconds, 3)
    end = round(start + max(2.0, 0.15 * seconds), 3)
    kill = round(0.7 * seconds, 3)
    return Scenario("outage", f"as randomised; camera dark over [{start}, {end}) s, infer process killed at {kill} s",
                    _walk(court, seed, randomised_light(), outages_s=[(start, end)]), infer_kill_at_s=kill)


def _loop(court: str, seed: int, render: RenderOptions | None = None, **extra) -> SimSourceConfig:
    return SimSourceConfig(court=court, trajectory="waypoints", waypoints=FUSION_LOOP, speed_mps=WALK_SPEED_MPS,
                           yaw_rate_rps=FUSION_YAW_RATE_RPS, seed=seed, render=render or randomised_light(), **extra)


def _drive(court: str, seconds: float, seed: int) -> Scenario:
    return Scenario("drive", "loop through the +x half at 1.5 m/s, randomised light (normal driving)",
                    _loop(court, seed), fusion=True)


def _drive_clean(court: str, seconds: float, seed: int) -> Scenario:
    return Scenario("drive_clean", "as drive, clean frames", _loop(court, seed, render=RenderOptions()), fusion=True)


def _blackout(court: str, seconds: float, seed: int) -> Scenario:
    # 2 s of frames without lines (a wall or a robot right in front of the lens) while driving; earlier
    # and shorter in a run too short for it.
    start = round(min(LOOP_EVENT_S, 0.4 * seconds), 3)
    end = round(start + min(BLACKOUT_S, 0.3 * seconds), 3)
    return Scenario("blackout", f"as drive; frames without lines (lens blocked) over [{start}, {end}) s",
                    _loop(court, seed, outages_s=[(start, end)], outage="blocked"), fusion=True,
                    blackout_s=(start, end))


def _drive_kidnap(court: str, seconds: float, seed: int) -> Scenario:
    at = round(min(LOOP_EVENT_S + 1.0, seconds / 3), 3)
    return Scenario("drive_kidnap", f"as drive; teleported within its half at {at} s (the wheels feel nothing), "
                    "random walk from there", _loop(court, seed, kidnaps_s=[at]), fusion=True)


def _mcu_loss(court: str, seconds: float, seed: int) -> Scenario:
    # The middle third of an occluded walk without the MCU (a cable shaken loose): fused, the stage is what it is
    # vision only meanwhile, and fuses again once odometry is back.
    start, end = round(seconds / 3, 3), round(2 * seconds / 3, 3)
    return Scenario("mcu_loss", f"as occluded; the MCU's cable out over [{start}, {end}) s (no odometry, no status)",
                    _walk(court, seed, occluded()), fusion=True, mcu_silent_s=(start, end))


SCENARIOS: dict[str, Callable[[str, float, int], Scenario]] = {
    "clean": _clean,
    "randomised": _randomised,
    "occluded": _occluded,
    "fast": _fast,
    "kidnap": _kidnap,
    "minus_x_start": _minus_x_start,
    "outage": _outage,
    "drive": _drive,
    "drive_clean": _drive_clean,
    "blackout": _blackout,
    "drive_kidnap": _drive_kidnap,
    "mcu_loss": _mcu_loss,
}


def scenario(name: str, court: str, seconds: float, seed: int = 1) -> Scenario:
    if name not in SCENARIOS:
        raise ValueError(f"unknown scenario {name!r}; known: {', '.join(SCENARIOS)}")
    return SCENARIOS[name](court, seconds, seed)
