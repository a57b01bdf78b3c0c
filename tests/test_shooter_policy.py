"""ShotPolicy: HOLD with a reason whenever the pose cannot be trusted; slew-limited, clamped RPM otherwise."""
from __future__ import annotations

import math

import pytest

from courtloc.services.shooter_bridge.config import AreaConfig, PolicyConfig, ShooterConfig
from courtloc.services.shooter_bridge.policy import ShotPolicy, build_area, build_policy, polygon_area
from courtloc.services.shooter_bridge.protocol import Command, Flag, HoldReason
from courtloc.shot.geometry import Pose2D, ShooterMount
from courtloc.shot.rpm import RpmLookup, RpmTable

RING = (6.0, 0.0, 2.43)
TABLE = RpmTable([1.0, 7.0], [1000.0, 4000.0])  # linear: 500 rpm per metre


def _policy(**overrides: object) -> ShotPolicy:
    settings = dict(freshness_s=0.2, min_rpm=500.0, max_rpm=3000.0, idle_rpm=0.0, slew_rpm_per_s=1000.0,
                    area=AreaConfig(kind="rectangle", x_min=-1.0, x_max=6.0, y_min=-4.0, y_max=4.0))
    settings.update(overrides)
    return ShotPolicy(PolicyConfig(**settings), RING, ShooterMount(), TABLE.lookup, build_area(settings["area"], ""))


def test_slew_from_idle_then_steady() -> None:
    policy = _policy()
    pose = Pose2D(2.0, 0.0, 0.0)  # 4 m -> 2500 rpm
    rpms = [policy.decide(pose, 0.05, True, t) for t in (10.0, 10.5, 11.0, 11.5, 12.0, 12.5)]
    assert [d.command for d in rpms] == [Command.SET_RPM] * 6
    # from idle 0, clamped up to min 500, then +500 per half second, then the target 2500
    assert [d.rpm for d in rpms] == pytest.approx([500, 1000, 1500, 2000, 2500, 2500])
    assert all(d.target_rpm == pytest.approx(2500) for d in rpms)
    assert Flag.SLEWING in rpms[0].flags and Flag.SLEWING not in rpms[-1].flags
    assert rpms[-1].distance_m == pytest.approx(4.0) and rpms[-1].bearing_rad == pytest.approx(0.0)
    assert rpms[-1].valid and rpms[-1].reason == ""


def test_clamped_to_max_and_flagged() -> None:
    policy = _policy(slew_rpm_per_s=1e6)
    decision = policy.decide(Pose2D(-0.5, 0.0, None), 0.0, True, 0.0)  # 6.5 m -> 3750 rpm
    decision = policy.decide(Pose2D(-0.5, 0.0, None), 0.0, True, 1.0)
    assert decision.rpm == pytest.approx(3000)
    assert decision.target_rpm == pytest.approx(3750)
    assert Flag.CLAMPED in decision.flags and Flag.NO_YAW in decision.flags


@pytest.mark.parametrize("pose, age, valid, reason", [
    (Pose2D(2.0, 0.0, 0.0), 0.25, True, "stale"),
    (Pose2D(2.0, 0.0, 0.0), math.inf, True, "stale"),
    (Pose2D(2.0, 0.0, 0.0), 0.05, False, "invalid"),
    (Pose2D(math.nan, 0.0, 0.0), 0.05, True, "invalid"),
    (Pose2D(2.0, 0.0, math.inf), 0.05, True, "invalid"),
    (Pose2D(-2.0, 0.0, 0.0), 0.05, True, "outside_area"),
    (None, 0.0, True, "no_pose"),
])
def test_hold_never_carries_an_rpm(pose: Pose2D | None, age: float, valid: bool, reason: str) -> None:
    policy = _policy()
    for t in range(5):  # spin up first, so a stale RPM would be there to leak
        policy.decide(Pose2D(2.0, 0.0, 0.0), 0.0, True, float(t))
    decision = policy.decide(pose, age, valid, 5.0)
    assert decision.command is Command.HOLD
    assert decision.rpm == 0.0
    assert decision.reason == reason and not decision.valid
    command, rpm, _, code = decision.frame_fields()
    assert (command, rpm, code) == (Command.HOLD, 0.0, int(HoldReason[reason.upper()]))


