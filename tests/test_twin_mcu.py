"""The twin's MCU: its clock follows the camera's frames, its wheels do not feel kidnaps, and the bridge's
own link reads its ODOMETRY frames off the pty and gets a STATUS for each of its frames."""
from __future__ import annotations

import math
import os
import time
from pathlib import Path

import pytest

from courtloc.services.shooter_bridge.config import LinkConfig
from courtloc.services.shooter_bridge.link import McuLink
from courtloc.services.shooter_bridge.protocol import StatusFlag
from courtloc.sim.odometry import OdometrySimConfig, felt_motion
from courtloc.sim.trajectory import WaypointTrajectory
from courtloc.sim.twin_mcu import SimClock, TwinMcu, TwinMcuConfig

LOOP = WaypointTrajectory([(0.5, -2.0, 0.2), (4.5, -1.0, 0.9), (4.0, 2.5, 2.4)], speed=1.5, yaw_rate=1.0)


def test_sim_clock_is_host_time_since_the_first_frame():
    clock = SimClock()
    assert clock.at(5_000_000_000) == 0.0  # before the first frame the robot stands at the start
    clock.start(5_000_000_000)
    assert clock.at(4_000_000_000) == 0.0 and clock.at(6_500_000_000) == pytest.approx(1.5)


@pytest.mark.skipif(not hasattr(os, "openpty"), reason="needs ptys")
def test_the_twin_camera_stamps_frames_with_the_instant_they_show(tmp_path: Path):
    from courtloc.sim.source import SimSource, SimSourceConfig

    config = SimSourceConfig(trajectory="waypoints", waypoints=[[0.5, -2.0, 0.2], [4.5, -1.0, 0.9]], speed_mps=1.5,
                             mcu=TwinMcuConfig(link=str(tmp_path / "mcu")))
    with SimSource(config) as source:
        _, first = source.read()
        t0 = source.taken_mono_ns
        time.sleep(0.05)  # the robot drives on in host time between reads (no synchronisation: just a gap)
        _, second = source.read()
        elapsed = (source.taken_mono_ns - t0) / 1e9
        assert elapsed >= 0.05
        expected = WaypointTrajectory(config.waypoints, 1.5, config.yaw_rate_rps).pose_at(elapsed)
        assert second == pytest.approx(expected) and first == pytest.approx((0.5, -2.0, 0.2))
        assert (tmp_path / "mcu").is_symlink()
    assert not (tmp_path / "mcu").exists()


def test_the_wheels_do_not_feel_a_kidnap():
    class Teleported:  # drives ahead at 1 m/s; at t = 1 s it is put down elsewhere, turned by 1 rad
        def pose_at(self, t: float) -> tuple[float, float, float]:
            if t < 1.0:
                return t, 0.0, 0.0
            return 5.0 + (t - 1.0) * math.cos(1.0), 3.0 + (t - 1.0) * math.sin(1.0), 1.0

    forward, left, turn = felt_motion(Teleported(), [1.0], 0.95, 1.05)
    assert forward == pytest.approx(0.1, abs=1e-5) and left == pytest.approx(0.0, abs=1e-9)
    assert turn == pytest.approx(0.0, abs=1e-9)
    assert felt_motion(Teleported(), [], 0.95, 1.05)[2] == pytest.approx(1.0)  # unless told it was a teleport


def test_the_simulated_odometry_stream_does_not_feel_a_kidnap_either():
    """`bench sweep` fuses the kidnap walks with `OdometrySimulator`'s stream, which must leave the teleport out as
    the twin MCU does: every window valid, dead-reckoned along the driving only."""
    from courtloc.sim.odometry import OdometrySimulator

    class Teleported:  # drives ahead at 1 m/s; at t = 1 s it is put down 5 m away, turned by 1 rad, and drives on
        def pose_at(self, t: float) -> tuple[float, float, float]:
            return (t, 0.0, 0.0) if t < 1.0 else (5.0 + (t - 1.0) * math.cos(1.0), 3.0 + (t - 1.0) * math.sin(1.0), 1.0)

    quiet = OdometrySimConfig(speed_noise_m_s=0.0, wheel_yaw_noise_rad_s=0.0, gyro_noise_rad_s=0.0,
                              gyro_bias_rad_s=0.0, slip_rate_hz=0.0)
    felt = list(OdometrySimulator(Teleported(), quiet, kidnaps_s=[1.0]).stream(2.0))
    told = list(OdometrySimulator(Teleported(), quiet).stream(2.0))
    assert all(d.message.header.valid for d in felt)
    assert max(abs(d.message.wz_gyro_rad_s) for d in felt) == 0.0
    # 2 s at 1 m/s, read with the simulated wheels' scale error: one epoch, no teleport in it
    assert len({d.message.epoch for d in felt}) == 1
    assert felt[-1].message.odom_x_m == pytest.approx(2.0 * quiet.wheel_scale, abs=0.02)
    assert felt[-1].message.odom_y_m == pytest.approx(0.0, abs=1e-6)
    assert not all(d.message.header.valid for d in told)  # without kidnaps_s the teleport is a window to refuse


