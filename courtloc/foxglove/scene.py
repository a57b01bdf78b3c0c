"""A robot on its court as Foxglove messages (plain dicts matching courtloc.foxglove.schemas).

Frames: `court` (origin at the centre, x along the long side, z up), `base_link` (the pose point on the
floor, x forward) and `camera` (the optical frame Foxglove's image panel expects: x right, y down, z
forward). court -> base_link comes from each valid pose; base_link -> camera from the camera model.
The same builders feed MCAP recordings and the live server, so both look the same in Foxglove.
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any, Iterable, Sequence

import numpy as np

from courtloc.common.messages import Edges, GroundTruth, Pose
from courtloc.common.payloads import hits_from_bytes

COURT_FRAME = "court"
ROBOT_FRAME = "base_link"
CAMERA_FRAME = "camera"
RING_RADIUS_M = 0.225  # FIBA ring: 450 mm inner diameter
LINE_THICKNESS_M = 0.05
DEFAULT_FOOTPRINT_M = (0.8, 0.8, 0.4)  # length, width, height of the drawn robot box

WHITE = {"r": 1.0, "g": 1.0, "b": 1.0, "a": 1.0}
ORANGE = {"r": 1.0, "g": 0.45, "b": 0.0, "a": 1.0}
ROBOT_COLOUR = {"r": 0.1, "g": 0.5, "b": 1.0, "a": 0.5}
HIT_COLOUR = {"r": 1.0, "g": 0.1, "b": 0.1, "a": 1.0}
IDENTITY = {"x": 0.0, "y": 0.0, "z": 0.0, "w": 1.0}
ORIGIN_POSE = {"position": {"x": 0.0, "y": 0.0, "z": 0.0}, "orientation": IDENTITY}


def stamp(ns: int) -> dict[str, int]:
    return {"sec": ns // 1_000_000_000, "nsec": ns % 1_000_000_000}


def yaw_quaternion(yaw: float) -> dict[str, float]:
    return {"x": 0.0, "y": 0.0, "z": math.sin(yaw / 2), "w": math.cos(yaw / 2)}


def matrix_quaternion(rotation: np.ndarray) -> dict[str, float]:
    """Unit quaternion of a proper rotation matrix (largest-diagonal branch for numerical safety)."""
    m = np.asarray(rotation, float)
    trace = m[0, 0] + m[1, 1] + m[2, 2]
    if trace > 0:
        s = 2.0 * math.sqrt(1.0 + trace)
        q = (0.25 * s, (m[2, 1] - m[1, 2]) / s, (m[0, 2] - m[2, 0]) / s, (m[1, 0] - m[0, 1]) / s)
    elif m[0, 0] > m[1, 1] and m[0, 0] > m[2, 2]:
        s = 2.0 * math.sqrt(1.0 + m[0, 0] - m[1, 1] - m[2, 2])
        q = ((m[2, 1] - m[1, 2]) / s, 0.25 * s, (m[0, 1] + m[1, 0]) / s, (m[0, 2] + m[2, 0]) / s)
    elif m[1, 1] > m[2, 2]:
        s = 2.0 * math.sqrt(1.0 + m[1, 1] - m[0, 0] - m[2, 2])
        q = ((m[0, 2] - m[2, 0]) / s, (m[0, 1] + m[1, 0]) / s, 0.25 * s, (m[1, 2] + m[2, 1]) / s)
    else:
        s = 2.0 * math.sqrt(1.0 + m[2, 2] - m[0, 0] - m[1, 1])
        q = ((m[1, 0] - m[0, 1]) / s, (m[0, 2] + m[2, 0]) / s, (m[1, 2] + m[2, 1]) / s, 0.25 * s)
    w, x, y, z = q
    return {"x": float(x), "y": float(y), "z": float(z), "w": float(w)}


@dataclass(frozen=True)
class CameraPlacement:
    """Where the camera sits on the robot: optical frame axes in robot axes, and its position (m)."""

    rotation: tuple[tuple[float, ...], ...]
    translation: tuple[float, float, float]

    @classmethod
    def from_camera_model(cls, camera: Any) -> "CameraPlacement":
        """From a camera model (courtloc.world.camera.CameraModel or anything with the same two methods)."""
        rotation = np.asarray(camera.robot_from_camera_rotation(), float)
        x, y, z = (float(v) for v in camera.camera_position())
        return cls(tuple(tuple(float(v) for v in row) for row in rotation), (x, y, z))


def _finite_pose(message: Pose | GroundTruth) -> tuple[float, float, float] | None:
    yaw = message.yaw if message.yaw is not None else 0.0
    if not all(math.isfinite(v) for v in (message.x, message.y, yaw)):
        return None
    return message.x, message.y, yaw


def pose_in_frame(message: Pose | GroundTruth) -> dict[str, Any] | None:
    """foxglove.PoseInFrame in the court frame, or None when x, y or yaw is not a number.

    A pose without yaw (a position-only model) is drawn facing +x.
    """
    pose = _finite_pose(message)
    if pose is None:
        return None
    x, y, yaw = pose
    return {"timestamp": stamp(message.header.capture_wall_ns), "frame_id": COURT_FRAME,
            "pose": {"position": {"x": x, "y": y, "z": 0.0}, "orientation": yaw_quaternion(yaw)}}


def robot_transform(message: Pose) -> dict[str, Any] | None:
    """foxglove.FrameTransform court -> base_link from a pose its producer marked valid, else None: the
    robot in the 3D panel stays where it was last known rather than jumping to a pose nobody trusts."""
    pose = _finite_pose(message)
    if pose is None or not message.header.valid:
        return None
    x, y, yaw = pose
    return {"timestamp": stamp(message.header.capture_wall_ns), "parent_frame_id": COURT_FRAME,
            "child_frame_id": ROBOT_FRAME, "translation": {"x": x, "y": y, "z": 0.0},
            "rotation": yaw_quaternion(yaw)}


def camera_transform(camera: CameraPlacement, wall_ns: int) -> dict[str, Any]:
    """foxglove.FrameTransform base_link -> camera (the optical frame)."""
    x, y, z = camera.translation
    return {"timestamp": stamp(wall_ns), "parent_frame_id": ROBOT_FRAME, "child_frame_id": CAMERA_FRAME,
            "translation": {"x": x, "y": y, "z": z}, "rotation": matrix_quaternion(np.array(camera.rotation))}


def _entity(entity_id: str, frame_id: str, wall_ns: int, **primitives: list[dict[str, Any]]) -> dict[str, Any]:
    entity: dict[str, Any] = {"timestamp": stamp(wall_ns), "frame_id": frame_id, "id": entity_id,
                              "lifetime": {"sec": 0, "nsec": 0}, "frame_locked": frame_id != COURT_FRAME,
                              "metadata": []}
    for kind in ("arrows", "cubes", "spheres", "cylinders", "lines", "triangles", "texts", "models"):
        entity[kind] = primitives.get(kind, [])
    return entity


def _line(points: Iterable[Sequence[float]], colour: dict[str, float], z: float = 0.0,
          loop: bool = True) -> dict[str, Any]:
    return {"type": 1 if loop else 0, "pose": ORIGIN_POSE, "thickness": LINE_THICKNESS_M, "scale_invariant": False,
            "points": [{"x": float(p[0]), "y": float(p[1]), "z": z} for p in points], "color": colour,
            "colors": [], "indices": []}


def _circle(x: float, y: float, z: float, radius: float, n: int = 32) -> list[tuple[float, float]]:
    return [(x + radius * math.cos(2 * math.pi * i / n), y + radius * math.sin(2 * math.pi * i / n)) for i in range(n)]


def court_scene(court_drawing: dict[str, Any], rings: Sequence[tuple[float, float, float]], wall_ns: int,
                footprint_m: tuple[float, float, float] = DEFAULT_FOOTPRINT_M) -> dict[str, Any]:
    """foxglove.SceneUpdate: the court's white lines and rings (frame court) and the robot's footprint
    (a box in base_link, so it follows the TF).

    `court_drawing` is the monitor's simplified court (courtloc.monitor.state.court_payload): the same
    polygons the pit page draws.
    """
    half_x, half_y = court_drawing["floor_half_extent_m"]
    lines = [_line([(-half_x, -half_y), (half_x, -half_y), (half_x, half_y), (-half_x, half_y)],
                   {"r": 0.5, "g": 0.5, "b": 0.5, "a": 1.0})]
    for element in court_drawing["elements"]:
        if element["white"]:
            lines += [_line(poly, WHITE) for poly in element["exteriors"]]
    ring_lines = [_line(_circle(x, y, z, RING_RADIUS_M), ORANGE, z=z) for x, y, z in rings]
    ring_poles = [{"pose": {"position": {"x": x, "y": y, "z": z / 2}, "orientation": IDENTITY},
                   "size": {"x": 0.05, "y": 0.05, "z": z}, "bottom_scale": 1.0, "top_scale": 1.0,
                   "color": {"r": 0.6, "g": 0.6, "b": 0.6, "a": 1.0}} for x, y, z in rings]
    length, width, height = footprint_m
    robot = {"pose": {"position": {"x": 0.0, "y": 0.0, "z": height / 2}, "orientation": IDENTITY},
             "size": {"x": length, "y": width, "z": height}, "color": ROBOT_COLOUR}
    heading = {"pose": {"position": {"x": 0.0, "y": 0.0, "z": height}, "orientation": IDENTITY},
               "shaft_length": length * 0.6, "shaft_diameter": 0.04, "head_length": 0.15, "head_diameter": 0.1,
               "color": ORANGE}
    return {"deletions": [], "entities": [
        _entity("court", COURT_FRAME, wall_ns, lines=lines + ring_lines, cylinders=ring_poles),
        _entity("robot", ROBOT_FRAME, wall_ns, cubes=[robot], arrows=[heading]),
    ]}


def hit_annotations(edges: Edges) -> dict[str, Any]:
    """foxglove.ImageAnnotations: the radial-scan hits as points on the camera image (same timestamp as
    the frame, so the image panel overlays them)."""
    hits = hits_from_bytes(edges.hits)[: edges.n_hits]
    points = [{"x": float(col) + 0.5, "y": float(row) + 0.5} for row, col in hits[:, :2].tolist()]
    annotation = {"timestamp": stamp(edges.header.capture_wall_ns), "type": 1, "points": points,
                  "outline_color": HIT_COLOUR, "outline_colors": [], "fill_color": HIT_COLOUR, "thickness": 3.0}
    return {"circles": [], "points": [annotation] if points else [], "texts": []}
