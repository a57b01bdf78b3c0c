"""JSON Schemas of the Foxglove message types courtloc writes, with the fields Foxglove documents.

Foxglove reads a JSON-encoded MCAP channel through the schema stored with it and recognises its own
types by schema name (`foxglove.PoseInFrame` ...). Every field is listed as required and nothing else is
allowed: what we write is always complete, and a typo in a builder fails validation in the tests instead
of silently vanishing from the 3D panel. Enums are integers, binary data is standard base64.
"""
from __future__ import annotations

import json
from functools import lru_cache
from typing import Any

_NUMBER = {"type": "number"}
_INT = {"type": "integer"}
_STRING = {"type": "string"}
_BOOL = {"type": "boolean"}
_BASE64 = {"type": "string", "contentEncoding": "base64"}


def _object(title: str, **properties: Any) -> dict[str, Any]:
    return {"type": "object", "title": title, "properties": properties, "required": list(properties),
            "additionalProperties": False}


def _array(items: dict[str, Any]) -> dict[str, Any]:
    return {"type": "array", "items": items}


def _enum(*values: int) -> dict[str, Any]:
    return {"type": "integer", "enum": list(values)}


TIME = _object("time", sec={"type": "integer", "minimum": 0},
               nsec={"type": "integer", "minimum": 0, "maximum": 999_999_999})
DURATION = _object("duration", sec=_INT, nsec={"type": "integer", "minimum": 0, "maximum": 999_999_999})
VECTOR3 = _object("foxglove.Vector3", x=_NUMBER, y=_NUMBER, z=_NUMBER)
POINT3 = _object("foxglove.Point3", x=_NUMBER, y=_NUMBER, z=_NUMBER)
POINT2 = _object("foxglove.Point2", x=_NUMBER, y=_NUMBER)
QUATERNION = _object("foxglove.Quaternion", x=_NUMBER, y=_NUMBER, z=_NUMBER, w=_NUMBER)
POSE = _object("foxglove.Pose", position=VECTOR3, orientation=QUATERNION)
COLOR = _object("foxglove.Color", r=_NUMBER, g=_NUMBER, b=_NUMBER, a=_NUMBER)
KEY_VALUE = _object("foxglove.KeyValuePair", key=_STRING, value=_STRING)

CUBE = _object("foxglove.CubePrimitive", pose=POSE, size=VECTOR3, color=COLOR)
CYLINDER = _object("foxglove.CylinderPrimitive", pose=POSE, size=VECTOR3, bottom_scale=_NUMBER, top_scale=_NUMBER,
                   color=COLOR)
LINE = _object("foxglove.LinePrimitive", type=_enum(0, 1, 2), pose=POSE, thickness=_NUMBER, scale_invariant=_BOOL,
               points=_array(POINT3), color=COLOR, colors=_array(COLOR), indices=_array(_INT))
TEXT = _object("foxglove.TextPrimitive", pose=POSE, billboard=_BOOL, font_size=_NUMBER, scale_invariant=_BOOL,
               color=COLOR, text=_STRING)
ARROW = _object("foxglove.ArrowPrimitive", pose=POSE, shaft_length=_NUMBER, shaft_diameter=_NUMBER,
                head_length=_NUMBER, head_diameter=_NUMBER, color=COLOR)
SPHERE = _object("foxglove.SpherePrimitive", pose=POSE, size=VECTOR3, color=COLOR)
TRIANGLES = _object("foxglove.TriangleListPrimitive", pose=POSE, points=_array(POINT3), color=COLOR,
                    colors=_array(COLOR), indices=_array(_INT))
MODEL = _object("foxglove.ModelPrimitive", pose=POSE, scale=VECTOR3, color=COLOR, override_color=_BOOL, url=_STRING,
                media_type=_STRING, data=_BASE64)
SCENE_ENTITY = _object(
    "foxglove.SceneEntity", timestamp=TIME, frame_id=_STRING, id=_STRING, lifetime=DURATION, frame_locked=_BOOL,
    metadata=_array(KEY_VALUE), arrows=_array(ARROW), cubes=_array(CUBE), spheres=_array(SPHERE),
    cylinders=_array(CYLINDER), lines=_array(LINE), triangles=_array(TRIANGLES), texts=_array(TEXT),
    models=_array(MODEL))
SCENE_DELETION = _object("foxglove.SceneEntityDeletion", timestamp=TIME, type=_enum(0, 1), id=_STRING)
POINTS_ANNOTATION = _object("foxglove.PointsAnnotation", timestamp=TIME, type=_enum(0, 1, 2, 3, 4),
                            points=_array(POINT2), outline_color=COLOR, outline_colors=_array(COLOR),
                            fill_color=COLOR, thickness=_NUMBER)

SCHEMAS: dict[str, dict[str, Any]] = {
    "foxglove.CompressedImage": _object("foxglove.CompressedImage", timestamp=TIME, frame_id=_STRING, data=_BASE64,
                                        format=_STRING),
    "foxglove.RawImage": _object("foxglove.RawImage", timestamp=TIME, frame_id=_STRING, width=_INT, height=_INT,
                                 encoding=_STRING, step=_INT, data=_BASE64),
    "foxglove.PoseInFrame": _object("foxglove.PoseInFrame", timestamp=TIME, frame_id=_STRING, pose=POSE),
    "foxglove.FrameTransform": _object("foxglove.FrameTransform", timestamp=TIME, parent_frame_id=_STRING,
                                       child_frame_id=_STRING, translation=VECTOR3, rotation=QUATERNION),
    "foxglove.SceneUpdate": _object("foxglove.SceneUpdate", deletions=_array(SCENE_DELETION),
                                    entities=_array(SCENE_ENTITY)),
    "foxglove.ImageAnnotations": _object("foxglove.ImageAnnotations", circles=_array(_object(
        "foxglove.CircleAnnotation", timestamp=TIME, position=POINT2, diameter=_NUMBER, thickness=_NUMBER,
        fill_color=COLOR, outline_color=COLOR)), points=_array(POINTS_ANNOTATION), texts=_array(_object(
            "foxglove.TextAnnotation", timestamp=TIME, position=POINT2, text=_STRING, font_size=_NUMBER,
            text_color=COLOR, background_color=COLOR))),
}


def is_foxglove(name: str) -> bool:
    return name in SCHEMAS


@lru_cache(maxsize=None)
def schema_bytes(name: str) -> bytes:
    return json.dumps(SCHEMAS[name], sort_keys=True).encode()
