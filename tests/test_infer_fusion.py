"""The infer stage as its own process with odometry fusion on: odometry from another source (here the test,
as a ROS bridge would) on shooter_bridge/odometry carries the pose through a blind frame, and bad odometry
is counted with its reason."""
from __future__ import annotations

import json
import math
import threading
from pathlib import Path

import pytest
from buskit import BusClient, free_port, start_router, start_stage, write_config
from infer_models import TwinFrames

from courtloc.common import codec
from courtloc.common.messages import Edges, Header, Odometry
from courtloc.common.payloads import hits_to_bytes

pytestmark = pytest.mark.integration

TRUTH = (2.0, -1.5, 0.4)


def _odometry(seq: int, x: float = 0.0) -> Odometry:
    header = Header.now("robot1", seq, "test-odometry")
    header.valid = True
    return Odometry(header=header, source="test", source_seq=seq, source_time_ns=header.capture_mono_ns,
                    received_mono_ns=header.capture_mono_ns, window_s=0.02, wheels_valid=True, gyro_valid=True,
                    odom_x_m=x)


def test_a_blind_frame_is_bridged_by_odometry_with_its_covariance(tmp_path: Path) -> None:
    port = free_port()
    config = write_config(tmp_path / "robot.toml", port, health_period_s=0.2, body=f"""
[infer]
store = "{tmp_path / 'store'}"
[infer.start]
x = {TRUTH[0]}
y = {TRUTH[1]}
yaw_deg = {math.degrees(TRUTH[2])}
[infer.fusion]
enabled = true
""")
    router = start_router(port)
    client = BusClient(port)
    client.subscribe("infer/pose")
    client.subscribe("infer/health")
    infer = start_stage("infer", config)
    stop = threading.Event()
    frames = TwinFrames([TRUTH])

    def stream_odometry() -> None:  # the robot stands still: its odometry pose stays at the origin, time goes on
        seq = 0
        while not stop.wait(0.02):
            client.put_raw("shooter_bridge/odometry", codec.encode(_odometry(seq)))
            seq += 1

    streamer = threading.Thread(target=stream_odometry, daemon=True)
    try:
        infer.wait_line("infer running for robot", timeout=60)
        client.wait_subscribed("preprocess/edges")
        client.wait_subscribed("shooter_bridge/odometry")
        streamer.start()
        # Odometry is in the stage's buffer before the first frame, so the frames can be aligned to it.
        client.wait_for("infer/health", lambda h: h.detail.get("fusion.odometry_buffered", 0) >= 3, timeout=60)
        seq = 0
        for seq in range(1, 10):  # acquisition from the configured start agrees over a few frames
            client.put_raw("preprocess/edges", codec.encode(frames.edges(0, seq)))
            seen = client.wait_for("infer/pose", lambda p, s=seq: p.header.seq == s)
            if seen.header.valid:
                break
        assert seen.header.valid and math.hypot(seen.x - TRUTH[0], seen.y - TRUTH[1]) < 0.1
        assert len(seen.covariance) == 9 and seen.covariance[0] > 0  # x variance of the tracked pose

        # The lens is covered: no hits. Vision alone would answer no_hits; the odometry says "not moved".
        header = Header.now("robot1", seq + 1, "camera").forwarded("preprocess", valid=True)
        blind = Edges(header=header, width=640, height=480, crop_top=0, n_hits=0,
                      hits=hits_to_bytes(frames.hits[0][:0]))
        client.put_raw("preprocess/edges", codec.encode(blind))
        bridged = client.wait_for("infer/pose", lambda p: p.header.seq == seq + 1)
        assert bridged.header.valid, bridged.reason
        assert math.hypot(bridged.x - seen.x, bridged.y - seen.y) < 0.01
        assert bridged.covariance[0] >= seen.covariance[0]  # the prediction is less certain than the fix

        # The stage keeps only the newest odometry sample not yet read: stop the stream, or a good sample published
        # after the bad one could replace it before the worker reads it (seen on a loaded machine).
        stop.set()
        streamer.join(2.0)
        bad = _odometry(10_000)
        bad.odom_x_m = math.nan
        client.put_raw("shooter_bridge/odometry", codec.encode(bad))
        health = client.wait_for("infer/health", lambda h: h.detail.get("odom_rejected.non_finite", 0) >= 1)
        assert health.detail["fusion.valid_on_odometry"] >= 1 and infer.alive()
        # Odometry replaced by newer odometry while a frame ran is counted apart: no frame was lost here.
        assert health.dropped == 0 and health.detail["superseded"] >= 0
    finally:
        stop.set()
        streamer.join(2.0)
        client.close()
        code = infer.stop()
        router.stop()
    assert code == 0, infer.output()


