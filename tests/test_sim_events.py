"""What the twin does to the robot and its camera for the bench scenarios: kidnaps, outages, motion blur,
a chosen start pose. All deterministic for a seed."""
from __future__ import annotations

import math

import numpy as np
import pytest
from pydantic import ValidationError

from courtloc.sim.render import Renderer, RenderOptions
from courtloc.sim.source import SimSource, SimSourceConfig
from courtloc.sim.trajectory import KidnapTrajectory, RandomWalkTrajectory
from courtloc.world.camera import load_camera
from courtloc.world.court import load_court


def test_kidnap_teleports_within_the_half_and_is_reproducible():
    court = load_court("robocon2025")

    def make() -> KidnapTrajectory:
        first = RandomWalkTrajectory(court, 1.5, 1.5, seed=4, start=(3.0, -1.0, 0.0))
        return KidnapTrajectory(first, court, [2.0, 4.0], 1.5, 1.5, seed=4)

    a, b = make(), make()
    dt = 1 / 30
    for t in (2.0, 4.0):
        before, after = a.pose_at(t - dt), a.pose_at(t)
        assert math.hypot(after[0] - before[0], after[1] - before[1]) >= 1.5 - 1.5 * dt  # a jump, not a step
        assert np.sign(after[0]) == np.sign(before[0]) and abs(after[0]) >= 1.0
        assert court.contains(after[0], after[1])
        # Between kidnaps the robot drives: no other jumps.
        steps = [a.pose_at(t + k * dt) for k in range(30)]
        assert max(math.hypot(q[0] - p[0], q[1] - p[1]) for p, q in zip(steps, steps[1:])) <= 1.5 * dt + 1e-9
    assert [a.pose_at(t) for t in np.linspace(0, 6, 50)] == [b.pose_at(t) for t in np.linspace(0, 6, 50)]
    with pytest.raises(ValueError, match="increasing"):
        KidnapTrajectory(RandomWalkTrajectory(court, 1.5, 1.5, seed=1), court, [3.0, 2.0], 1.5, 1.5, seed=1)


@pytest.mark.parametrize("kind", ["dark", "blocked"])
def test_source_outage_frames_show_nothing_while_the_robot_moves_on(kind: str):
    cfg = SimSourceConfig(court="seed-gazebo", trajectory="random_walk", seed=2, fps=10, start=[2.0, 1.0, 0.5],
                          outages_s=[(0.2, 0.4)], outage=kind)
    from courtloc.sim.edges import scan_hits

    with SimSource(cfg) as source:
        shots = [source.read() for _ in range(6)]
    assert shots[0][1] == pytest.approx((2.0, 1.0, 0.5))
    for k, (frame, pose) in enumerate(shots):
        hits = scan_hits(frame)
        if k in (2, 3):
            assert len(hits) == 0  # no line edge to find
            assert (frame.max() < 60) == (kind == "dark")
        else:
            assert len(hits) > 20
    assert shots[3][1] != shots[2][1]  # the truth keeps moving through the outage


def test_source_rejects_a_bad_start_or_outage():
    with pytest.raises(ValidationError, match="start"):
        SimSourceConfig(start=[1.0, 2.0])
    with pytest.raises(ValidationError, match="outage"):
        SimSourceConfig(outages_s=[(3.0, 2.0)])
    with pytest.raises(ValueError, match="start .* outside"):
        SimSource(SimSourceConfig(court="robocon2025", trajectory="random_walk", start=[9.0, 0.0, 0.0])).open()
    with pytest.raises(ValueError, match="random walk only"):
        SimSource(SimSourceConfig(start=[1.0, 0.0, 0.0])).open()


def test_motion_blur_smears_a_turning_view_and_leaves_a_still_one_alone():
    court = load_court("seed-gazebo")
    renderer = Renderer(court, load_camera("seed-gazebo"))
    pose = (2.0, 0.5, 0.3)
    blur = RenderOptions(motion_blur_s=0.01, motion_blur_samples=4)
    sharp = renderer.render(pose, RenderOptions())
    assert np.array_equal(renderer.render(pose, blur), sharp)  # no shutter pose: nothing to blur
    assert np.array_equal(renderer.render(pose, blur, shutter_open_pose=pose), sharp)
    turned = (2.0, 0.5, 0.33)  # 3 rad/s for 10 ms
    smeared = renderer.render(pose, blur, shutter_open_pose=turned)
    # The mean of the sharp views along the turn (up to rounding), and not any one of them.
    views = [renderer.render((2.0, 0.5, yaw), RenderOptions()).astype(float) for yaw in np.linspace(0.33, 0.3, 4)]
    assert np.abs(smeared - np.mean(views, axis=0)).max() <= 1.0
    assert not np.array_equal(smeared, sharp) and not np.array_equal(smeared, views[0].astype(np.uint8))
    # Sharp line edges get softer: fewer pixels jump by more than 100 grey levels across a column.
    def hard_edges(img: np.ndarray) -> int:
        grey = img.mean(axis=2)
        return int(np.count_nonzero(np.abs(np.diff(grey, axis=1)) > 100))
    assert hard_edges(smeared) < hard_edges(sharp)
