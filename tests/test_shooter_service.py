"""The shooter bridge as its own process on a real router, driving a pseudo-terminal MCU."""
from __future__ import annotations

import os
from pathlib import Path
from typing import Iterator

import pytest
from buskit import BusClient, free_port, start_router, start_stage, write_config
from test_shooter_link import FakeMcu  # the same pty MCU as the link tests (tests/ is on sys.path)

from courtloc.common import codec
from courtloc.common.messages import Header, Pose
from courtloc.common.services_table import TOPICS
from courtloc.services.shooter_bridge.protocol import Command, HoldReason

pytestmark = [pytest.mark.integration, pytest.mark.skipif(not hasattr(os, "openpty"), reason="needs ptys")]

RING = (6.0, 0.0, 2.43)


@pytest.fixture
def mcu() -> Iterator[FakeMcu]:
    device = FakeMcu()
    yield device
    device.close()


def _pose(client: BusClient, seq: int, x: float, y: float, valid: bool = True, reason: str = "") -> None:
    header = Header.now("robot1", seq, "test")
    header.valid = valid
    pose = Pose(header=header, x=x, y=y, yaw=0.0, quality=1.0, model_name="test", model_version=1,
                infer_ms=0.1, reason=reason)
    client.session.put(TOPICS["infer/pose"].key("robot1"), codec.encode(pose))


def test_bridge_process_sends_table_rpm_then_hold(tmp_path: Path, mcu: FakeMcu) -> None:
    table = tmp_path / "table.csv"
    table.write_text("distance_m,rpm\n2.0,2000\n6.0,3000\n")
    port = free_port()
    config = write_config(tmp_path / "deploy.toml", port, health_period_s=0.2, body=f"""
[shooter_bridge]
decide_period_s = 0.05
[shooter_bridge.target]
ring = [{RING[0]}, {RING[1]}, {RING[2]}]
[shooter_bridge.rpm]
table = "table.csv"
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
        # No pose yet: the MCU hears HOLD (no_pose), never an RPM.
        first = mcu.next_frame(lambda f: f.command is not Command.HEARTBEAT, timeout=20.0)
        assert first.command is Command.HOLD and first.reason == int(HoldReason.NO_POSE)

        # (2, 0) is 4 m from the ring: the table says 2500 rpm.
        frame = None
        for seq in range(200):
            _pose(client, seq, 2.0, 0.0)
            try:
                frame = mcu.next_frame(lambda f: f.command is Command.SET_RPM and f.rpm == 2500, timeout=0.2)
                break
            except AssertionError:
                continue
        assert frame is not None, bridge.output()
        solution = client.wait_for("shooter_bridge/solution", lambda s: s.command == "SET_RPM" and s.rpm > 2499)
        assert solution.distance_m == pytest.approx(4.0) and solution.rpm == pytest.approx(2500, abs=0.5)
        assert solution.header.valid and solution.header.stamps[-1].stage == "shooter_bridge"

        # Poses stop: within the freshness budget plus a tick the MCU gets HOLD (stale), not the old RPM.
        hold = mcu.next_frame(lambda f: f.command is Command.HOLD)
        assert hold.reason == int(HoldReason.STALE) and hold.rpm == 0
        stale = client.wait_for("shooter_bridge/solution", lambda s: s.command == "HOLD")
        assert stale.reason == "stale"

        # An invalid pose is a HOLD whose published reason keeps the upstream cause.
        _pose(client, 1000, 2.0, 0.0, valid=False, reason="off_court")
        invalid = client.wait_for("shooter_bridge/solution", lambda s: s.reason.startswith("invalid"))
        assert invalid.reason == "invalid:off_court" and invalid.rpm == 0
        mcu.next_frame(lambda f: f.command is Command.HOLD and f.reason == int(HoldReason.INVALID))

        # Garbage on the pose topic is counted and the bridge carries on.
        client.put_raw("infer/pose", b"\x01not msgpack")
        health = client.wait_for("shooter_bridge/health", lambda h: h.rejected >= 1)
        assert health.detail["mcu_connected"] == 1 and health.detail["hold.stale"] >= 1
        _pose(client, 1001, 3.0, 0.0)  # 3 m -> 2250 rpm
        mcu.next_frame(lambda f: f.command is Command.SET_RPM and f.rpm == 2250)
        assert bridge.alive()
    finally:
        client.close()
        code = bridge.stop()
        router.stop()
    assert code == 0, bridge.output()
    last = mcu.next_frame(lambda f: f.command is Command.HOLD and f.reason == int(HoldReason.STOPPED))
    assert last.rpm == 0


def test_bad_table_stops_the_bridge_at_start_with_the_file_named(tmp_path: Path) -> None:
    table = tmp_path / "table.csv"
    table.write_text("distance_m,rpm\n2.0,2000\n2.0,3000\n")
    config = write_config(tmp_path / "deploy.toml", free_port(), """
[shooter_bridge.rpm]
table = "table.csv"
""")
    bridge = start_stage("shooter_bridge", config)
    bridge.wait_line("appears twice")
    assert bridge.process is not None and bridge.process.wait(20) == 2
    assert "table.csv" in bridge.output()


def test_bridge_process_publishes_mcu_odometry_on_the_bus(tmp_path: Path, mcu: FakeMcu) -> None:
    import time

    from courtloc.services.shooter_bridge.protocol import McuFrame, OdometrySample, OdomFlag, encode, encode_odometry

    port = free_port()
    config = write_config(tmp_path / "deploy.toml", port, health_period_s=0.2, body=f"""
[shooter_bridge.target]
ring = [{RING[0]}, {RING[1]}, {RING[2]}]
[shooter_bridge.link]
port = "{mcu.slave_path}"
""")
    router = start_router(port)
    client = BusClient(port)
    client.subscribe("shooter_bridge/odometry")
    client.subscribe("shooter_bridge/health")
    bridge = start_stage("shooter_bridge", config)
    try:
        client.wait_alive("shooter_bridge")
        mcu.next_frame(timeout=20.0)  # the link is open: bytes written now reach the bridge
        client.wait_subscribed("shooter_bridge/odometry")
        t0_us = time.monotonic_ns() // 1000
        for i in range(20):  # the MCU's 100 Hz stream, 1 m/s straight ahead, paced like the real one
            sample = OdometrySample(seq=i, mcu_time_us=t0_us + 10_000 * i, vx_m_s=1.0, vy_m_s=0.0,
                                    wz_wheels_rad_s=0.0, wz_gyro_rad_s=0.0,
                                    flags=OdomFlag.WHEELS_VALID | OdomFlag.GYRO_VALID)
            os.write(mcu.master, encode_odometry(sample))
            time.sleep(0.01)
        os.write(mcu.master, encode(McuFrame(seq=99, command=Command.ODOMETRY, extra=b"\x01\x02")))  # truncated
        last = client.wait_for("shooter_bridge/odometry", lambda m: m.source_seq == 19)
        assert last.header.valid and last.source == "mcu" and last.epoch == 0
        assert last.odom_x_m == pytest.approx(0.19) and last.vx_m_s == 1.0
        # On this host's clock, at or before the moment the bridge read it, within the freshness budget.
        assert 0 <= last.received_mono_ns - last.header.capture_mono_ns <= 100e6
        health = client.wait_for("shooter_bridge/health", lambda h: h.detail.get("mcu_bad_odometry", 0) >= 1)
        assert health.detail["mcu_odometry_frames"] == 20 and bridge.alive()
    finally:
        client.close()
        code = bridge.stop()
        router.stop()
    assert code == 0, bridge.output()
