"""A stamp from the future is as stale as one from the past: counted, never valid, the shooter HOLDs."""
from __future__ import annotations

import math
import os
import time
from pathlib import Path
from typing import Iterator

import pytest
from buskit import BusClient, free_port, start_router, start_stage, write_config
from test_shooter_link import FakeMcu  # the pty MCU of the link tests (tests/ is on sys.path)
from test_shooter_policy import _policy

from courtloc.common import codec
from courtloc.common.messages import CLOCK_OFFSET_TOLERANCE_NS, HOST, Header, Pose
from courtloc.common.services_table import TOPICS
from courtloc.services.shooter_bridge.protocol import Command, HoldReason
from courtloc.shot.geometry import Pose2D

RING = (6.0, 0.0, 2.43)


def _header(ahead_s: float, host: str = HOST) -> Header:
    header = Header.now("robot1", 0, "test")
    ahead = int(ahead_s * 1e9)
    return header.model_copy(update={"capture_mono_ns": header.capture_mono_ns + ahead,
                                     "capture_wall_ns": header.capture_wall_ns + ahead, "capture_host": host})


def test_same_host_future_stamp_is_stale() -> None:
    assert _header(0.0).is_fresh(100e6)
    assert not _header(10.0).is_fresh(100e6)
    assert not _header(1000.0).is_fresh(100e6)
    assert not _header(-1.0).is_fresh(100e6)  # and the past, as before


def test_other_host_may_be_ahead_by_the_clock_offset_only() -> None:
    within = CLOCK_OFFSET_TOLERANCE_NS / 1e9 / 2
    beyond = CLOCK_OFFSET_TOLERANCE_NS / 1e9 * 5
    assert _header(within, host="laptop").is_fresh(100e6)
    assert not _header(beyond, host="laptop").is_fresh(100e6)
    assert not _header(within, host=HOST).is_fresh(100e6)  # one clock: nothing is legitimately ahead


def test_policy_holds_on_a_pose_from_the_future() -> None:
    policy = _policy()
    pose = Pose2D(2.0, 0.0, 0.0)
    assert policy.decide(pose, 0.0, True, 0.0).command is Command.SET_RPM
    future = policy.decide(pose, -10.0, True, 0.1)
    assert future.command is Command.HOLD and future.reason == "stale" and future.rpm == 0
    # a pose from another host ahead by less than the clock tolerance is still a pose
    assert policy.decide(pose, -0.01, True, 0.2, future_tolerance_s=0.02).command is Command.SET_RPM


@pytest.fixture
def mcu() -> Iterator[FakeMcu]:
    device = FakeMcu()
    yield device
    device.close()


@pytest.mark.integration
@pytest.mark.skipif(not hasattr(os, "openpty"), reason="needs ptys")
def test_bridge_process_holds_and_counts_a_pose_stamped_in_the_future(tmp_path: Path, mcu: FakeMcu) -> None:
    port = free_port()
    config = write_config(tmp_path / "deploy.toml", port, health_period_s=0.2, body=f"""
[shooter_bridge]
decide_period_s = 0.05
[shooter_bridge.target]
ring = [{RING[0]}, {RING[1]}, {RING[2]}]
[shooter_bridge.policy]
freshness_s = 0.3
slew_rpm_per_s = 100000.0
[shooter_bridge.link]
port = "{mcu.slave_path}"
heartbeat_s = 0.1
""")
    router = start_router(port)
    client = BusClient(port)
    client.subscribe("shooter_bridge/solution")
    client.subscribe("shooter_bridge/health")
    bridge = start_stage("shooter_bridge", config)
    try:
        client.wait_alive("shooter_bridge")
        client.wait_subscribed("infer/pose")
        header = _header(10.0)
        header.valid = True
        pose = Pose(header=header, x=2.0, y=0.0, yaw=0.0, quality=1.0, model_name="t", model_version=1,
                    infer_ms=0.1)
        client.session.put(TOPICS["infer/pose"].key("robot1"), codec.encode(pose))
        solution = client.wait_for("shooter_bridge/solution", lambda s: s.header.seq == 0 and
                                   s.header.stamps[0].stage == "test")
        assert solution.command == "HOLD" and solution.reason == "stale" and not solution.header.valid
        health = client.wait_for("shooter_bridge/health", lambda h: h.stale >= 1)
        assert health.detail.get("hold.stale", 0) >= 1
        # the MCU never heard an RPM for it
        frame = mcu.next_frame(lambda f: f.command is not Command.HEARTBEAT)
        assert frame.command is Command.HOLD
        deadline = time.monotonic() + 1.0
        while time.monotonic() < deadline:
            try:
                frame = mcu.next_frame(lambda f: f.command is not Command.HEARTBEAT, timeout=0.2)
            except AssertionError:
                continue
            assert frame.command is Command.HOLD and frame.reason in (int(HoldReason.STALE), int(HoldReason.NO_POSE))
    finally:
        client.close()
        bridge.stop()
        router.stop()


@pytest.mark.integration
def test_infer_process_never_makes_a_valid_pose_from_future_edges(tmp_path: Path) -> None:
    """Edges stamped +1000 s: an invalid pose (stale_input), and the next real frame is still tracked."""
    from infer_models import TwinFrames

    truth = (2.0, -1.5, 0.4)
    frames = TwinFrames([truth])
    port = free_port()
    router = start_router(port)
    # The robot starts where the frames show it (a configured start: the evidence acquisition needs).
    config = write_config(tmp_path / "deploy.toml", port, f'[infer]\nstore = "{tmp_path / "store"}"\n'
                          f'[infer.start]\nx = {truth[0]}\ny = {truth[1]}\nyaw_deg = {math.degrees(truth[2])}\n',
                          health_period_s=0.2)
    client = BusClient(port)
    client.subscribe("infer/pose")
    client.subscribe("infer/health")
    stage = start_stage("infer", config)
    try:
        stage.wait_line("infer running for robot", timeout=60)
        client.wait_subscribed("preprocess/edges")

        def pose_of(seq: int, ahead_s: float = 0.0) -> Pose:
            edges = frames.edges(0, seq)
            if ahead_s:
                ahead = int(ahead_s * 1e9)
                edges.header = edges.header.model_copy(update={
                    "capture_mono_ns": edges.header.capture_mono_ns + ahead,
                    "capture_wall_ns": edges.header.capture_wall_ns + ahead})
            client.put_raw("preprocess/edges", codec.encode(edges))
            return client.wait_for("infer/pose", lambda p: p.header.seq == seq, timeout=20)

        seq = 1
        while not pose_of(seq).header.valid:  # acquisition agrees over a few frames (docs/localizer.md)
            seq += 1
            assert seq < 10, "no valid pose from the configured start"
        future = pose_of(seq + 1, ahead_s=1000.0)
        assert not future.header.valid and future.reason == "stale_input"
        after = pose_of(seq + 2)
        assert after.header.valid and abs(after.x - truth[0]) < 0.5 and abs(after.y - truth[1]) < 0.5
        assert client.wait_for("infer/health", lambda h: h.stale >= 1).stale >= 1
    finally:
        client.close()
        stage.stop()
        router.stop()
