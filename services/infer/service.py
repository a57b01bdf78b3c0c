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
from courtloc.common.control import ModelReply, ModelRequest, PoseReply, SetPose
from courtloc.common.inbox import Delivery
from courtloc.common.messages import Edges, Pose
from courtloc.common.bus import ZenohConfig
from courtloc.common.runtime import Service
from courtloc.common.services_table import CONTROLS, Topic
from courtloc.localizer.acquire import Prior
from courtloc.services.infer.config import InferConfig, StartConfig
from courtloc.services.infer.resume import ResumeFile
from courtloc.services.infer.engine import LoadedModel, ModelRefused, deployment_mismatch, is_on_court, load_model
from courtloc.services.infer.golden import GoldenSets
from courtloc.services.infer.model_control import ModelControl
from courtloc.services.infer.pose_control import PoseControl
from courtloc.services.infer.shadow import ShadowRunner
from courtloc.services.infer.store import ModelRef, ModelStore, StoredModel
from courtloc.services.infer.tracking import Tracker
from courtloc.services.infer.uploads import Uploads
from courtloc.services.preprocess.pipeline import hits_from_bytes

DEFAULT_MODEL_NAME = "default"


def bundled_default() -> Path:
    """The seed-gazebo package (the built-in deployment's court and camera)."""
    return Path(str(importlib.resources.files("courtloc.models") / "default"))


def bundled_for(config: InferConfig) -> Path:
    """The shipped package for the deployment's court and camera (ModelRefused naming what ships otherwise)."""
    from courtloc.localizer.manifest import ManifestError
    from courtloc.localizer.package import bundled_package

    if config.court is None:
        return bundled_default()
    try:
        return bundled_package(config.court, config.camera or config.court)
    except ManifestError as exc:
        raise ModelRefused(str(exc)) from None