def test_distance_and_bearing_limits() -> None:
    policy = _policy(min_distance_m=2.0, max_distance_m=5.0, max_bearing_rad=0.1)
    assert policy.decide(Pose2D(5.0, 0.0, 0.0), 0.0, True, 0.0).reason == "out_of_range"  # 1 m
    assert policy.decide(Pose2D(0.0, 0.0, 0.0), 0.0, True, 0.0).reason == "out_of_range"  # 6 m
    turned = policy.decide(Pose2D(2.0, 0.0, 0.5), 0.0, True, 0.0)
    assert turned.reason == "not_facing" and turned.bearing_rad == pytest.approx(-0.5)
    assert policy.decide(Pose2D(2.0, 0.0, None), 0.0, True, 0.0).valid  # unknown yaw cannot be judged


def test_beyond_table_clamps_or_holds() -> None:
    far = Pose2D(-0.5, 0.0, 0.0)
    table = RpmTable([2.0, 5.0], [2000.0, 2600.0])
    relaxed = ShotPolicy(PolicyConfig(area=AreaConfig(kind="rectangle")), RING, ShooterMount(), table.lookup,
                         lambda x, y: True)
    decision = relaxed.decide(far, 0.0, True, 0.0)
    assert decision.valid and decision.target_rpm == pytest.approx(2600) and Flag.BEYOND_TABLE in decision.flags
    strict = ShotPolicy(PolicyConfig(hold_beyond_table=True), RING, ShooterMount(), table.lookup, lambda x, y: True)
    assert strict.decide(far, 0.0, True, 0.0).reason == "out_of_range"


def test_reference_decays_while_holding_so_resume_ramps() -> None:
    policy = _policy()
    pose = Pose2D(2.0, 0.0, 0.0)
    for t in (0.0, 1.0, 2.0, 3.0):
        last = policy.decide(pose, 0.0, True, t)
    assert last.rpm == pytest.approx(2500)
    assert policy.decide(pose, 1.0, True, 4.0).reason == "stale"  # one second of HOLD: reference 1500
    resumed = policy.decide(pose, 0.0, True, 4.5)
    assert resumed.rpm == pytest.approx(2000)  # 1500 + 0.5 s * 1000 rpm/s


def test_time_going_backwards_does_not_allow_a_jump() -> None:
    policy = _policy()
    pose = Pose2D(2.0, 0.0, 0.0)
    policy.decide(pose, 0.0, True, 5.0)
    assert policy.decide(pose, 0.0, True, 1.0).rpm == pytest.approx(500)
    assert policy.decide(pose, 0.0, True, 5.5).rpm == pytest.approx(1000)


def test_polygon_and_court_areas() -> None:
    triangle = polygon_area([(0.0, 0.0), (4.0, 0.0), (0.0, 4.0)])
    assert triangle(1.0, 1.0) and not triangle(3.0, 3.0) and not triangle(-0.1, 1.0)
    court = build_area(AreaConfig(), "robocon2025")
    assert court(0.0, 0.0) and court(7.0, 3.5) and not court(9.0, 0.0) and not court(0.0, -5.0)


def test_build_policy_from_the_default_config_aims_at_the_positive_ring() -> None:
    lookup = lambda d: RpmLookup(1000.0 + d, False)  # noqa: E731
    policy = build_policy(ShooterConfig(), lookup)
    decision = policy.decide(Pose2D(0.0, 0.0, 0.0), 0.0, True, 0.0)
    assert decision.distance_m == pytest.approx(6.525)  # robocon2025 ring at x = 6.525
    assert decision.bearing_rad == pytest.approx(0.0)
