"""The JSON view of bus messages, as Foxglove and other MCAP tools read it.

Foxglove's JSON encoding wants standard base64 strings for binary fields, flagged in the schema with
`"contentEncoding": "base64"`; pydantic's own base64 is the URL-safe alphabet, so bytes are converted
here. JSON has no NaN or infinity: non-finite floats become null in the view (the msgpack copy keeps
them exactly).

Every float of a courtloc schema is "number or null" for that reason.

Frames are the exception to "the view is the courtloc message": a base64 blob helps nobody, so a
Frame's view is Foxglove's own image message (`foxglove.CompressedImage` for JPEG, `foxglove.RawImage`
for raw BGR), which Foxglove's Image panel shows. The full Frame, header included, stays on the
msgpack channel.
"""
from __future__ import annotations

import base64
import json
import math
from dataclasses import dataclass
from functools import lru_cache
from typing import Any

from pydantic import BaseModel

from courtloc.common.messages import Frame
from courtloc.common.services_table import TOPICS
from courtloc.foxglove.schemas import is_foxglove, schema_bytes


@dataclass(frozen=True)
class JsonView:
    schema_name: str
    data: bytes

    @property
    def schema(self) -> bytes:
        return schema_data(self.schema_name)


def schema_name(message_type: type[BaseModel]) -> str:
    return f"courtloc.{message_type.__name__}"


def _message_types() -> dict[str, type[BaseModel]]:
    return {schema_name(t.message): t.message for t in TOPICS.values()}


@lru_cache(maxsize=None)
def schema_data(name: str) -> bytes:
    """JSON Schema bytes of a courtloc message type or of a Foxglove image type, by schema name."""
    if is_foxglove(name):
        return schema_bytes(name)
    message_type = _message_types()[name]
    schema = message_type.model_json_schema(mode="serialization")
    schema["title"] = name
    return json.dumps(_nullable_numbers(_mark_binary(schema)), sort_keys=True).encode()


def _nullable_numbers(node: Any) -> Any:
    """Every float field may be null in the view (JSON has no NaN or infinity, see _jsonable), so the
    schema says so: a ShotSolution without a distance (NaN) is then valid against its own schema."""
    if isinstance(node, dict):
        if node.get("type") == "number":
            rest = {k: v for k, v in node.items() if k != "type"}
            return {**rest, "anyOf": [{"type": "number"}, {"type": "null"}]}
        if any(isinstance(o, dict) and o.get("type") == "null" for o in node.get("anyOf", [])):
            return node  # already nullable (an Optional field)
        return {k: _nullable_numbers(v) for k, v in node.items()}
    if isinstance(node, list):
        return [_nullable_numbers(v) for v in node]
    return node


def _mark_binary(node: Any) -> Any:
    if isinstance(node, dict):
        if node.get("type") == "string" and node.get("format") in ("binary", "base64", "base64url"):
            # maxLength counts bytes in the contract, not base64 characters: the text is longer
            node = {k: v for k, v in node.items() if k not in ("format", "maxLength")}
            node["contentEncoding"] = "base64"
        return {k: _mark_binary(v) for k, v in node.items()}
    if isinstance(node, list):
        return [_mark_binary(v) for v in node]
    return node


def json_view(message: BaseModel, source: str = "camera") -> JsonView:
    """The view of one message; `source` becomes a Frame's `frame_id` (the topic's service)."""
    if isinstance(message, Frame):
        return _image_view(message, source)
    return JsonView(schema_name(type(message)), _dumps(_jsonable(message.model_dump())))


def _image_view(frame: Frame, source: str) -> JsonView:
    wall = frame.header.capture_wall_ns
    body: dict[str, Any] = {"timestamp": {"sec": wall // 1_000_000_000, "nsec": wall % 1_000_000_000},
                            "frame_id": source, "data": base64.b64encode(frame.data).decode("ascii")}
    if frame.encoding == "jpeg":
        return JsonView("foxglove.CompressedImage", _dumps({**body, "format": "jpeg"}))
    return JsonView("foxglove.RawImage", _dumps({**body, "width": frame.width, "height": frame.height,
                                                 "encoding": "bgr8", "step": frame.width * 3}))


def _dumps(value: Any) -> bytes:
    return json.dumps(value, separators=(",", ":"), allow_nan=False).encode()


def _jsonable(value: Any) -> Any:
    if isinstance(value, dict):
        return {k: _jsonable(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [_jsonable(v) for v in value]
    if isinstance(value, (bytes, bytearray, memoryview)):
        return base64.b64encode(bytes(value)).decode("ascii")
    if isinstance(value, float) and not math.isfinite(value):
        return None
    return value
