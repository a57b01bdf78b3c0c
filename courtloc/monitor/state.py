"""What the page shows, as JSON: the court drawing (once) and the live state (10+ times a second)."""
from __future__ import annotations

import math
import time
from itertools import islice
from typing import Any, Iterable

import cv2
import numpy as np

from courtloc.common.messages import Pose
from courtloc.common.services_table import SERVICES
from courtloc.monitor.thumbnail import Thumbnailer
from courtloc.monitor.watcher import MonitorWatcher

POSE_STALE_S = 1.0  # no pose for this long: the page says "stale"
HEALTH_STALE_S = 3.0  # a stage whose health is older than this is shown as silent
TRAIL_SENT = 300  # trail points sent with every update (10 s at 30 Hz)
SIMPLIFY_M = 0.003  # polygon simplification: 3 mm is far below a pixel of the drawing


def court_payload(court: Any) -> dict[str, Any]:
    """Painted elements as simplified polygons in court metres, with colours, for the page to draw."""
    def simplify(poly: np.ndarray) -> list[list[float]]:
        approx = cv2.approxPolyDP(np.asarray(poly, np.float32).reshape(-1, 1, 2), SIMPLIFY_M, True)
        return [[round(float(x), 4), round(float(y), 4)] for x, y in approx.reshape(-1, 2)]

    elements = [
        {"name": name, "colour": "#%02x%02x%02x" % court.rgb(colour), "white": colour in court.white_colours,
         "exteriors": [simplify(p) for p in exteriors], "holes": [simplify(p) for p in holes]}
        for name, colour, exteriors, holes in court.painted_elements()
    ]
    return {
        "name": court.name, "length_m": court.length_m, "width_m": court.width_m,
        "floor_half_extent_m": list(court.floor_half_extent_m),
        "background": "#%02x%02x%02x" % court.rgb(court.outside_colour),
        "rings": [{"x": r.x, "y": r.y} for r in court.rings], "elements": elements,
    }


def _newest(values: Iterable[Any], n: int) -> list[Any]:
    """The last `n` items of a list or deque without copying the rest (the watcher keeps 100k)."""
    return list(islice(reversed(values), n))  # type: ignore[call-overload]


def _finite(value: float | None, digits: int = 4) -> float | None:
    return round(value, digits) if value is not None and math.isfinite(value) else None


def _pose_json(pose: Pose, received_at: float | None, now: float) -> dict[str, Any]:
    return {
        "x": _finite(pose.x), "y": _finite(pose.y), "yaw": _finite(pose.yaw), "valid": pose.header.valid,
        "quality": _finite(pose.quality), "seq": pose.header.seq, "model_name": pose.model_name,
        "model_version": pose.model_version, "infer_ms": _finite(pose.infer_ms, 3), "reason": pose.reason,
        "age_s": None if received_at is None else round(now - received_at, 3),
    }


class Snapshotter:
    """Builds the page's state from the watcher and the thumbnailer (called from the ticker thread)."""

    def __init__(self, watcher: MonitorWatcher, thumbnailer: Thumbnailer) -> None:
        self.watcher = watcher
        self.thumbnailer = thumbnailer
        self._connected = False
        self._connected_checked = 0.0

    def connected(self, now: float) -> bool:
        if now - self._connected_checked >= 0.5:  # asking zenoh is cheap, but not needed 20x a second
            self._connected = self.watcher.connected()
            self._connected_checked = now
        return self._connected

    def snapshot(self) -> dict[str, Any]:
        now = time.monotonic()
        w = self.watcher
        received = dict(w.received_at)
        with w.locked() as state:
            pose, solution = state.last_pose, state.last_solution
            truth, shadow = w.last_truth, w.shadow_pose
            trail = list(w.trail)[-TRAIL_SENT:]
            truth_trail = list(w.truth_trail)[-TRAIL_SENT:]
            health = dict(state.health)
            alive = set(state.alive)
            errors = _newest(state.pose_errors_m, 60)
            e2e = _newest(state.e2e_ns, 300)
            undecodable = state.undecodable
        pose_age = None if "infer/pose" not in received else now - received["infer/pose"]
        connected = self.connected(now)
        stages = []
        for name in SERVICES:
            h = health.get(name)
            health_age = None if name not in w.health_at else now - w.health_at[name]
            stages.append({
                "name": name, "alive": name in alive,
                "health_age_s": None if health_age is None else round(health_age, 2),
                "silent": health_age is None or health_age > HEALTH_STALE_S,
                **({} if h is None else {
                    "rate_in_hz": round(h.rate_in_hz, 2), "rate_out_hz": round(h.rate_out_hz, 2),
                    "latency_ms_p50": round(h.latency_ms_p50, 3), "latency_ms_p99": round(h.latency_ms_p99, 3),
                    "rejected": h.rejected, "dropped": h.dropped, "stale": h.stale, "last_error": h.last_error,
                    "frames_out": h.frames_out}),
            })
        thumb = self.thumbnailer.latest
        if not connected:
            status = "disconnected"
        elif pose_age is None or pose_age > POSE_STALE_S:
            status = "stale"
        else:
            status = "live"
        return {
            "robot_id": w.config.robot_id, "wall_ns": time.time_ns(), "connected": connected, "status": status,
            "pose": None if pose is None else _pose_json(pose, received.get("infer/pose"), now),
            "truth": None if truth is None else {"x": _finite(truth.x), "y": _finite(truth.y),
                                                 "yaw": _finite(truth.yaw), "seq": truth.header.seq},
            "shadow": None if shadow is None else _pose_json(shadow, received.get("infer/shadow_pose"), now),
            "trail": [[round(x, 3), round(y, 3)] for x, y in trail],
            "truth_trail": [[round(x, 3), round(y, 3)] for x, y in truth_trail],
            "solution": None if solution is None else {
                "distance_m": _finite(solution.distance_m, 3), "rpm": _finite(solution.rpm, 1),
                "bearing_rad": _finite(solution.bearing_rad), "command": solution.command,
                "reason": solution.reason, "valid": solution.header.valid,
                "age_s": round(now - received["shooter_bridge/solution"], 3)
                if "shooter_bridge/solution" in received else None},
            "error_m_median": round(float(np.median(errors)), 4) if errors else None,
            "e2e_ms_p50": round(float(np.median(e2e)) / 1e6, 3) if e2e else None,
            "stages": stages,
            "thumb": None if thumb is None else {"id": thumb.ident, "seq": thumb.seq, "source": thumb.source,
                                                 "n_hits": thumb.n_hits, "age_s": round(now - thumb.made_at, 2)},
            "frames_subscribed": w.frames_subscribed,
            "undecodable": undecodable,
        }
