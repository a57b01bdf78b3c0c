"""Model-control requests and replies (queries to the infer service's `infer/model` queryable).

Only the pit identity may send these (see the access rules derived from the services table).
"""
from __future__ import annotations

from typing import Annotated, Literal, Optional, Union

from pydantic import BaseModel, ConfigDict, Field

from courtloc.common.messages import SCHEMA_VERSION


class _Msg(BaseModel):
    model_config = ConfigDict(extra="forbid")
    schema_version: int = SCHEMA_VERSION


class FileSpec(BaseModel):
    model_config = ConfigDict(extra="forbid")
    path: str = Field(pattern=r"^[A-Za-z0-9_.-]+$", description="a plain file name inside the model folder")
    size: int = Field(ge=0)
    sha256: str = Field(pattern=r"^[0-9a-f]{64}$")


class PushBegin(_Msg):
    op: Literal["push_begin"] = "push_begin"
    files: list[FileSpec] = Field(min_length=1)


class PushChunk(_Msg):
    op: Literal["push_chunk"] = "push_chunk"
    upload_id: str
    file_index: int = Field(ge=0)
    offset: int = Field(ge=0)
    data: bytes


class PushCommit(_Msg):
    op: Literal["push_commit"] = "push_commit"
    upload_id: str
    activate: bool = True


class ListModels(_Msg):
    op: Literal["list"] = "list"


class Activate(_Msg):
    op: Literal["activate"] = "activate"
    name: Optional[str] = None  # default: the active model's name
    version: int = Field(ge=1)


class Rollback(_Msg):
    op: Literal["rollback"] = "rollback"


class Shadow(_Msg):
    op: Literal["shadow"] = "shadow"
    name: Optional[str] = None
    version: Optional[int] = Field(default=None, ge=1, description="None stops shadow mode")


ModelRequestBody = Annotated[
    Union[PushBegin, PushChunk, PushCommit, ListModels, Activate, Rollback, Shadow], Field(discriminator="op")]


class ModelRequest(_Msg):
    body: ModelRequestBody


class ModelInfo(BaseModel):
    model_config = ConfigDict(extra="forbid")
    name: str
    version: int
    input_kind: str
    size_bytes: int
    active: bool = False
    shadow: bool = False


class ShadowStats(BaseModel):
    model_config = ConfigDict(extra="forbid")
    name: str
    version: int
    n: int = 0
    mean_diff_m: float = 0.0
    p95_diff_m: float = 0.0
    max_diff_m: float = 0.0
    yaw_mean_diff_deg: float = 0.0


class ModelReply(_Msg):
    ok: bool
    reason: str = ""
    upload_id: str = ""
    received: list[int] = Field(default_factory=list, description="bytes already stored per file (resume)")
    name: str = ""
    version: int = 0
    models: list[ModelInfo] = Field(default_factory=list)
    shadow: Optional[ShadowStats] = None


class SetPose(_Msg):
    """The pit tells the robot where it is (like an initial-pose tool): court metres, heading in radians CCW
    from +x, each with how well it is known. The localizer takes it as evidence, confirmed against the view."""

    op: Literal["set_pose"] = "set_pose"
    x: float = Field(allow_inf_nan=False)
    y: float = Field(allow_inf_nan=False)
    yaw: float = Field(allow_inf_nan=False, description="radians")
    std_m: float = Field(0.3, gt=0, le=20, allow_inf_nan=False)
    yaw_std_rad: float = Field(0.2, gt=0, le=3.2, allow_inf_nan=False)


class PoseRequest(_Msg):
    body: SetPose


class PoseReply(_Msg):
    ok: bool
    reason: str = ""
