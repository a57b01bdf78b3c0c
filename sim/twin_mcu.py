"""The twin's MCU: the robot's wheels and gyro, on a pseudo-terminal the shooter bridge opens as its port.

The simulated camera (`source.py`) runs it when its config has an `mcu` table. It follows the SAME truth
the camera renders on the SAME clock: with the MCU the sim runs in real time (`SimClock`: host monotonic
time since the first frame's read), each frame shows the robot where it is at its read and is stamped
with that instant, so frames, ground truth and odometry agree whatever the camera's pacing (a camera
that cannot keep its rate misses moments; it does not slow the robot down, which no wheel could follow).
Kidnaps are teleports the wheels do not feel. `silent_s` unplugs the cable for a while: nothing either way.

Every 1 / `odometry.rate_hz` of host time it writes one ODOMETRY frame (`protocol.encode_odometry`, the
same bytes a real MCU sends) for the window since the previous one, with `OdometrySimulator`'s errors
(wheel scale, slip bursts, gyro bias and noise, clock offset and drift); the serial delay is the real
one of the pty and the scheduler. Like the firmware it answers each frame of the bridge with a STATUS
(holding unless told SET_RPM) and streams odometry only while the bridge is heard (a frame within
`listen_timeout_s`; the bridge heartbeats every 0.1 s): frames nobody reads would wait in the pty and
reach a bridge that opens later as old news.

The pty's slave path is published as the symlink `link` (replaced atomically), so a deployment points
`[shooter_bridge.link] port` at a fixed path before the camera has created the pty.
"""
from __future__ import annotations

import logging
import os
import threading
import time
import tty
from pathlib import Path
from typing import Optional, Sequence

from pydantic import BaseModel, ConfigDict, Field, model_validator

from courtloc.services.shooter_bridge.protocol import (
    Command,
    McuFrame,
    StatusFlag,
    StreamDecoder,
    encode,
    encode_odometry,
)
from courtloc.sim.odometry import OdometrySimConfig, OdometrySimulator, felt_motion
from courtloc.sim.trajectory import Trajectory

log = logging.getLogger(__name__)


class TwinMcuConfig(BaseModel):
    model_config = ConfigDict(extra="forbid")
    link: str = Field(description="symlink to the pty's slave: the shooter bridge's [link] port")
    odometry: OdometrySimConfig = Field(default_factory=OdometrySimConfig)
    listen_timeout_s: float = Field(0.5, gt=0, description="odometry flows while the bridge was heard this recently")
    silent_s: list[tuple[float, float]] = Field(
        default_factory=list, description="sim-time intervals [start, end) in which the cable is out: the MCU sends "
        "nothing (no odometry, no status) and hears nothing")

    @model_validator(mode="after")
    def _intervals(self) -> "TwinMcuConfig":
        for start, end in self.silent_s:
            if not 0 <= start < end:
                raise ValueError(f"silent_s: [{start}, {end}) is not an interval of sim time")
        return self


class SimClock:
    """Sim time of host monotonic time: with the MCU the sim runs in real time from the first frame's read
    (`start`); before it the robot stands at t = 0."""

    def __init__(self) -> None:
        self._t0_ns: Optional[int] = None

    def start(self, t0_ns: int) -> None:
        self._t0_ns = t0_ns

    def at(self, mono_ns: int) -> float:
        t0 = self._t0_ns
        return 0.0 if t0 is None else max((mono_ns - t0) / 1e9, 0.0)