def test_a_restarted_stage_carries_its_saved_pose_by_the_odometry_since(tmp_path: Path) -> None:
    """kill -9 of a tracking infer stage with odometry: the pose it saved comes with the odometry buffered from
    that pose's time on, the new process seeds its fusion with it (counted `fusion.resumed`), and odometry
    arriving after the restart carries the pose to the first frame: valid again within the few frames a tight
    prior needs, where a prior aged by the restart would be wider by 0.5 m a second."""
    from infer_models import first_valid_pose, request_pose

    port = free_port()
    body = f"""
[infer]
store = "{tmp_path / 'store'}"
[infer.fusion]
enabled = true
"""
    start = f"""[infer.start]
x = {TRUTH[0]}
y = {TRUTH[1]}
yaw_deg = {math.degrees(TRUTH[2])}
"""
    first = write_config(tmp_path / "first.toml", port, health_period_s=0.2, body=body + start)
    # The restarted stage is given no start at all: only the saved pose can say which twin the robot is.
    again = write_config(tmp_path / "again.toml", port, health_period_s=0.2, body=body)
    router = start_router(port)
    client = BusClient(port)
    client.subscribe("infer/pose")
    client.subscribe("infer/health")
    stop = threading.Event()
    frames = TwinFrames([TRUTH])

    def stream_odometry() -> None:  # standing still; the MCU keeps counting through the restart
        seq = 0
        while not stop.wait(0.02):
            client.put_raw("shooter_bridge/odometry", codec.encode(_odometry(seq)))
            seq += 1

    streamer = threading.Thread(target=stream_odometry, daemon=True)
    infer = start_stage("infer", first)
    try:
        infer.wait_line("infer running for robot", timeout=60)
        client.wait_subscribed("shooter_bridge/odometry")
        streamer.start()
        client.wait_for("infer/health", lambda h: h.detail.get("fusion.odometry_buffered", 0) >= 3, timeout=60)
        pose, seq = first_valid_pose(client, frames, 1, most=10)
        assert pose.header.valid, pose.reason
        # The stage saves a valid frame's pose after publishing it; the next frame's pose comes from the same
        # worker, so once it is here the save is done.
        assert request_pose(client, frames, seq).header.valid
        seq += 1
    finally:
        infer.kill()
    saved = json.loads((tmp_path / "store.last-pose.json").read_text())
    assert saved["odometry"] and saved["odometry_last"] is not None
    infer = start_stage("infer", again)
    try:
        infer.wait_line("carried by odometry", timeout=60)
        infer.wait_line("infer running for robot", timeout=60)
        client.wait_for("infer/health", lambda h: h.detail.get("fusion.resumed", 0) == 1, timeout=60)
        poses = [request_pose(client, frames, s) for s in range(seq, seq + 5)]
        assert poses[-1].header.valid, [(p.x, p.y, p.reason) for p in poses]
        assert all(math.hypot(p.x - TRUTH[0], p.y - TRUTH[1]) < 0.1 for p in poses if p.header.valid)
    finally:
        stop.set()
        streamer.join(2.0)
        client.close()
        infer.stop()
        router.stop()
