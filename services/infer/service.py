"""Infer stage: edge hits -> pose, from the store's active model, with hot swap and shadow mode."""
from __future__ import annotations

import math
import time

import numpy as np
from pydantic import BaseModel

from courtloc.common.bus import ZenohConfig
from courtloc.common.control import ModelReply
from courtloc.common.inbox import Delivery
from courtloc.common.messages import Edges, Odometry, Pose
from courtloc.common.payloads import edges_hits
from courtloc.common.runtime import Service
from courtloc.common.services_table import Control, Topic
from courtloc.localizer.odometry_fusion import OdometryFusion, pose_covariance
from courtloc.localizer.predictor import GeometricPredictor
from courtloc.localizer.tracking import Tracker
from courtloc.models import bundled_package
from courtloc.services.infer.config import InferConfig
from courtloc.services.infer.engine import LoadedModel, load_model
from courtloc.services.infer.model_control import ModelControl
from courtloc.services.infer.shadow import ShadowRunner
from courtloc.services.infer.store import ModelRef, ModelStore, StoredModel
from courtloc.services.infer.uploads import Uploads
from courtloc.services.infer.validation import ModelRefused, is_on_court

DEFAULT_MODEL_NAME = "default"


class InferService(Service):
    name = "infer"
    side_inputs = frozenset({"shooter_bridge/odometry"})

    def __init__(self, robot_id: str, zenoh_config: ZenohConfig, config: InferConfig) -> None:
        super().__init__(robot_id, zenoh_config)
        self.config = config
        self.store = ModelStore(config.store)
        self.active: LoadedModel | None = None
        self.shadow: ShadowRunner | None = None
        self.tracker = Tracker()
        # Odometry fusion (localizer/odometry_fusion.py): None unless configured, then poses are as before.
        self.fusion = OdometryFusion(config.fusion) if config.fusion.enabled else None
        self.swaps = 0
        self._control = ModelControl(self, Uploads(self.store, int(config.max_upload_mb * 2**20),
                                                   max_open=config.max_open_uploads, ttl_s=config.upload_ttl_h * 3600))

    # ---- start-up ----------------------------------------------------------------------
    def on_start(self) -> None:
        self.active = self._load_active()
        self.log.info("serving model %s", self.active.ref)

    def _load_active(self) -> LoadedModel:
        """The store's active model; a fresh store gets the bundled default as version 1."""
        if self.store.record().active is None:
            stored = self.store.add_folder(bundled_package(), DEFAULT_MODEL_NAME)
            self.store.set_active(stored.ref)
        stored = self.store.active()
        assert stored is not None
        try:
            return load_model(stored, self.config)
        except ModelRefused as exc:
            # The active model was validated when it came in; if it is broken on disk now, roll back.
            self.record_error("model", f"active model {stored.ref} cannot load ({exc}); rolling back")
            target = self.store.rollback()
            return load_model(self.store.get(target), self.config)

    # ---- the hot path --------------------------------------------------------------------
    def on_message(self, topic: Topic, message: Edges | Odometry, delivery: Delivery) -> None:
        if isinstance(message, Odometry):  # fusion hook: odometry only fills the fusion's buffer
            if self.fusion is not None:
                self.fusion.offer(message, time.monotonic())
            return
        fresh = self.is_fresh(message.header, topic)
        try:
            hits = edges_hits(message)
        except ValueError as exc:
            self.reject(topic.path, "bad_hits", str(exc))
            return
        model = self.active  # one read: a swap between frames never splits a frame across two models
        assert model is not None
        if not fresh:
            # Old, or stamped in the future: never valid, and its capture time must not reach the
            # tracker's motion model (a frame "from" +1000 s would poison every later prediction).
            self.publish("infer/pose", Pose(header=message.header.forwarded(self.name, valid=False), x=0.0, y=0.0,
                                            model_name=model.ref.name, model_version=model.ref.version,
                                            infer_ms=0.0, reason="stale_input"))
            return
        pose = self.make_pose(model, message, hits, fresh=fresh, tracker=self.tracker)
        self.publish("infer/pose", pose)
        shadow = self.shadow
        if shadow is not None:
            shadow.offer(message, hits, pose)

    def make_pose(self, model: LoadedModel, edges: Edges, hits: np.ndarray, fresh: bool, tracker: Tracker) -> Pose:
        """The pose of one frame; `tracker` gives the start and learns from the result."""
        start = time.perf_counter()
        reason = ""
        x = y = 0.0
        yaw: float | None = None
        quality = 0.0
        ok = False
        # Fusion hook: the serving tracker (never a shadow's) of a geometric model predicts with odometry,
        # even through a blind frame.
        fusion = self.fusion if tracker is self.tracker and isinstance(model.predictor, GeometricPredictor) else None
        covariance: list[float] = []
        fusion_reason = ""
        if len(hits) == 0 and fusion is None:
            reason = "no_hits"
        else:
            # Capture times on the camera's monotonic clock: the filter predicts over the real interval.
            pred = tracker.step(model.predictor, hits, edges.width, edges.height,
                                t=edges.header.capture_mono_ns * 1e-9, fusion=fusion)
            fusion_reason = tracker.odometry_reason
            covariance = pose_covariance(tracker.motion)
            x, y, yaw, quality = float(pred.x), float(pred.y), pred.yaw, float(pred.quality)
            finite = all(math.isfinite(v) for v in (x, y, *(() if yaw is None else (yaw,))))
            if not finite:
                reason, x, y, yaw = "non_finite", 0.0, 0.0, None
            elif not is_on_court(model.court, x, y, self.config.on_court_margin_m):
                reason = "off_court"
            elif not pred.valid:
                reason = fusion_reason or ("no_hits" if len(hits) == 0 else "low_quality")
            ok = not reason
        if ok and not fresh:
            reason, ok = "stale_input", False
        if ok and not edges.header.valid:
            reason, ok = "invalid_input", False
        header = edges.header.forwarded(self.name, valid=ok)
        return Pose(header=header, x=x, y=y, yaw=None if yaw is None else float(yaw), quality=quality,
                    model_name=model.ref.name, model_version=model.ref.version,
                    infer_ms=(time.perf_counter() - start) * 1e3, reason=reason, covariance=covariance)

    # ---- model control (the runtime's control thread) -------------------------------------------
    def on_control(self, control: Control, request: BaseModel) -> BaseModel:
        return self._without_internals(self._control.handle(request))

    def _without_internals(self, reply: ModelReply) -> ModelReply:
        """The asker learns what went wrong, not where the robot keeps its files: the store's absolute
        folder becomes `<store>` in any text of the reply."""
        reason = reply.reason
        for root in {str(self.store.root.resolve()), str(self.store.root)}:
            reason = reason.replace(root, "<store>")
        return reply if reason == reply.reason else reply.model_copy(update={"reason": reason})

    # ModelHost, for ModelControl
    def validate(self, stored: StoredModel, pushed: bool = False) -> LoadedModel:
        return load_model(stored, self.config, validate=True, pushed=pushed)

    def swap_in(self, model: LoadedModel) -> None:
        old, self.active = self.active, model  # one reference assignment: the worker sees the old or the new model
        if old is None or old.manifest.court != model.manifest.court:
            # The previous pose is in court coordinates: the new model of the same court tracks on from it
            # (a cold-start search takes several frame periods, and frames would be skipped meanwhile).
            self.tracker.reset()
        self.swaps += 1
        self.log.info("now serving model %s", model.ref)

    def start_shadow(self, model: LoadedModel | None) -> None:
        old, self.shadow = self.shadow, None
        if old is not None:
            old.stop()
        if model is not None:
            self.shadow = ShadowRunner(model, lambda pose: self.publish("infer/shadow_pose", pose),
                                       lambda m, edges, hits, tracker: self.make_pose(m, edges, hits, True, tracker))

    def active_ref(self) -> ModelRef | None:
        return self.active.ref if self.active is not None else None

    def shadow_reply(self) -> ModelReply:
        shadow = self.shadow
        if shadow is None:
            return ModelReply(ok=False, reason="no shadow model")
        stats = shadow.stats()
        return ModelReply(ok=True, name=stats.name, version=stats.version, shadow=stats)

    def on_stop(self) -> None:
        self.start_shadow(None)

    def health_detail(self) -> dict[str, float | int | str]:
        model = self.active
        detail: dict[str, float | int | str] = {"swaps": self.swaps}
        if model is not None:
            detail.update(model=model.ref.name, model_version=model.ref.version)
        if self.fusion is not None:
            detail.update(self.fusion.health())
        return detail
