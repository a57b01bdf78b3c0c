"""Shadow mode: a candidate model runs beside the active one on the same live inputs, on its own
thread, so it never delays the active pose; its poses go to the shadow key with running statistics
of how far they are from the active model's."""
from __future__ import annotations

import math
import threading
from collections import deque
from typing import Callable

import numpy as np

from courtloc.common.control import ShadowStats
from courtloc.common.inbox import Inbox
from courtloc.common.messages import Edges, Pose
from courtloc.localizer.tracking import Tracker
from courtloc.world.angles import wrap_angle


class ShadowRunner:
    def __init__(self, model, publish: Callable[[Pose], None], make_pose,  # noqa: ANN001
                 tracker: Tracker | None = None) -> None:
        self.model = model
        self._publish = publish
        self._make_pose = make_pose
        self._inbox = Inbox()  # latest only: a candidate that falls behind skips frames, never delays them
        self._stop = threading.Event()
        self._diffs: deque[float] = deque(maxlen=1000)
        self._yaw_diffs: deque[float] = deque(maxlen=1000)
        self._lock = threading.Lock()
        self._tracker = tracker or Tracker()  # the candidate tracks on its own poses
        self._thread = threading.Thread(target=self._run, name="infer-shadow", daemon=True)
        self._thread.start()

    def offer(self, edges: Edges, hits: np.ndarray, active: Pose, marks: np.ndarray | None = None) -> None:
        self._inbox.put("frame", (edges, hits, active, marks))

    def _run(self) -> None:
        while not self._stop.is_set():
            delivery = self._inbox.take(timeout=0.5)
            if delivery is None:
                continue
            edges, hits, active, marks = delivery.payload
            pose = self._make_pose(self.model, edges, hits, self._tracker, marks)
            self._publish(pose)
            if pose.header.valid and active.header.valid:
                with self._lock:
                    self._diffs.append(math.hypot(pose.x - active.x, pose.y - active.y))
                    if pose.yaw is not None and active.yaw is not None:
                        wrapped = wrap_angle(pose.yaw - active.yaw)
                        self._yaw_diffs.append(abs(math.degrees(wrapped)))

    def stats(self) -> ShadowStats:
        with self._lock:
            diffs = np.asarray(self._diffs)
            yaws = np.asarray(self._yaw_diffs)
        ref = self.model.ref
        if diffs.size == 0:
            return ShadowStats(name=ref.name, version=ref.version)
        return ShadowStats(name=ref.name, version=ref.version, n=int(diffs.size), mean_diff_m=float(diffs.mean()),
                           p95_diff_m=float(np.percentile(diffs, 95)), max_diff_m=float(diffs.max()),
                           yaw_mean_diff_deg=float(yaws.mean()) if yaws.size else 0.0)

    def stop(self) -> None:
        self._stop.set()
        self._inbox.wake()
        self._thread.join(timeout=5.0)