class TwinMcu:
    """start() -> ... -> stop(); the camera starts `clock` at its first frame."""

    def __init__(self, config: TwinMcuConfig, trajectory: Trajectory, kidnaps_s: Sequence[float],
                 seed: int = 0) -> None:
        self.config = config
        self.clock = SimClock()
        self._trajectory = trajectory
        self._kidnaps = [float(t) for t in kidnaps_s]
        self._errors = OdometrySimulator(trajectory, config.odometry, seed=seed)
        self._decoder = StreamDecoder()
        self._stop = threading.Event()
        self._thread: Optional[threading.Thread] = None
        self._master = self._slave = -1
        self._heard_ns = 0
        self._commanded_rpm = 0
        self.sent = 0
        self.dropped = 0  # frames the pty had no room for (the bridge stopped reading)
        self.host_frames = 0

    def start(self) -> str:
        """Create the pty and its symlink, start streaming; returns the slave's device path."""
        self._master, self._slave = os.openpty()
        tty.setraw(self._slave)  # bytes, not lines: no echo, no translation
        os.set_blocking(self._master, False)
        device = os.ttyname(self._slave)
        link = Path(self.config.link)
        link.parent.mkdir(parents=True, exist_ok=True)
        staging = link.with_name(f".{link.name}.{os.getpid()}")
        staging.unlink(missing_ok=True)
        staging.symlink_to(device)
        os.replace(staging, link)
        self._thread = threading.Thread(target=self._run, name="twin-mcu", daemon=True)
        self._thread.start()
        log.info("twin MCU on %s (-> %s), odometry at %.0f Hz", link, device, self.config.odometry.rate_hz)
        return device

    def stop(self) -> None:
        self._stop.set()
        if self._thread is not None:
            self._thread.join(timeout=2.0)
            self._thread = None
        for fd in (self._master, self._slave):
            if fd >= 0:
                os.close(fd)
        self._master = self._slave = -1
        link = Path(self.config.link)
        try:
            if link.is_symlink():
                link.unlink()
        except OSError:  # already replaced or removed: nothing of ours left there
            pass

    def _run(self) -> None:
        period_ns = int(1e9 / self.config.odometry.rate_hz)
        start_ns = prev_ns = time.monotonic_ns()
        prev_sim = self.clock.at(prev_ns)
        next_ns = prev_ns + period_ns
        while not self._stop.wait(max(0.0, (next_ns - time.monotonic_ns()) / 1e9)):
            now_ns = time.monotonic_ns()
            next_ns = max(next_ns + period_ns, now_ns)  # behind (a loaded machine): the next window is longer
            sim = self.clock.at(now_ns)
            silent = self._cable_out(sim)
            self._read_host(now_ns, answer=not silent)
            dt = (now_ns - prev_ns) / 1e9
            if dt <= 0:
                continue
            # Cable out: the wheels still turn, the windows measured meanwhile never reach the bridge.
            if not silent and now_ns - self._heard_ns <= self.config.listen_timeout_s * 1e9:
                forward, left, turn = felt_motion(self._trajectory, self._kidnaps, prev_sim, sim)
                sample = self._errors.measure(self.sent, forward / dt, left / dt, turn / dt, dt,
                                              (now_ns - start_ns) / 1e9)
                self._write(encode_odometry(sample), count=True)
            prev_ns, prev_sim = now_ns, sim

    def _cable_out(self, sim: float) -> bool:
        return any(start <= sim < end for start, end in self.config.silent_s)

    def _write(self, data: bytes, count: bool = False) -> None:
        try:
            os.write(self._master, data)
        except BlockingIOError:
            self.dropped += 1
            return
        except OSError as exc:  # the pty went away under us (stop() in progress)
            log.debug("twin MCU write: %s", exc)
            return
        if count:
            self.sent += 1

    def _read_host(self, now_ns: int, answer: bool = True) -> None:
        """Take the bridge's frames and answer each with a STATUS; with the cable out (`answer` False) they are lost
        on the way: read, so they do not pile up in the pty, and dropped."""
        try:
            data = os.read(self._master, 4096)
        except (BlockingIOError, OSError):  # nothing waiting (EIO: no bridge has the port open)
            return
        if not answer:
            return
        for frame in self._decoder.feed(data):
            if frame.command not in (Command.SET_RPM, Command.HOLD, Command.HEARTBEAT):
                continue
            self.host_frames += 1
            self._heard_ns = now_ns
            if frame.command is Command.SET_RPM:
                self._commanded_rpm = frame.rpm
            elif frame.command is Command.HOLD:
                self._commanded_rpm = 0
            flags = StatusFlag.AT_SPEED if self._commanded_rpm else StatusFlag.HOLDING
            self._write(encode(McuFrame(seq=frame.seq, command=Command.STATUS, rpm=self._commanded_rpm,
                                        flags=int(flags))))

