"""From a pose to a command for the MCU: SET_RPM when every check passes, HOLD with a reason otherwise.

Never a stale RPM: a pose that is too old (or stamped in the future), marked invalid, missing, or taken outside the shooting
area gives HOLD. The commanded RPM moves towards the table's value at most `slew_rpm_per_s` and stays
inside [min_rpm, max_rpm]. While holding, the slew reference decays towards `idle_rpm` at the same
rate, so the first SET_RPM after a long HOLD ramps up again instead of jumping back to speed.

Time comes in as a parameter: the policy is a pure function of its inputs and its slew state.
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Callable, Optional, Sequence

from courtloc.common.messages import age_is_fresh
from courtloc.services.shooter_bridge.config import AreaConfig, PolicyConfig, ShooterConfig
from courtloc.services.shooter_bridge.protocol import Command, Flag, HoldReason
from courtloc.shot.geometry import Aim, Pose2D, ShooterMount, UnreachableAim, aim
from courtloc.shot.rpm import RpmLookup
from courtloc.world.court import load_court

Area = Callable[[float, float], bool]


def polygon_area(vertices: Sequence[tuple[float, float]]) -> Area:
    """Point-in-polygon by the even-odd rule (the boundary may count either way)."""
    points = [(float(x), float(y)) for x, y in vertices]

    def contains(x: float, y: float) -> bool:
        inside = False
        for (x0, y0), (x1, y1) in zip(points, points[1:] + points[:1]):
            if (y0 > y) != (y1 > y) and x < x0 + (y - y0) * (x1 - x0) / (y1 - y0):
                inside = not inside
        return inside

    return contains


def build_area(config: AreaConfig, court_name: str) -> Area:
    if config.kind == "polygon":
        return polygon_area(config.polygon)
    if config.kind == "rectangle":
        return lambda x, y: config.x_min <= x <= config.x_max and config.y_min <= y <= config.y_max

    court = load_court(court_name)
    return lambda x, y: bool(court.contains(x, y))


@dataclass(frozen=True)
class ShotDecision:
    command: Command  # SET_RPM or HOLD
    rpm: float  # what goes to the MCU: 0 for HOLD
    target_rpm: Optional[float]  # the table's value for this distance, before slew and clamp
    distance_m: Optional[float]  # floor distance from the release point once facing the ring
    bearing_rad: Optional[float]
    flags: Flag
    reason: str  # "" for SET_RPM

    @property
    def valid(self) -> bool:
        return self.command is Command.SET_RPM

    def frame_fields(self) -> tuple[Command, float, int, int]:
        """Arguments for McuLink.send: command, rpm, flags, reason code."""
        return self.command, self.rpm, int(self.flags), int(HoldReason.from_text(self.reason)) if self.reason else 0


def _approach(value: float, target: float, step: float) -> float:
    return min(value + step, target) if target >= value else max(value - step, target)


class ShotPolicy:
    def __init__(self, config: PolicyConfig, ring: Sequence[float], mount: ShooterMount,
                 rpm_for: Callable[[float], RpmLookup], area: Area) -> None:
        self.config = config
        self.ring = tuple(float(v) for v in ring)
        self.mount = mount
        self.rpm_for = rpm_for
        self.area = area
        self._reference = config.idle_rpm  # the slew-limited RPM the MCU was last told (or decays to)
        self._last_now: Optional[float] = None

    def _advance(self, now_s: float) -> float:
        """Slew budget (rpm) since the previous decision; time running backwards gives none."""
        dt = 0.0 if self._last_now is None else max(0.0, now_s - self._last_now)
        self._last_now = now_s if self._last_now is None else max(self._last_now, now_s)
        return self.config.slew_rpm_per_s * dt

    def decide(self, pose: Optional[Pose2D], age_s: float, valid: bool, now_s: float,
               future_tolerance_s: float = 0.0) -> ShotDecision:
        """`age_s` below zero is a pose from the future: stale beyond `future_tolerance_s` (clock offset)."""
        step = self._advance(now_s)
        shot: Optional[Aim] = None
        reason = self._gate(pose, age_s, valid, future_tolerance_s)
        if pose is not None and reason in ("", "outside_area", "stale"):
            try:
                shot = aim(pose, self.ring, self.mount)
            except UnreachableAim:
                reason = reason or "unreachable"
        lookup: Optional[RpmLookup] = None
        if shot is not None:
            lookup = self.rpm_for(shot.horizontal_m)
            reason = reason or self._range_reason(shot, lookup)
        flags = Flag(0)
        if pose is not None and pose.yaw is None:
            flags |= Flag.NO_YAW
        if lookup is not None and lookup.clamped:
            flags |= Flag.BEYOND_TABLE
        distance = shot.horizontal_m if shot else None
        bearing = shot.bearing_rad if shot else None
        target = lookup.rpm if lookup else None
        if reason or target is None:
            self._reference = _approach(self._reference, self.config.idle_rpm, step)
            return ShotDecision(Command.HOLD, 0.0, target, distance, bearing, flags, reason or "invalid")
        limited = min(max(target, self.config.min_rpm), self.config.max_rpm)
        if limited != target:
            flags |= Flag.CLAMPED
        rpm = min(max(_approach(self._reference, limited, step), self.config.min_rpm), self.config.max_rpm)
        if rpm != limited:
            flags |= Flag.SLEWING
        self._reference = rpm
        return ShotDecision(Command.SET_RPM, rpm, target, distance, bearing, flags, "")

    def _gate(self, pose: Optional[Pose2D], age_s: float, valid: bool, future_tolerance_s: float) -> str:
        """The first reason the pose cannot be shot from, or ''."""
        if pose is None:
            return "no_pose"
        if not valid or not (math.isfinite(pose.x) and math.isfinite(pose.y)):
            return "invalid"
        if pose.yaw is not None and not math.isfinite(pose.yaw):
            return "invalid"
        if not math.isfinite(age_s) or not age_is_fresh(age_s, self.config.freshness_s, future_tolerance_s):
            return "stale"
        if not self.area(pose.x, pose.y):
            return "outside_area"
        return ""

    def _range_reason(self, shot: Aim, lookup: RpmLookup) -> str:
        c = self.config
        if shot.horizontal_m < c.min_distance_m or (c.max_distance_m is not None and shot.horizontal_m > c.max_distance_m):
            return "out_of_range"
        if lookup.clamped and c.hold_beyond_table:
            return "out_of_range"
        if c.max_bearing_rad is not None and shot.bearing_rad is not None and abs(shot.bearing_rad) > c.max_bearing_rad:
            return "not_facing"
        return ""


def build_policy(config: ShooterConfig, rpm_for: Callable[[float], RpmLookup],
                 ring: Optional[Sequence[float]] = None) -> ShotPolicy:
    """The policy a bridge runs with `config` (ring centre from the court model unless given)."""
    return ShotPolicy(config.policy, ring if ring is not None else config.target.ring_centre(),
                      config.mount.mount(), rpm_for, build_area(config.policy.area, config.target.court))
