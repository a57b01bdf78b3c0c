"""MCU odometry: clock mapping, checks with counted reasons, dead reckoning, and the link over a real pty."""
from __future__ import annotations

import math
import os

import pytest

from courtloc.services.shooter_bridge.config import LinkConfig
from courtloc.services.shooter_bridge.link import McuLink
from courtloc.services.shooter_bridge.odometry import ClockMap, OdometryConfig, OdometryIntake
from courtloc.services.shooter_bridge.protocol import (
    Command,
    McuFrame,
    OdometrySample,
    OdomFlag,
    encode,
    encode_odometry,
)

BOTH = OdomFlag.WHEELS_VALID | OdomFlag.GYRO_VALID
HOST0 = 5_000_000_000  # host monotonic ns at the first frame
MCU0 = 4_294_000_000  # the MCU's uint32 microsecond clock, about to wrap


def sample(i: int, t_us: int, vx: float = 1.0, wz: float = 0.0, flags: OdomFlag = BOTH, seq: int | None = None
           ) -> OdometrySample:
    return OdometrySample(seq=(i if seq is None else seq) & 0xFFFF, mcu_time_us=t_us & 0xFFFFFFFF, vx_m_s=vx,
                          vy_m_s=0.0, wz_wheels_rad_s=wz, wz_gyro_rad_s=wz, flags=flags)


def feed(intake: OdometryIntake, n: int, delays_us: list[int], period_us: int = 10_000, **kw: float):
    out = []
    for i in range(n):
        t_us = MCU0 + i * period_us
        received = HOST0 + i * period_us * 1000 + delays_us[i % len(delays_us)] * 1000
        out.append(intake.accept(sample(i, t_us, **kw), received, received))
    return out


def test_clock_map_takes_the_least_delayed_frame_and_unwraps() -> None:
    intake = OdometryIntake("robot1", OdometryConfig())
    # Serial + scheduling delay between 1 and 7 ms; the true offset shows in the 1 ms frames.
    messages = feed(intake, 50, delays_us=[7000, 3000, 1000, 5000, 2000])
    assert all(m is not None for m in messages)
    last = messages[-1]
    true_end_ns = HOST0 + 49 * 10_000_000
    # From the third frame on the map is the 1 ms-delay offset: stamps are 1 ms late, never earlier than true.
    for i, message in enumerate(messages[2:], start=2):
        assert message.header.capture_mono_ns - (HOST0 + i * 10_000_000) == 1_000_000
    assert last.header.capture_mono_ns == true_end_ns + 1_000_000
    # The MCU clock wrapped (MCU0 + 0.49 s > 2^32 us) and the source time kept growing.
    assert last.source_time_ns - messages[0].source_time_ns == 49 * 10_000_000
    assert last.window_s == pytest.approx(0.01)
    assert ClockMap.delta_us(0xFFFFFFF0, 0x10) == 0x20 and ClockMap.delta_us(0x10, 0xFFFFFFF0) == -0x20


def test_dead_reckoning_follows_an_arc() -> None:
    intake = OdometryIntake("robot1", OdometryConfig())
    # 1 m/s, 0.5 rad/s for 2 s: an arc of radius 2 m turning 1 rad.
    messages = feed(intake, 201, delays_us=[1000], vx=1.0, wz=0.5)
    last = messages[-1]
    assert last.epoch == 0 and last.heading_from_gyro
    assert last.odom_yaw_rad == pytest.approx(1.0, abs=1e-9)
    # Midpoint rule on 10 ms steps: the chord error is O(dt^2) per unit length, far below 1e-5 m.
    assert last.odom_x_m == pytest.approx(2.0 * math.sin(1.0), abs=1e-5)
    assert last.odom_y_m == pytest.approx(2.0 * (1 - math.cos(1.0)), abs=1e-5)


