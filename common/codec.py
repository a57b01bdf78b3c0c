"""One msgpack codec for every bus message.

Decoding never raises anything but `DecodeError`, whose `reason` is short and stable so it can be
counted per topic ("too_large", "schema_version", "truncated", "invalid", ...).

Fields are checked, not coerced (pydantic strict mode): `"yes"` is not a bool and `"640"` not an int;
a peer that sends the wrong type is refused, not guessed at.
"""
from __future__ import annotations

from typing import Any, TypeVar

import msgpack
from pydantic import BaseModel, ValidationError

from courtloc.common.messages import SCHEMA_VERSION

M = TypeVar("M", bound=BaseModel)


class DecodeError(ValueError):
    def __init__(self, reason: str, detail: str) -> None:
        super().__init__(f"{reason}: {detail}")
        self.reason = reason
        self.detail = detail


def check_size(n_bytes: int, max_bytes: int) -> None:
    """Refuse a payload bigger than the contract allows, before it is copied or unpacked."""
    if n_bytes > max_bytes:
        raise DecodeError("too_large", f"{n_bytes} bytes, the limit is {max_bytes}")


def encode(message: BaseModel) -> bytes:
    return msgpack.packb(message.model_dump(), use_bin_type=True)


def decode(payload: bytes | bytearray | memoryview, message_type: type[M], max_bytes: int | None = None) -> M:
    """`payload` as `message_type`; with `max_bytes`, a bigger payload is refused before it is unpacked."""
    if max_bytes is not None:
        check_size(len(payload), max_bytes)
    try:
        raw: Any = msgpack.unpackb(payload, raw=False, strict_map_key=True)
    except (msgpack.ExtraData, ValueError, msgpack.UnpackException) as exc:
        # msgpack signals a short buffer as ValueError("Unpack failed: incomplete input")
        reason = "truncated" if "incomplete" in str(exc) else "not_msgpack"
        raise DecodeError(reason, str(exc)) from None
    except Exception as exc:  # msgpack may raise TypeError/OverflowError on hostile input
        raise DecodeError("not_msgpack", repr(exc)) from None
    if not isinstance(raw, dict):
        raise DecodeError("not_a_map", f"expected a map, got {type(raw).__name__}")
    holder = raw.get("header", raw)
    version = holder.get("schema_version") if isinstance(holder, dict) else None
    if version != SCHEMA_VERSION:
        raise DecodeError("schema_version", f"got {version!r}, this build speaks {SCHEMA_VERSION}")
    try:
        return message_type.model_validate(raw, strict=True)
    except ValidationError as exc:
        first = exc.errors()[0]
        where = ".".join(str(p) for p in first["loc"])
        raise DecodeError("invalid", f"{message_type.__name__}.{where}: {first['msg']}") from None
