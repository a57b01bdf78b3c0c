"""`courtloc replay`: a recording back onto the bus with its original timing.

The msgpack channels hold the exact payloads, so by default replay is bit-exact. Two options change
the bytes on purpose: `--robot` (another robot id: stages drop messages addressed to another robot)
and `--restamp` (capture times moved to now, so freshness checks downstream treat the replayed
frames as live rather than stale). At the recorded speed every stamp moves by the same amount, set by the first
message (it arrives as old as it was when recorded): the stamps keep their recorded spacing and each message its
recorded age, so a stage that integrates over time (the infer stage's motion filter) sees the live run's time steps,
not the replay's wake-up jitter. At another speed each message is stamped as captured when it is sent.
"""
from __future__ import annotations

import logging
import threading
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import zenoh

from courtloc.common import codec
from courtloc.common.bus import ZenohConfig, declare_publisher, open_session
from courtloc.common.messages import Header, Health
from courtloc.common.services_table import TOPICS
from courtloc.recording.mcapfile import Recorded, read_series, recorded_channels

log = logging.getLogger("courtloc.replay")


@dataclass
class ReplayOptions:
    speed: float = 1.0
    loop: bool = False
    only: set[str] | None = None
    robot_id: str | None = None  # None: the recorded robot id
    restamp: bool = False
    wait_subscribers_s: float = 0.0  # wait this long for someone to listen before the first message


@dataclass
class ReplayStats:
    published: dict[str, int] = field(default_factory=dict)
    rewritten: int = 0
    undecodable_skipped: int = 0
    loops: int = 0
    late_ms_max: float = 0.0

    def as_dict(self) -> dict[str, Any]:
        return {"published": dict(self.published), "rewritten": self.rewritten,
                "undecodable_skipped": self.undecodable_skipped, "loops": self.loops,
                "late_ms_max": round(self.late_ms_max, 3)}


def _shift_to_now(header: Header, age_ns: int) -> tuple[int, int]:
    """(monotonic, wall) nanoseconds that move `header`'s capture stamps so that it is `age_ns` old now."""
    return (time.monotonic_ns() - header.capture_mono_ns - age_ns, time.time_ns() - header.capture_wall_ns - age_ns)


def restamp_shift(record: Recorded) -> tuple[int, int] | None:
    """The shift that makes this record arrive now as old as it was when recorded (its log time); None for a
    message without a header or one that does not decode."""
    try:
        message = codec.decode(record.data, TOPICS[record.path].message)
    except codec.DecodeError:
        return None
    header = getattr(message, "header", None)
    if header is None:
        return None
    return _shift_to_now(header, record.log_time - header.capture_wall_ns)


def rewrite(record: Recorded, robot_id: str | None, restamp: bool, shift: tuple[int, int] | None = None) -> bytes:
    """The payload with another robot id and/or its capture time moved: by `shift` ((monotonic, wall) ns, from
    `restamp_shift`), or without one to now."""
    message_type = TOPICS[record.path].message
    message = codec.decode(record.data, message_type)
    if isinstance(message, Health):
        update: dict[str, Any] = {}
        if robot_id is not None:
            update["robot_id"] = robot_id
        if restamp:
            update["wall_ns"] = time.time_ns()
        return codec.encode(message.model_copy(update=update))
    header = message.header
    header_update: dict[str, Any] = {}
    if robot_id is not None:
        header_update["robot_id"] = robot_id
    if restamp:
        # Every stamp of the header moves by the same shift: its spans (stage latencies) stay as recorded, only
        # its age downstream changes (to `shift`'s, or "just captured").
        mono_shift, wall_shift = shift if shift is not None else _shift_to_now(header, 0)
        header_update["capture_mono_ns"] = header.capture_mono_ns + mono_shift
        header_update["capture_wall_ns"] = header.capture_wall_ns + wall_shift
        header_update["stamps"] = [s.model_copy(update={"mono_ns": s.mono_ns + mono_shift,
                                                        "wall_ns": s.wall_ns + wall_shift})
                                   for s in header.stamps]
    return codec.encode(message.model_copy(update={"header": header.model_copy(update=header_update)}))