def test_bad_clocks_are_rejected_with_a_counted_reason() -> None:
    intake = OdometryIntake("robot1", OdometryConfig())
    t0 = 1_000_000
    assert intake.accept(sample(0, t0), HOST0) is not None
    assert intake.accept(sample(1, t0 + 10_000), HOST0 + 10_000_000) is not None
    assert intake.accept(sample(1, t0 + 10_000), HOST0 + 11_000_000) is None  # the same frame twice
    assert intake.accept(sample(2, t0 + 10_000), HOST0 + 20_000_000) is None  # new SEQ, the clock stood still
    assert intake.accept(sample(3, t0 + 5_000), HOST0 + 30_000_000) is None  # the clock went back
    assert dict(intake.rejected) == {"duplicate": 1, "clock_stalled": 1, "clock_backwards": 1}
    before = intake.accept(sample(4, t0 + 40_000), HOST0 + 40_000_000)
    assert before is not None and before.epoch == 0
    # The MCU claims 3 s passed while the host saw 10 ms: a jump (or a reboot). A new epoch starts.
    jumped = intake.accept(sample(5, t0 + 3_040_000), HOST0 + 50_000_000)
    assert jumped is not None and jumped.epoch == 1 and jumped.odom_x_m == 0.0
    assert intake.degraded["clock_jump"] == 1
    # Two frames lost on the way (SEQ 6, 7) are counted; the next one still integrates.
    after = intake.accept(sample(8, t0 + 3_070_000), HOST0 + 80_000_000)
    assert after is not None and after.epoch == 1 and intake.lost == 2
    assert after.odom_x_m == pytest.approx(0.03)


def test_implausible_wheels_and_a_saturated_gyro_are_not_used() -> None:
    intake = OdometryIntake("robot1", OdometryConfig(max_speed_m_s=5.0))
    feed(intake, 3, delays_us=[1000])
    fast = intake.accept(sample(3, MCU0 + 30_000, vx=9.0), HOST0 + 31_000_000)
    assert fast is not None and not fast.wheels_valid and fast.vx_m_s == 0.0 and fast.epoch == 1
    assert intake.degraded["implausible_wheels"] == 1
    sat = intake.accept(sample(4, MCU0 + 40_000, wz=3.0, flags=BOTH | OdomFlag.GYRO_SATURATED),
                        HOST0 + 41_000_000)
    assert sat is not None and sat.wheels_valid and not sat.gyro_valid and sat.gyro_saturated
    assert intake.degraded["gyro_saturated"] == 1
    nothing = intake.accept(sample(5, MCU0 + 50_000, flags=OdomFlag(0)), HOST0 + 51_000_000)
    assert nothing is not None and not nothing.header.valid


def test_a_frame_later_than_the_freshness_budget_is_dropped() -> None:
    intake = OdometryIntake("robot1", OdometryConfig(freshness_s=0.05))
    feed(intake, 5, delays_us=[1000])
    # The next frame arrives 200 ms after its window ended (a stalled USB buffer): stale, not published.
    late = intake.accept(sample(5, MCU0 + 50_000), HOST0 + 250_000_000)
    assert late is None and intake.rejected["late"] == 1


@pytest.mark.skipif(not hasattr(os, "openpty"), reason="needs pseudo-terminals")
def test_link_hands_odometry_frames_from_a_pty_with_their_receive_time() -> None:
    import queue
    import time

    from test_shooter_link import FakeMcu  # tests/ is on sys.path

    mcu = FakeMcu()
    got: "queue.Queue[tuple[OdometrySample, int]]" = queue.Queue()
    link = McuLink(LinkConfig(port=mcu.slave_path, heartbeat_s=1.0),
                   on_odometry=lambda s, ns: got.put((s, ns)))
    try:
        link.start()
        assert link.wait_connected(10.0)
        sent = [sample(i, 1000 + 10_000 * i, vx=0.5, wz=-0.25) for i in range(5)]
        for s in sent:
            written_ns = time.monotonic_ns()
            os.write(mcu.master, encode(McuFrame(seq=s.seq, command=Command.STATUS, rpm=1200)) + encode_odometry(s))
            received, received_ns = got.get(timeout=10.0)
            assert received == s
            assert received_ns >= written_ns  # stamped on reading, after the bytes were written
        assert link.wait_until(lambda l: l.stats.status_frames == 5 and l.stats.odometry_frames == 5, 10.0)
        # A truncated ODOMETRY payload (good CRC) is counted, not handed on.
        os.write(mcu.master, encode(McuFrame(seq=9, command=Command.ODOMETRY, extra=b"\x00" * 4)))
        assert link.wait_until(lambda l: l.stats.bad_odometry == 1, 10.0)
        assert got.empty()
    finally:
        link.stop()
        mcu.close()
