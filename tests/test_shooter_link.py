"""McuLink over a real pseudo-terminal pair: the test plays the MCU on the master side.

The link opens the slave through a symlink, so the "device" can vanish (link removed, pty closed)
and come back as a different pty behind the same path.
"""
from __future__ import annotations

import errno
import os
import queue
import select
import threading
import time
from pathlib import Path
from typing import Callable, Iterator

import pytest

from courtloc.services.shooter_bridge.config import AreaConfig, LinkConfig, PolicyConfig
from courtloc.services.shooter_bridge.link import McuLink, backoff_delays
from courtloc.services.shooter_bridge.policy import ShotPolicy, build_area
from courtloc.services.shooter_bridge.protocol import Command, HoldReason, McuFrame, StreamDecoder, encode
from courtloc.shot.geometry import Pose2D, ShooterMount
from courtloc.shot.rpm import RpmTable

pytestmark = pytest.mark.skipif(not hasattr(os, "openpty"), reason="needs pseudo-terminals")

WAIT_S = 10.0  # generous upper bound for any one expected event; the tests normally finish far sooner


class FakeMcu:
    """The MCU side of a pty: a reader thread decodes every frame into a queue."""

    def __init__(self) -> None:
        self.master, self.slave = os.openpty()
        self.slave_path = os.ttyname(self.slave)
        self.decoder = StreamDecoder()
        self.frames: "queue.Queue[McuFrame]" = queue.Queue()
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._read, daemon=True)
        self._thread.start()

    def _read(self) -> None:
        while not self._stop.is_set():
            ready, _, _ = select.select([self.master], [], [], 0.05)
            if not ready:
                continue
            try:
                data = os.read(self.master, 4096)
            except OSError as exc:
                if exc.errno == errno.EIO:
                    continue  # no slave open at the moment
                return
            for frame in self.decoder.feed(data):
                self.frames.put(frame)

    def next_frame(self, match: Callable[[McuFrame], bool] = lambda f: True, timeout: float = WAIT_S) -> McuFrame:
        """The next frame that satisfies `match` (others are skipped), waiting at most `timeout`."""
        deadline = time.monotonic() + timeout
        while True:
            remaining = deadline - time.monotonic()
            if remaining <= 0:
                raise AssertionError("no matching frame arrived in time")
            try:
                frame = self.frames.get(timeout=remaining)
            except queue.Empty:
                raise AssertionError("no matching frame arrived in time") from None
            if match(frame):
                return frame

    def reply(self, frame: McuFrame) -> None:
        os.write(self.master, encode(frame))

    def close(self) -> None:
        self._stop.set()
        self._thread.join(2.0)
        for fd in (self.master, self.slave):
            try:
                os.close(fd)
            except OSError:
                pass


@pytest.fixture
def mcu() -> Iterator[FakeMcu]:
    device = FakeMcu()
    yield device
    device.close()


@pytest.fixture
def port_link(tmp_path: Path) -> Path:
    return tmp_path / "ttyMCU"


def _link(port: Path, **overrides: object) -> McuLink:
    settings = dict(port=str(port), baud=115200, heartbeat_s=0.05, reconnect_initial_s=0.02, reconnect_max_s=0.2)
    settings.update(overrides)
    return McuLink(LinkConfig(**settings))


@pytest.fixture
def link_to(port_link: Path) -> Iterator[Callable[..., McuLink]]:
    started: list[McuLink] = []

    def make(**overrides: object) -> McuLink:
        link = _link(port_link, **overrides)
        link.start()
        started.append(link)
        return link

    yield make
    for link in started:
        link.stop()


def test_set_rpm_frames_arrive_and_decode(mcu: FakeMcu, port_link: Path, link_to: Callable[..., McuLink]) -> None:
    os.symlink(mcu.slave_path, port_link)
    link = link_to(heartbeat_s=1.0)
    assert link.wait_connected(WAIT_S)
    link.send(Command.SET_RPM, 2345.4, flags=0x02)
    frame = mcu.next_frame(lambda f: f.command is Command.SET_RPM)
    assert (frame.rpm, frame.flags, frame.reason) == (2345, 0x02, 0)
    link.send(Command.SET_RPM, 2400.0)
    second = mcu.next_frame(lambda f: f.command is Command.SET_RPM)
    assert second.rpm == 2400 and second.seq == (frame.seq + 1) & 0xFFFF
    assert mcu.decoder.stats.crc_errors == 0


def test_heartbeat_when_idle(mcu: FakeMcu, port_link: Path, link_to: Callable[..., McuLink]) -> None:
    os.symlink(mcu.slave_path, port_link)
    link = link_to()
    beats = [mcu.next_frame() for _ in range(4)]
    assert all(b.command is Command.HEARTBEAT for b in beats)
    assert [b.seq for b in beats] == list(range(beats[0].seq, beats[0].seq + 4))
    assert link.wait_until(lambda lk: lk.stats.heartbeats_sent >= 4, WAIT_S)  # counted after the write returns


def test_status_frames_from_the_mcu_are_read(mcu: FakeMcu, port_link: Path, link_to: Callable[..., McuLink]) -> None:
    os.symlink(mcu.slave_path, port_link)
    link = link_to()
    assert link.wait_connected(WAIT_S)
    mcu.reply(McuFrame(seq=3, command=Command.STATUS, rpm=2210, flags=0x01))
    assert link.wait_until(lambda lk: lk.last_status is not None, WAIT_S)
    assert link.last_status == McuFrame(seq=3, command=Command.STATUS, rpm=2210, flags=0x01)