@pytest.mark.skipif(not hasattr(os, "openpty"), reason="needs ptys")
def test_the_bridge_link_reads_the_twin_mcu_off_its_pty(tmp_path: Path):
    quiet = OdometrySimConfig(speed_noise_m_s=0.0, wheel_yaw_noise_rad_s=0.0, gyro_noise_rad_s=0.0,
                              gyro_bias_rad_s=0.0, slip_rate_hz=0.0)
    mcu = TwinMcu(TwinMcuConfig(link=str(tmp_path / "mcu"), odometry=quiet), LOOP, [])
    samples = []
    mcu.start()
    link = McuLink(LinkConfig(port=str(tmp_path / "mcu"), heartbeat_s=0.05),
                   on_odometry=lambda sample, received_ns: samples.append(sample))
    try:
        assert (tmp_path / "mcu").is_symlink()
        link.start()
        # Odometry flows once the MCU hears the bridge (its heartbeats); each is answered with a STATUS.
        assert link.wait_until(lambda lk: lk.stats.odometry_frames >= 20 and lk.stats.status_frames >= 2, 20.0)
        assert link.last_status is not None and link.last_status.flags & StatusFlag.HOLDING
        # No frame shown yet: the robot stands at the start, the wheels read nothing.
        assert all(s.vx_m_s == 0.0 and s.vy_m_s == 0.0 and s.wheels_valid and s.gyro_valid for s in samples)
        assert [s.seq for s in samples] == list(range(samples[0].seq, samples[0].seq + len(samples)))
        assert link.stats.bad_odometry == 0
    finally:
        link.stop()
        mcu.stop()
    assert not (tmp_path / "mcu").exists()


@pytest.mark.skipif(not hasattr(os, "openpty"), reason="needs ptys")
def test_with_its_cable_out_the_twin_mcu_sends_nothing_and_streams_again_after(tmp_path: Path):
    """`bench twin --scenario mcu_loss`: over `silent_s` (sim time) the bridge hears nothing, then odometry flows."""
    mcu = TwinMcu(TwinMcuConfig(link=str(tmp_path / "mcu"), silent_s=[(0.0, 0.6)]), LOOP, [])
    received: list[int] = []
    mcu.start()
    t0 = time.monotonic_ns()
    mcu.clock.start(t0)  # sim time runs from here, as from a camera's first frame
    link = McuLink(LinkConfig(port=str(tmp_path / "mcu"), heartbeat_s=0.05),
                   on_odometry=lambda sample, received_ns: received.append(received_ns))
    try:
        link.start()
        assert link.wait_until(lambda lk: lk.stats.odometry_frames >= 20 and lk.stats.status_frames >= 1, 20.0)
        # Plugged in, the first frames come within a heartbeat or two (the test above); out, none before 0.6 s.
        assert min(received) >= t0 + 600_000_000
        assert link.stats.bad_odometry == 0
    finally:
        link.stop()
        mcu.stop()


def test_a_silence_that_is_no_interval_is_refused():
    with pytest.raises(ValueError, match="silent_s"):
        TwinMcuConfig(link="mcu", silent_s=[(2.0, 1.0)])


def test_the_camera_stamps_a_frame_at_the_instant_its_source_says():
    from courtloc.services.camera.service import capture_header

    taken = time.monotonic_ns() - 12_000_000  # rendered 12 ms ago
    header = capture_header("robot1", 7, "camera", taken)
    assert header.capture_mono_ns == taken and header.seq == 7
    assert header.stamps[-1].mono_ns - header.capture_mono_ns >= 12_000_000  # published after it was taken
    assert header.stamps[-1].wall_ns - header.capture_wall_ns == header.stamps[-1].mono_ns - taken
    future = capture_header("robot1", 8, "camera", time.monotonic_ns() + 10**9)  # a claim from the future
    assert future.capture_mono_ns == future.stamps[-1].mono_ns
    plain = capture_header("robot1", 9, "camera", None)  # a source that does not know: stamped now
    assert plain.capture_mono_ns == plain.stamps[-1].mono_ns
