"""A bus client that watches one robot: health, liveliness, poses, solutions and end-to-end latency.

Used by `courtloc up` for its status line and summary, and by benchmarks.
"""
from __future__ import annotations

import logging
import math
import queue
import threading
import time
from collections import deque
from dataclasses import dataclass, field
from typing import Any

import numpy as np
import zenoh

from courtloc.common import codec
from courtloc.common.bus import ZenohConfig, open_session
from courtloc.common.messages import GroundTruth, Health, Pose, ShotSolution
from courtloc.common.services_table import (
    HEALTH_TOPICS,
    SERVICES,
    TOPICS,
    all_liveliness_key,
    service_of_liveliness_key,
)
from courtloc.services.deployment import DeploymentConfig

log = logging.getLogger("courtloc.watch")
_MAX_TRUTHS = 256


def chain_output(services: list[str]) -> str:
    """The main output topic of the most downstream stage that runs: where end-to-end latency is read."""
    last = [name for name in SERVICES if name in services][-1]
    return SERVICES[last].outputs[0]


@dataclass
class WatchState:
    health: dict[str, Health] = field(default_factory=dict)
    alive: set[str] = field(default_factory=set)
    counts: dict[str, int] = field(default_factory=dict)
    valid_counts: dict[str, int] = field(default_factory=dict)
    # Bounded, so a long `courtloc up` does not grow: ~55 min of samples at 30 Hz; the maximum is kept apart.
    e2e_ns: deque[int] = field(default_factory=lambda: deque(maxlen=100_000))
    e2e_max_ns: int = 0
    truths: dict[int, GroundTruth] = field(default_factory=dict)
    pose_errors_m: deque[float] = field(default_factory=lambda: deque(maxlen=100_000))
    last_pose: Pose | None = None
    last_solution: ShotSolution | None = None
    undecodable: int = 0
    overflow: int = 0


