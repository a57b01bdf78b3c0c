"""Named twin scenarios for `courtloc bench twin`: what the simulated camera shows, and what goes wrong.

A scenario is a `SimSourceConfig` (trajectory, rendering, kidnaps, outages) plus the events the bench
causes itself (an infer-process kill). Times scale with the run length so a short development run and a
long one exercise the same things. Everything is deterministic for a seed.
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


@dataclass(frozen=True)
class Scenario:
    name: str
    description: str
    sim: SimSourceConfig
    infer_kill_at_s: Optional[float] = None  # sim time at which the bench kills the infer process (SIGKILL)

    @property
    def start_pose(self) -> tuple[float, float, float]:
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


SCENARIOS: dict[str, Callable[[str, float, int], Scenario]] = {
    "clean": _clean,
    "randomised": _randomised,
    "occluded": _occluded,
    "fast": _fast,
    "kidnap": _kidnap,
    "minus_x_start": _minus_x_start,
    "outage": _outage,
}


def scenario(name: str, court: str, seconds: float, seed: int = 1) -> Scenario:
    if name not in SCENARIOS:
        raise ValueError(f"unknown scenario {name!r}; known: {', '.join(SCENARIOS)}")
    return SCENARIOS[name](court, seconds, seed)