class Replayer:
    def __init__(self, files: list[Path], zenoh_config: ZenohConfig, options: ReplayOptions) -> None:
        self.files = files
        self.zenoh_config = zenoh_config
        self.options = options
        self.stats = ReplayStats()
        self._publishers: dict[tuple[str, str], zenoh.Publisher] = {}

    def run(self, stop: threading.Event) -> ReplayStats:
        zsession = open_session(self.zenoh_config, stop)
        if zsession is None:
            return self.stats
        try:
            self._declare_all(zsession)
            self._wait_for_subscribers(stop)
            while not stop.is_set():
                self._play_once(zsession, stop)
                self.stats.loops += 1
                if not self.options.loop:
                    break
        finally:
            for publisher in self._publishers.values():
                publisher.undeclare()
            zsession.close()
        return self.stats

    def _declare_all(self, zsession: zenoh.Session) -> None:
        """Publishers exist before the first message, so routes are in place when timing starts."""
        for path, robot in recorded_channels(self.files):
            if self.options.only is None or path in self.options.only:
                self._publisher(zsession, path, robot)

    def _publisher(self, zsession: zenoh.Session, path: str, recorded_robot: str) -> zenoh.Publisher:
        robot = self.options.robot_id or recorded_robot
        found = self._publishers.get((path, robot))
        if found is None:
            found = declare_publisher(zsession, TOPICS[path], robot)
            self._publishers[(path, robot)] = found
        return found

    def _wait_for_subscribers(self, stop: threading.Event) -> None:
        if self.options.wait_subscribers_s <= 0 or not self._publishers:
            return
        matched = threading.Event()
        listeners = []

        def on_status(status: Any) -> None:
            if status.matching:
                matched.set()
        for publisher in self._publishers.values():
            if publisher.matching_status.matching:
                matched.set()
            listeners.append(publisher.declare_matching_listener(on_status))
        deadline = time.monotonic() + self.options.wait_subscribers_s
        while not matched.is_set() and not stop.is_set() and time.monotonic() < deadline:
            matched.wait(0.1)
        for listener in listeners:
            listener.undeclare()
        if not matched.is_set():
            log.warning("no subscriber after %.1f s; replaying anyway", self.options.wait_subscribers_s)

    def _play_once(self, zsession: zenoh.Session, stop: threading.Event) -> None:
        opts = self.options
        start_wall: float | None = None
        first_log = 0
        # At the recorded speed one shift for the whole pass (module docstring), set by the first stamped message.
        shift: tuple[int, int] | None = None
        for record in read_series(self.files, only=opts.only):
            if start_wall is None:
                start_wall, first_log = time.monotonic(), record.log_time
            due = start_wall + (record.log_time - first_log) / 1e9 / opts.speed
            remaining = due - time.monotonic()
            if remaining > 0 and stop.wait(remaining):
                return
            if stop.is_set():
                return
            self.stats.late_ms_max = max(self.stats.late_ms_max, -remaining * 1e3)
            payload = record.data
            robot_changes = opts.robot_id is not None and opts.robot_id != record.robot_id
            if robot_changes or opts.restamp:
                if opts.restamp and opts.speed == 1.0 and shift is None:
                    shift = restamp_shift(record)
                try:
                    payload = rewrite(record, opts.robot_id if robot_changes else None, opts.restamp,
                                      shift if opts.speed == 1.0 else None)
                except codec.DecodeError:
                    # A payload that never decoded cannot be readdressed or restamped.
                    self.stats.undecodable_skipped += 1
                    continue
                self.stats.rewritten += 1
            self._publisher(zsession, record.path, record.robot_id).put(payload)
            self.stats.published[record.path] = self.stats.published.get(record.path, 0) + 1