def test_policy_through_the_link_sends_hold_for_stale_invalid_and_outside(
        mcu: FakeMcu, port_link: Path, link_to: Callable[..., McuLink]) -> None:
    os.symlink(mcu.slave_path, port_link)
    area = AreaConfig(kind="rectangle", x_min=0.0, x_max=7.5, y_min=-4.0, y_max=4.0)
    table = RpmTable([2.0, 6.0], [2000.0, 3000.0])
    policy = ShotPolicy(PolicyConfig(freshness_s=0.2, slew_rpm_per_s=1e6, area=area), (6.0, 0.0, 2.43),
                        ShooterMount(), table.lookup, build_area(area, ""))
    link = link_to(heartbeat_s=1.0)
    assert link.wait_connected(WAIT_S)
    cases = [
        (Pose2D(2.0, 0.0, 0.0), 0.05, True, Command.SET_RPM, 2500, HoldReason.NONE),
        (Pose2D(2.0, 0.0, 0.0), 0.5, True, Command.HOLD, 0, HoldReason.STALE),
        (Pose2D(3.0, 0.0, 0.0), 0.05, True, Command.SET_RPM, 2250, HoldReason.NONE),
        (Pose2D(2.0, 0.0, 0.0), 0.05, False, Command.HOLD, 0, HoldReason.INVALID),
        (Pose2D(4.0, 0.0, 0.0), 0.05, True, Command.SET_RPM, 2000, HoldReason.NONE),
        (Pose2D(-1.0, 0.0, 0.0), 0.05, True, Command.HOLD, 0, HoldReason.OUTSIDE_AREA),
    ]
    policy.decide(Pose2D(2.0, 0.0, 0.0), 0.0, True, -1.0)  # the slew clock starts one second earlier
    for step, (pose, age, valid, command, rpm, reason) in enumerate(cases):
        decision = policy.decide(pose, age, valid, float(step))
        link.send(*decision.frame_fields())
        frame = mcu.next_frame(lambda f: f.command is not Command.HEARTBEAT)
        assert (frame.command, frame.rpm, frame.reason) == (command, rpm, int(reason)), step


def test_reconnects_after_the_port_vanishes(mcu: FakeMcu, port_link: Path, link_to: Callable[..., McuLink]) -> None:
    os.symlink(mcu.slave_path, port_link)
    link = link_to()
    mcu.next_frame()  # traffic on the first device
    port_link.unlink()
    mcu.close()  # the device is gone: the next write fails with EIO
    assert link.wait_until(lambda lk: not lk.connected and lk.stats.open_failures >= 2, WAIT_S)
    assert link.stats.write_errors + link.stats.read_errors >= 1  # whichever touched the dead pty first
    link.send(Command.SET_RPM, 3000.0)  # while away: must not raise, must not be delivered later
    replacement = FakeMcu()
    try:
        os.symlink(replacement.slave_path, port_link)
        assert link.wait_connected(WAIT_S)
        first = replacement.next_frame()
        assert first.command is Command.HEARTBEAT  # the queued SET_RPM was dropped, not replayed
        link.send(Command.SET_RPM, 2750.0)
        assert replacement.next_frame(lambda f: f.command is Command.SET_RPM).rpm == 2750
        assert link.stats.connects == 2
    finally:
        link.stop()
        replacement.close()


def test_missing_port_at_start_never_raises_and_connects_later(
        port_link: Path, link_to: Callable[..., McuLink]) -> None:
    link = link_to()
    link.send(Command.HOLD, reason=int(HoldReason.NO_POSE))
    assert link.wait_until(lambda lk: lk.stats.open_failures >= 3, WAIT_S)
    assert not link.connected and str(port_link) in link.stats.last_error
    device = FakeMcu()
    try:
        os.symlink(device.slave_path, port_link)
        assert link.wait_connected(WAIT_S)
        assert device.next_frame().command is Command.HEARTBEAT
    finally:
        link.stop()
        device.close()


def test_stop_sends_a_final_hold(mcu: FakeMcu, port_link: Path) -> None:
    os.symlink(mcu.slave_path, port_link)
    link = _link(port_link, heartbeat_s=1.0)
    link.start()
    assert link.wait_connected(WAIT_S)
    link.send(Command.SET_RPM, 2000.0)
    mcu.next_frame(lambda f: f.command is Command.SET_RPM)
    link.stop()
    final = mcu.next_frame(lambda f: f.command is not Command.HEARTBEAT)
    assert final.command is Command.HOLD and final.reason == int(HoldReason.STOPPED)


def test_backoff_doubles_up_to_the_cap() -> None:
    delays = backoff_delays(0.1, 1.0)
    assert [round(next(delays), 6) for _ in range(7)] == [0.1, 0.2, 0.4, 0.8, 1.0, 1.0, 1.0]


def test_a_second_link_cannot_share_the_port(mcu: FakeMcu, port_link: Path, link_to: Callable[..., McuLink]) -> None:
    os.symlink(mcu.slave_path, port_link)
    first = link_to()
    assert first.wait_connected(WAIT_S)
    second = link_to()
    assert second.wait_until(lambda lk: lk.stats.open_failures >= 1, WAIT_S)
    assert not second.connected and first.connected
