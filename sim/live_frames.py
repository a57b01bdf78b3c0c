"""Frames from a running robot's camera (`camera/frame` on its bus), saved as images: the `--live` source
of `courtloc calibrate mount`, so a team need not copy frames off the robot by hand."""
from __future__ import annotations

import logging
import queue
import threading
import time
from pathlib import Path
from typing import Any

import cv2

from courtloc.common import codec
from courtloc.common.bus import open_session
from courtloc.common.messages import Frame
from courtloc.common.payloads import FrameError, decode_frame
from courtloc.common.services_table import TOPICS

log = logging.getLogger(__name__)


class LiveFramesError(ValueError):
    pass


def grab_frames(robot_id: str, zenoh_config: Any, n: int, out_dir: Path, timeout_s: float = 30.0) -> list[Path]:
    """Save the next `n` decodable frames of `camera/frame` into `out_dir` as PNG; LiveFramesError when fewer
    than `n` arrive within `timeout_s` (the camera stage is not running, or another robot id)."""

    out_dir.mkdir(parents=True, exist_ok=True)
    payloads: queue.Queue[Any] = queue.Queue(maxsize=4 * n)

    def on_sample(sample: Any) -> None:  # zenoh thread: hand the payload over, nothing else
        try:
            payloads.put_nowait(sample.payload)
        except queue.Full:
            pass

    stop = threading.Event()
    session = open_session(zenoh_config, stop)
    assert session is not None  # only None when `stop` is set
    subscriber = session.declare_subscriber(TOPICS["camera/frame"].key(robot_id), on_sample)
    saved: list[Path] = []
    bad = 0
    deadline = time.monotonic() + timeout_s
    try:
        while len(saved) < n:
            remaining = deadline - time.monotonic()
            if remaining <= 0:
                raise LiveFramesError(f"{len(saved)} of {n} frames from camera/frame of robot {robot_id!r} in "
                                      f"{timeout_s:.0f} s ({bad} undecodable): is its camera stage running?")
            try:
                payload = payloads.get(timeout=min(remaining, 0.5))
            except queue.Empty:
                continue
            try:
                frame = codec.decode(bytes(payload), Frame)
                image = decode_frame(frame.encoding, frame.data, frame.width, frame.height)
            except (codec.DecodeError, FrameError) as exc:
                bad += 1
                log.warning("frame skipped: %s", exc)
                continue
            path = out_dir / f"live{len(saved):02d}.png"
            cv2.imwrite(str(path), image)
            saved.append(path)
    finally:
        subscriber.undeclare()
        session.close()
    return saved
