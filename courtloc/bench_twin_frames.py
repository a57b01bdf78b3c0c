"""The frames a twin run's infer stage answered, kept to replay that run in one process (`bench twin --keep-frames`).

Through the chain, which frames the infer stage reaches (its bounded inbox drops those it had not reached) and
their capture times are the chain's own; the sweep's in-process walks choose theirs. A valid-and-wrong pose seen once
through the chain (the robocon2025 suite, vision only, `drive`, twenty-fifth session) could not be traced for want of
its inputs. The kept file holds, in order, every frame the stage answered with its capture stamps, hits and colour
marks, the truth of that frame and the pose published, so `replay` steps a fresh tracker through the same input, as
openpilot's process replay does, and a trace of the localizer can be taken on it.

With fusion each frame also keeps the odometry messages the stage took in before answering it (`Pose.odometry_seqs`
names them; the bench has them from the bridge's topic), offered to the replay's fusion in the same order.
"""
from __future__ import annotations

import json
from pathlib import Path
from typing import Optional

import numpy as np
from pydantic import BaseModel, ConfigDict, Field

from courtloc.common.messages import HOST, Odometry
from courtloc.localizer.odometry_fusion import FusionConfig, OdometryFusion
from courtloc.localizer.package import bundled_package
from courtloc.localizer.predictor import Prediction, load_predictor
from courtloc.localizer.tracking import Tracker
from courtloc.services.infer.config import StartConfig
from courtloc.services.infer.service import start_prior


class KeptFrame(BaseModel):
    """One frame the infer stage answered: its input and what it published."""

    model_config = ConfigDict(extra="forbid")
    capture_ns: int = Field(description="the frame's capture time on the camera's monotonic clock")
    capture_wall_ns: int
    hits: list[int] = Field(description="the edge hits, flattened rows of (row, col, ray, d)")
    marks: list[int] = Field(default_factory=list, description="the colour marks, flattened rows of (row, col, mark)")
    truth: Optional[list[float]] = Field(None, description="(x, y, yaw) of the twin's robot at this frame")
    pose: list[Optional[float]] = Field(description="the published (x, y, yaw)")
    valid: bool
    reason: str = ""
    odometry: list[Odometry] = Field(default_factory=list, description="the odometry the stage took in before "
                                     "answering this frame, in order (fused runs)")


class KeptRun(BaseModel):
    """One run's kept frames and what the replay needs to step them as the infer stage did."""

    model_config = ConfigDict(extra="forbid")
    command: str
    scenario: str
    court: str
    camera: str
    fused: bool
    start: Optional[StartConfig] = Field(None, description="the infer stage's [infer] start, as configured")
    fusion: Optional[FusionConfig] = Field(None, description="the infer stage's [infer.fusion] (fused runs)")
    size: list[int] = Field(description="(width, height) of the frames")
    dropped: int = Field(0, description="frames before the run's last answer whose edges the bench saw and the infer "
                         "stage did not answer (its bounded inbox pushed them out)")
    odometry_unkept: int = Field(0, description="odometry messages the stage took in that the bench did not see (a "
                                 "replay of a fused run with any is not the run)")
    frames: list[KeptFrame]


def write_kept(path: Path, run: KeptRun) -> None:
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(run.model_dump_json() + "\n")


def read_kept(path: Path) -> KeptRun:
    return KeptRun.model_validate(json.loads(path.read_text()))


def replay(run: KeptRun) -> list[Prediction]:
    """The bundled localizer of the run's court and camera, stepped by a fresh tracker with the run's start (and, fused,
    a fresh odometry fusion taking in each frame's odometry first) through the frames the infer stage answered, as the
    stage steps it (`InferService.on_message`, `make_pose`). A frame the stage refused as stale stepped nothing: its
    answer here is an invalid one at the origin, as published."""
    if run.fused and run.fusion is None:
        raise ValueError(f"{run.scenario}: a fused run kept without its [infer.fusion] cannot be replayed")
    predictor = load_predictor(bundled_package(run.court, run.camera))
    tracker = Tracker(start=start_prior(run.start))
    fusion = OdometryFusion(run.fusion) if run.fused and run.fusion is not None else None
    width, height = run.size
    out = []
    for frame in run.frames:
        if fusion is not None:
            for message in frame.odometry:
                _take_in(fusion, message)
        if frame.reason == "stale_input":
            out.append(Prediction(x=0.0, y=0.0, quality=0.0, valid=False, reason="stale_input"))
            continue
        hits = np.asarray(frame.hits, dtype=np.int16).reshape(-1, 4)
        marks = np.asarray(frame.marks, dtype=np.int16).reshape(-1, 3)
        out.append(tracker.step(predictor, hits, width, height, t=frame.capture_ns * 1e-9, fusion=fusion,
                                capture_wall_ns=frame.capture_wall_ns, marks=marks))
    return out


def _take_in(fusion: OdometryFusion, message: Odometry) -> None:
    """Offer one kept message as the stage did: on this host (the kept stamps are one machine's monotonic clock,
    whichever replays them) and at about its publication, the bridge's stamp (the stage's clock when it took it in
    only judges stale and future messages, seconds off)."""
    header = message.header.model_copy(update={"capture_host": HOST})
    taken_ns = header.stamps[-1].mono_ns if header.stamps else header.capture_mono_ns
    fusion.offer(message.model_copy(update={"header": header}), taken_ns * 1e-9)
