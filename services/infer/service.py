"""Infer stage: edge hits -> pose, from the store's active model, with hot swap and shadow mode."""
from __future__ import annotations

import importlib.resources
import math
import queue
import threading
import time
from pathlib import Path

import numpy as np
import zenoh

from courtloc.common import codec
from courtloc.common.control import ModelReply, ModelRequest
from courtloc.common.inbox import Delivery
from courtloc.common.messages import Edges, Pose
from courtloc.common.bus import ZenohConfig
from courtloc.common.runtime import Service
from courtloc.common.services_table import CONTROLS, Topic
from courtloc.services.infer.config import InferConfig
from courtloc.services.infer.engine import LoadedModel, ModelRefused, is_on_court, load_model
from courtloc.services.infer.model_control import ModelControl
from courtloc.services.infer.shadow import ShadowRunner
from courtloc.services.infer.store import ModelRef, ModelStore, StoredModel
from courtloc.services.infer.tracking import Tracker
from courtloc.services.infer.uploads import Uploads
from courtloc.services.preprocess.pipeline import hits_from_bytes

DEFAULT_MODEL_NAME = "default"


def bundled_default() -> Path:
    return Path(str(importlib.resources.files("courtloc.models") / "default"))


def hits_of(edges: Edges) -> np.ndarray:
    hits = hits_from_bytes(edges.hits)
    if len(hits) != edges.n_hits:
        raise ValueError(f"{len(hits)} hits in the payload, the header says {edges.n_hits}")
    return hits


class InferService(Service):
    name = "infer"

    def __init__(self, robot_id: str, zenoh_config: ZenohConfig, config: InferConfig) -> None:
        super().__init__(robot_id, zenoh_config)
        self.config = config
        self.store = ModelStore(config.store)
        self.active: LoadedModel | None = None
        self.shadow: ShadowRunner | None = None
        self.tracker = Tracker()
        self.swaps = 0
        self._control = ModelControl(self, Uploads(self.store, int(config.max_upload_mb * 2**20),
                                                   max_open=config.max_open_uploads, ttl_s=config.upload_ttl_h * 3600))
        self._control_thread: threading.Thread | None = None
        self._queries: queue.Queue[zenoh.Query] = queue.Queue(maxsize=64)
        self._queryable = None

    # ---- start-up ----------------------------------------------------------------------
    def on_start(self) -> None:
        self.active = self._load_active()
        self.log.info("serving model %s", self.active.ref)
        assert self.session is not None
        control = CONTROLS["infer/model"]
        # The callback only queues the query; requests are answered on our own control thread.
        self._queryable = self.session.declare_queryable(control.key(self.robot_id), self._enqueue_query)
        self._control_thread = threading.Thread(target=self._serve_control, name="infer-control", daemon=True)
        self._control_thread.start()

    def _load_active(self) -> LoadedModel:
        """The store's active model; a fresh store gets the bundled default as version 1."""
        if self.store.record().active is None:
            stored = self.store.add_folder(bundled_default(), DEFAULT_MODEL_NAME)
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
    def on_message(self, topic: Topic, message: Edges, delivery: Delivery) -> None:
        fresh = self.is_fresh(message.header, topic)
        try:
            hits = hits_of(message)
        except ValueError as exc:
            self.reject(topic.path, "bad_hits", str(exc))
            return
        model = self.active  # one read: a swap between frames never splits a frame across two models
        assert model is not None
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
        if len(hits) == 0:
            reason = "no_hits"
        else:
            track = getattr(model.predictor, "track", None)
            if track is not None:
                # Capture times on the camera's monotonic clock: the filter predicts over the real interval.
                pred, tracker.motion = track(hits, edges.width, edges.height, tracker.motion,
                                             t=edges.header.capture_mono_ns * 1e-9)
            else:
                pred = model.predictor.predict(hits, edges.width, edges.height, previous=tracker.previous)
            x, y, yaw, quality = float(pred.x), float(pred.y), pred.yaw, float(pred.quality)
            tracker.update(x, y, yaw, pred.valid, pred.trackable)
            finite = all(math.isfinite(v) for v in (x, y, *(() if yaw is None else (yaw,))))
            if not finite:
                reason, x, y, yaw = "non_finite", 0.0, 0.0, None
            elif not is_on_court(model.court, x, y, self.config.on_court_margin_m):
                reason = "off_court"
            elif not pred.valid:
                reason = "low_quality"
            ok = not reason
        if ok and not fresh:
            reason, ok = "stale_input", False
        if ok and not edges.header.valid:
            reason, ok = "invalid_input", False
        header = edges.header.forwarded(self.name, valid=ok)
        return Pose(header=header, x=x, y=y, yaw=None if yaw is None else float(yaw), quality=quality,
                    model_name=model.ref.name, model_version=model.ref.version,
                    infer_ms=(time.perf_counter() - start) * 1e3, reason=reason)

    # ---- model control (its own thread) -------------------------------------------------------
    def _enqueue_query(self, query: zenoh.Query) -> None:
        try:
            self._queries.put_nowait(query)
        except queue.Full:  # dropped: the caller's request times out and it may ask again
            self.record_error("control", "model request queue full; request dropped")

    def _serve_control(self) -> None:
        assert self._queryable is not None
        while not self.stop_event.is_set():
            try:
                query = self._queries.get(timeout=0.5)  # wakes up to notice a shutdown
            except queue.Empty:
                continue
            # Dropping the query finalises it; until then the asker does not get the reply (a query
            # kept alive in the loop variable would hold it until the next request arrived).
            with query:
                self._answer(query)

    def _answer(self, query: zenoh.Query) -> None:
        payload = query.payload
        try:
            request = codec.decode(bytes(payload) if payload is not None else b"", ModelRequest)
            reply = self._control.handle(request)
        except codec.DecodeError as exc:
            self.reject(CONTROLS["infer/model"].path, exc.reason, exc.detail)
            reply = ModelReply(ok=False, reason=f"bad request: {exc}")
        except Exception as exc:  # a control bug must not stop inference
            self.log.exception("model control failed")
            reply = ModelReply(ok=False, reason=f"internal error: {type(exc).__name__}: {exc}")
        try:
            query.reply(query.key_expr, codec.encode(reply))
        except zenoh.ZError as exc:
            self.record_error("control", f"cannot answer model request: {exc}")

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
        if self._control_thread is not None:
            self._control_thread.join(timeout=5.0)
        if self._queryable is not None:
            self._queryable.undeclare()
        self.start_shadow(None)

    def health_detail(self) -> dict[str, float | int | str]:
        model = self.active
        detail: dict[str, float | int | str] = {"swaps": self.swaps}
        if model is not None:
            detail.update(model=model.ref.name, model_version=model.ref.version)
        return detail