def start_prior(start: StartConfig | None) -> Prior | None:
    """The configured start as the localizer's evidence for a fresh run."""
    if start is None:
        return None
    if start.x is None or start.y is None:
        return Prior(source="start", half=start.half)
    yaw = 0.0 if start.yaw_deg is None else math.radians(start.yaw_deg)
    return Prior(source="start", pose=np.array([start.x, start.y, yaw]), std_m=start.std_m, half=start.half,
                 yaw_std_rad=None if start.yaw_deg is None else math.radians(start.yaw_std_deg))


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
        self.golden = GoldenSets()
        self.active: LoadedModel | None = None
        self.shadow: ShadowRunner | None = None
        self.tracker = Tracker(start=start_prior(config.start))
        self.resume = ResumeFile(config.resume_path, robot_id)
        self.swaps = 0
        self._control = ModelControl(self, Uploads(self.store, int(config.max_upload_mb * 2**20)))
        self._control_thread: threading.Thread | None = None
        self._queries: queue.Queue[zenoh.Query] = queue.Queue(maxsize=64)
        self._queryable = None
        self._pose_control: PoseControl | None = None

    # ---- start-up ----------------------------------------------------------------------
    def on_start(self) -> None:
        self.active = self._load_active()
        self.log.info("serving model %s (court %s, camera %s)", self.active.ref, self.active.manifest.court,
                      self.active.manifest.camera)
        saved = self.resume.load(self.active.manifest.court, self.config.resume_max_age_s)
        if saved is not None:  # a restart mid-run: the saved pose, not the configured start, is the evidence
            self.tracker.set_prior(saved.prior(), wall_ns=saved.wall_ns)
            self.log.info("resuming from the pose saved %.1f s ago: (%.2f, %.2f)", saved.age_s(), saved.x, saved.y)
        self._prepare_golden(self.active)
        assert self.session is not None
        control = CONTROLS["infer/model"]
        # The callback only queues the query; requests are answered on our own control thread.
        self._queryable = self.session.declare_queryable(control.key(self.robot_id), self._enqueue_query)
        self._control_thread = threading.Thread(target=self._serve_control, name="infer-control", daemon=True)
        self._control_thread.start()
        self._pose_control = PoseControl(self.session, self.robot_id, self.set_pose, self.reject, self.stop_event)

    def _prepare_golden(self, model: LoadedModel) -> None:
        """Render the golden inputs of the serving model's court now, before frames flow: rendering them at
        the first push would hold the GIL for tens of ms at a time while the worker serves frames."""
        try:
            self.golden.get(model.manifest.court, model.manifest.camera)
        except Exception as exc:  # no golden set for this court: a push will be refused with the reason
            self.record_error("model", f"no golden inputs for {model.ref}: {exc}")

    def _load_active(self) -> LoadedModel:
        """The store's active model; a fresh store gets the bundled package of the deployment's court and
        camera. An active model for another court or camera is refused (with the reason) and the bundled
        package of this deployment serves instead."""
        if self.store.record().active is None:
            self._activate_bundled()
        stored = self.store.active()
        assert stored is not None
        mismatch = self._mismatch(stored)
        if mismatch:
            self.record_error("model", f"active model {stored.ref} refused: {mismatch}; serving the bundled package "
                              f"for this deployment")
            stored = self._activate_bundled()
        try:
            return load_model(stored, self.config, golden=None)
        except ModelRefused as exc:
            # The active model was validated when it came in; if it is broken on disk now, roll back.
            self.record_error("model", f"active model {stored.ref} cannot load ({exc}); rolling back")
            target = self.store.rollback()
            return load_model(self.store.get(target), self.config, golden=None)

    def _mismatch(self, stored: StoredModel) -> str:
        from courtloc.localizer.manifest import read_manifest

        try:
            return deployment_mismatch(read_manifest(stored.model_path), self.config)
        except Exception:  # unreadable: load_model below says why
            return ""

    def _activate_bundled(self) -> StoredModel:
        """The bundled package for this deployment, as a store version (the existing copy when there is one)."""
        from courtloc.localizer.manifest import read_manifest

        source = bundled_for(self.config)
        weights = read_manifest(source / "model.onnx").weights_sha256
        for stored in self.store.models():
            try:
                if stored.ref.name == DEFAULT_MODEL_NAME and read_manifest(stored.model_path).weights_sha256 == weights:
                    self.store.set_active(stored.ref)
                    return stored
            except Exception:  # an unreadable version is not the copy we look for
                continue
        stored = self.store.add_folder(source, DEFAULT_MODEL_NAME)
        self.store.set_active(stored.ref)
        return stored

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
        if pose.header.valid:
            self.resume.offer(self.tracker.tracked_prior(), model.manifest.court, pose.header.capture_wall_ns)
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
                pred, tracker.motion = track(hits, edges.width, edges.height,
                                             tracker.state_for(edges.header.capture_wall_ns),
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
                reason = getattr(pred, "reason", "") or "low_quality"
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

    def set_pose(self, request: SetPose) -> PoseReply:
        """The pit's pose: the next frame acquires with it as the evidence (control thread; the worker applies it)."""
        model = self.active
        if model is not None and not is_on_court(model.court, request.x, request.y, 0.0):
            return PoseReply(ok=False, reason=f"({request.x:.2f}, {request.y:.2f}) is not on court {model.manifest.court!r}")
        self.tracker.request_prior(Prior(source="pit", pose=np.array([request.x, request.y, request.yaw]),
                                         std_m=request.std_m, yaw_std_rad=request.yaw_std_rad))
        self.log.info("pose set by the pit: (%.2f, %.2f, %.1f deg) +- %.2f m", request.x, request.y,
                      math.degrees(request.yaw), request.std_m)
        return PoseReply(ok=True, reason="pose set; the localizer confirms it against the view")

    # ModelHost, for ModelControl
    def validate(self, stored: StoredModel, pushed: bool = False) -> LoadedModel:
        return load_model(stored, self.config, golden=self.golden, pushed=pushed)

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
                                       lambda m, edges, hits, tracker: self.make_pose(m, edges, hits, True, tracker),
                                       tracker=self.tracker.handover())

    def active_ref(self) -> ModelRef | None:
        return self.active.ref if self.active is not None else None

    def shadow_reply(self) -> ModelReply:
        shadow = self.shadow
        if shadow is None:
            return ModelReply(ok=False, reason="no shadow model")
        stats = shadow.stats()
        return ModelReply(ok=True, name=stats.name, version=stats.version, shadow=stats)

    def on_stop(self) -> None:
        if self._pose_control is not None:
            self._pose_control.close()
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
