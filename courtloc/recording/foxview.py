"""The Foxglove channels of a recording: poses as foxglove.PoseInFrame, the robot and camera as TF
(foxglove.FrameTransform), the court as a foxglove.SceneUpdate (once per file), the hits as
foxglove.ImageAnnotations on the camera image. They sit beside the courtloc JSON view in the same file.

Topics (robot id `r`): `courtloc/r/<service>/<topic>/in_frame` for each pose topic, `courtloc/r/tf`,
`courtloc/r/scene`, `courtloc/r/preprocess/edges/annotations`. The live server (courtloc.foxglove.live)
uses the same names, so one Foxglove layout (deploy/foxglove/) serves a recording and a live robot.
"""
from __future__ import annotations

import json
from dataclasses import dataclass
from typing import Any

from pydantic import BaseModel

from courtloc.common.messages import Edges, GroundTruth, Pose
from courtloc.common.services_table import ROOT, TOPICS
from courtloc.foxglove import scene
from courtloc.monitor.state import court_payload
from courtloc.world.camera import load_camera
from courtloc.world.court import load_court

POSE_TOPICS = frozenset({"infer/pose", "infer/shadow_pose", "camera/ground_truth"})


@dataclass(frozen=True)
class TopicView:
    """One extra JSON message: its MCAP topic, Foxglove schema name and JSON bytes."""

    topic: str
    schema_name: str
    data: bytes


def _view(topic: str, schema_name: str, body: dict[str, Any]) -> TopicView:
    return TopicView(topic, schema_name, json.dumps(body, separators=(",", ":"), allow_nan=False).encode())


def pose_topic(path: str, robot_id: str) -> str:
    return TOPICS[path].key(robot_id) + "/in_frame"


def hits_topic(robot_id: str) -> str:
    return TOPICS["preprocess/edges"].key(robot_id) + "/annotations"


def tf_topic(robot_id: str) -> str:
    return f"{ROOT}/{robot_id}/tf"


def scene_topic(robot_id: str) -> str:
    return f"{ROOT}/{robot_id}/scene"


@dataclass(frozen=True)
class FoxgloveViews:
    """What a recording needs to draw a robot in Foxglove's 3D panel: the court and the camera's place."""

    court_drawing: dict[str, Any]
    rings: tuple[tuple[float, float, float], ...]
    camera: scene.CameraPlacement

    @classmethod
    def load(cls, court_name: str, camera_name: str | None = None) -> "FoxgloveViews":
        """From the packaged court and camera models (the camera defaults to the court's)."""

        court = load_court(court_name)
        camera = load_camera(camera_name or court.default_camera)
        return cls(court_payload(court), tuple((r.x, r.y, r.z) for r in court.rings),
                   scene.CameraPlacement.from_camera_model(camera))

    def of(self, path: str, robot_id: str, message: BaseModel) -> list[TopicView]:
        views: list[TopicView] = []
        if path in POSE_TOPICS and isinstance(message, (Pose, GroundTruth)):
            in_frame = scene.pose_in_frame(message)
            if in_frame is not None:
                views.append(_view(pose_topic(path, robot_id), "foxglove.PoseInFrame", in_frame))
            if path == "infer/pose" and isinstance(message, Pose):
                transform = scene.robot_transform(message)
                if transform is not None:
                    views.append(_view(tf_topic(robot_id), "foxglove.FrameTransform", transform))
                    views.append(_view(tf_topic(robot_id), "foxglove.FrameTransform",
                                       scene.camera_transform(self.camera, message.header.capture_wall_ns)))
        elif path == "preprocess/edges" and isinstance(message, Edges):
            views.append(_view(hits_topic(robot_id), "foxglove.ImageAnnotations", scene.hit_annotations(message)))
        return views

    def preamble(self, robot_id: str, wall_ns: int) -> list[TopicView]:
        """Written first in every file: the court scene and the camera on the robot."""
        return [_view(scene_topic(robot_id), "foxglove.SceneUpdate", scene.court_scene(self.court_drawing, self.rings,
                                                                                        wall_ns)),
                _view(tf_topic(robot_id), "foxglove.FrameTransform", scene.camera_transform(self.camera, wall_ns))]