class BusWatcher:
    def __init__(self, config: DeploymentConfig, zenoh_config: ZenohConfig | None = None,
                 warmup_s: float = 2.0) -> None:
        self.config = config
        self.warmup_s = warmup_s
        self._first_e2e: float | None = None
        self.zenoh_config = zenoh_config or config.zenoh
        self.e2e_topic = chain_output(config.launcher.services)
        self.state = WatchState()
        self._lock = threading.Lock()
        self._queue: queue.Queue[tuple[str, Any]] = queue.Queue(maxsize=1024)
        self._session: zenoh.Session | None = None
        self._threads: list[threading.Thread] = []
        self._stop = threading.Event()
        self._subs: list[Any] = []

    def start(self, stop: threading.Event) -> None:
        self._stop = stop
        thread = threading.Thread(target=self._run, name="watch", daemon=True)
        thread.start()
        self._threads.append(thread)

    def _run(self) -> None:
        self._session = open_session(self.zenoh_config, self._stop)
        if self._session is None:
            return
        robot = self.config.robot_id
        for path in self.watched_paths():
            self._subs.append(self._session.declare_subscriber(TOPICS[path].key(robot), self._enqueue(path)))
        self._subs.append(self._session.liveliness().declare_subscriber(
            all_liveliness_key(robot), self._on_liveliness, history=True))
        self._subs.extend(self.extra_subscribers(self._session))
        while not self._stop.is_set():
            try:
                path, payload = self._queue.get(timeout=0.5)
            except queue.Empty:
                continue
            self._handle(path, payload)

    def watched_paths(self) -> set[str]:
        """Topics decoded on the watcher's thread into `state` (a subclass may add some and handle them)."""
        paths = {"camera/ground_truth", "infer/pose", "shooter_bridge/solution", self.e2e_topic}
        paths.update(t.path for t in HEALTH_TOPICS.values())
        return paths

    def extra_subscribers(self, zsession: zenoh.Session) -> list[Any]:
        """Hook for a subclass's own subscribers on the watcher's session (e.g. frames, not decoded here)."""
        return []

    def _enqueue(self, path: str):  # noqa: ANN202 - zenoh callback
        def on_sample(sample: zenoh.Sample) -> None:
            try:
                self._queue.put_nowait((path, sample.payload))
            except queue.Full:
                self.state.overflow += 1
        return on_sample

    def _on_liveliness(self, sample: zenoh.Sample) -> None:
        service = service_of_liveliness_key(str(sample.key_expr))
        with self._lock:
            if sample.kind == zenoh.SampleKind.PUT:
                self.state.alive.add(service)
            else:
                self.state.alive.discard(service)

    def _handle(self, path: str, payload: Any) -> None:
        topic = TOPICS[path]
        try:
            message = codec.decode(bytes(payload), topic.message)
        except codec.DecodeError:
            self.state.undecodable += 1
            return
        with self._lock:
            state = self.state
            if isinstance(message, Health):
                state.health[message.service] = message
                return
            state.counts[path] = state.counts.get(path, 0) + 1
            header = message.header
            if header.valid:
                state.valid_counts[path] = state.valid_counts.get(path, 0) + 1
            if path == self.e2e_topic and header.valid:
                # Latency of the first seconds measures start-up (imports, first renders), not the chain.
                now = time.monotonic()
                self._first_e2e = self._first_e2e or now
                if now - self._first_e2e >= self.warmup_s:
                    span = header.span_ns()
                    state.e2e_ns.append(span)
                    state.e2e_max_ns = max(state.e2e_max_ns, span)
            if isinstance(message, GroundTruth):
                state.truths[header.seq] = message
                if len(state.truths) > _MAX_TRUTHS:
                    state.truths.pop(next(iter(state.truths)))
            elif isinstance(message, Pose):
                state.last_pose = message
                truth = state.truths.get(header.seq)
                if truth is not None and header.valid:
                    state.pose_errors_m.append(math.hypot(message.x - truth.x, message.y - truth.y))
            elif isinstance(message, ShotSolution):
                state.last_solution = message

    def close(self) -> None:
        self._stop.set()
        for thread in self._threads:
            thread.join(timeout=3.0)
        for sub in self._subs:
            sub.undeclare()
        if self._session is not None:
            self._session.close()

    # ---- reading -------------------------------------------------------------------------
    def status_line(self) -> str:
        with self._lock:
            state = self.state
            rates = " ".join(
                f"{name}:{state.health[name].rate_out_hz:4.1f}" if name in state.health else f"{name}:--"
                for name in self.config.launcher.services)
            parts = [f"fps {rates}"]
            pose = state.last_pose
            if pose is not None:
                yaw = "" if pose.yaw is None else f" {math.degrees(pose.yaw):+6.1f}deg"
                parts.append(f"pose ({pose.x:+.2f},{pose.y:+.2f}){yaw}{'' if pose.header.valid else ' INVALID'}")
            if state.pose_errors_m:
                parts.append(f"err {np.median(list(state.pose_errors_m)[-60:]):.3f} m")
            sol = state.last_solution
            if sol is not None:
                parts.append(f"rpm {sol.rpm:.0f} {sol.command}" + (f" ({sol.reason})" if sol.reason else ""))
            if state.e2e_ns:
                parts.append(f"e2e p50 {np.median(list(state.e2e_ns)[-300:]) / 1e6:.1f} ms")
        return " | ".join(parts)

    def summary(self, restarts: dict[str, int], duration_s: float) -> dict[str, Any]:
        with self._lock:
            state = self.state
            e2e = np.fromiter(state.e2e_ns, dtype=np.float64) / 1e6
            stages = {
                name: {
                    **{k: getattr(h, k) for k in ("frames_in", "frames_out", "rate_in_hz", "rate_out_hz",
                                                  "dropped", "rejected", "stale", "latency_ms_p50",
                                                  "latency_ms_p99", "last_error")},
                    "alive": name in state.alive,
                    "restarts": restarts.get(name, 0),
                }
                for name, h in state.health.items()
            }
            errors = np.fromiter(state.pose_errors_m, dtype=np.float64)
            return {
                "robot_id": self.config.robot_id,
                "duration_s": round(duration_s, 3),
                "services": list(self.config.launcher.services),
                "stages": stages,
                "messages": dict(state.counts),
                "valid_messages": dict(state.valid_counts),
                "poses": state.counts.get("infer/pose", 0),
                "valid_poses": state.valid_counts.get("infer/pose", 0),
                "solutions": state.counts.get("shooter_bridge/solution", 0),
                "valid_solutions": state.valid_counts.get("shooter_bridge/solution", 0),
                "e2e_latency_ms": {
                    "topic": self.e2e_topic, "n": int(e2e.size), "warmup_s": self.warmup_s,
                    "p50": float(np.percentile(e2e, 50)) if e2e.size else None,
                    "p99": float(np.percentile(e2e, 99)) if e2e.size else None,
                    "max": state.e2e_max_ns / 1e6 if e2e.size else None,
                    # a backlog shows as the last tenth of the run slower than the first
                    "p50_first_10pct": float(np.median(e2e[:max(e2e.size // 10, 1)])) if e2e.size else None,
                    "p50_last_10pct": float(np.median(e2e[-max(e2e.size // 10, 1):])) if e2e.size else None,
                },
                "pose_error_m": {
                    "n": int(errors.size),
                    "mean": float(errors.mean()) if errors.size else None,
                    "p95": float(np.percentile(errors, 95)) if errors.size else None,
                },
                "drops": int(sum(h.dropped for h in state.health.values())),
                "rejected": int(sum(h.rejected for h in state.health.values())),
                "restarts": int(sum(restarts.values())),
                "restarts_by_process": restarts,
                "last_pose": state.last_pose.model_dump(exclude={"header"}) if state.last_pose else None,
                "last_solution": state.last_solution.model_dump(exclude={"header"}) if state.last_solution else None,
                "watcher_overflow": state.overflow,
            }
