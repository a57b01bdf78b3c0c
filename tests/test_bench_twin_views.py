"""Usable views (courtloc/bench_twin_views.py): the frames whose lines alone place the twin robot, judged
on rendered robocon2025 frames with the bundled package."""
from __future__ import annotations

import numpy as np
import pytest

from courtloc.bench_twin_metrics import Event, TruthSample
from courtloc.bench_twin_views import NEAR_M, view_judge, with_views

POSE = (3.0, 1.0, 0.0)  # facing +x from the +x half: the key's lines, crossing


@pytest.fixture(scope="module")
def judge_and_view():  # noqa: ANN201
    from courtloc.sim.edges import scan_hits
    from courtloc.sim.render import Renderer
    from courtloc.world.camera import load_camera
    from courtloc.world.court import load_court

    judge = view_judge("robocon2025", "robocon2025")
    assert judge is not None
    return judge, scan_hits(Renderer(load_court("robocon2025"), load_camera("robocon2025")).render(POSE))


def truth(k: int, dx: float = 0.0) -> TruthSample:
    return TruthSample(seq=k, capture_ns=k * 33_000_000, x=POSE[0] + dx, y=POSE[1], yaw=POSE[2])


def test_a_view_is_usable_only_where_its_lines_place_the_robot(judge_and_view) -> None:
    judge, hits = judge_and_view
    assert len(hits) >= 40
    assert judge.usable(hits, truth(0))
    # The same lines with the truth elsewhere: the fit slides back to where they place the robot.
    assert not judge.usable(hits, truth(0, dx=2 * NEAR_M))
    assert not judge.usable(np.zeros((0, 4), np.int16), truth(0))
    # Too few of them to pin the pose.
    assert not judge.usable(hits[:4], truth(0))


def test_a_view_of_lines_along_one_direction_is_not_usable(judge_and_view) -> None:
    """The robocon2025 twin's second kidnap lands facing lines that run one way (45 hits, all inliers): the
    fit at the truth cannot pin the position along them, so no localizer could place the robot from it."""
    from courtloc.sim.edges import scan_hits
    from courtloc.sim.render import Renderer
    from courtloc.world.camera import load_camera
    from courtloc.world.court import load_court

    judge, _ = judge_and_view
    pose = (1.0, -0.7, 1.85)
    hits = scan_hits(Renderer(load_court("robocon2025"), load_camera("robocon2025")).render(pose))
    assert len(hits) >= 40
    assert not judge.usable(hits, TruthSample(seq=0, capture_ns=0, x=pose[0], y=pose[1], yaw=pose[2]))


def test_each_event_gets_its_first_usable_view_before_the_next_event(judge_and_view) -> None:
    judge, hits = judge_and_view
    blind = np.zeros((0, 4), np.int16)
    frames = [blind, blind, hits, hits, blind, blind, blind, hits]
    truths = [truth(k) for k in range(len(frames))]
    by_capture = {t.capture_ns: f for t, f in zip(truths, frames)}
    events = [Event("start", truths[0].capture_ns), Event("kidnap", truths[4].capture_ns),
              Event("outage", truths[5].capture_ns)]
    start, kidnap, outage = with_views(events, truths, by_capture, judge, end_ns=truths[-1].capture_ns + 1)
    assert start.view_ns == truths[2].capture_ns
    assert kidnap.view_ns is None  # its only frame (before the outage's) shows nothing
    assert outage.view_ns == truths[7].capture_ns


def test_without_a_judge_events_are_timed_from_their_own_first_frame() -> None:
    events = [Event("start", 5), Event("kidnap", 50)]
    assert [e.usable_from() for e in with_views(events, [], {}, None, end_ns=100)] == [5, 50]
    assert view_judge("robocon2025", "seed-gazebo") is None  # no package ships for that pair

