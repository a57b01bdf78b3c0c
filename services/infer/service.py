"""Infer stage: edge hits -> pose, from the store's active model, with hot swap and shadow mode."""
from __future__ import annotations

import math
import time
from collections import deque
from pathlib import Path

import numpy as np
from pydantic import BaseModel

from courtloc.common.bus import ZenohConfig
from courtloc.common.control import ModelReply, PoseReply, SetPose
from courtloc.common.inbox import Delivery
from courtloc.common.messages import ODOMETRY_SEQS_MAX, Edges, Odometry, Pose
from courtloc.common.payloads import edges_hits, edges_marks
from courtloc.common.runtime import Service
from courtloc.common.services_table import Control, Topic
from courtloc.localizer import motion
from courtloc.localizer.acquire import Prior
from courtloc.localizer.manifest import ManifestError, read_manifest
from courtloc.localizer.odometry_fusion import OdometryFusion
from courtloc.localizer.package import bundled_package
from courtloc.localizer.predictor import GeometricPredictor
from courtloc.localizer.tracking import Tracker, ages_agree
from courtloc.models import bundled_package as bundled_default
from courtloc.services.infer.config import InferConfig, StartConfig
from courtloc.services.infer.engine import LoadedModel, load_model
from courtloc.services.infer.model_control import ModelControl
from courtloc.services.infer.resume import ResumeFile, SavedPose
from courtloc.services.infer.shadow import ShadowRunner
from courtloc.services.infer.store import ModelRef, ModelStore, StoredModel
from courtloc.services.infer.uploads import Uploads
from courtloc.services.infer.validation import ModelRefused, deployment_mismatch, is_on_court

DEFAULT_MODEL_NAME = "default"


def bundled_for(config: InferConfig) -> Path:
    """The shipped package for the deployment's court and camera (ModelRefused naming what ships otherwise)."""
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


class InferService(Service):
    name = "infer"
    side_inputs = frozenset({"shooter_bridge/odometry"})

    def __init__(self, robot_id: str, zenoh_config: ZenohConfig, config: InferConfig) -> None:
        super().__init__(robot_id, zenoh_config)
        self.config = config
        self.store = ModelStore(config.store)
        self.active: LoadedModel | None = None
        self.shadow: ShadowRunner | None = None
        self.tracker = Tracker(start=start_prior(config.start))
        self.resume = ResumeFile(config.resume_path, robot_id)
        # Odometry fusion (localizer/odometry_fusion.py): None unless configured, then poses are as before.
        self.fusion = OdometryFusion(config.fusion) if config.fusion.enabled else None
        self._odometry_seqs: deque[int] = deque(maxlen=ODOMETRY_SEQS_MAX)  # taken in since the last answer
        self.swaps = 0
        self._control = ModelControl(self, Uploads(self.store, int(config.max_upload_mb * 2**20),
                                                   max_open=config.max_open_uploads, ttl_s=config.upload_ttl_h * 3600))

    # ---- start-up ----------------------------------------------------------------------
    def on_start(self) -> None:
        self.active = self._load_active()
        self.log.info("serving model %s (court %s, camera %s)", self.active.ref, self.active.manifest.court,
                      self.active.manifest.camera)
        saved = self.resume.load(self.active.manifest.court, self.config.resume_max_age_s)
        if saved is not None:  # a restart mid-run: the saved pose, not the configured start, is the evidence
            self.tracker.set_prior(saved.prior(), wall_ns=saved.wall_ns)
            carried = self.fusion is not None and self._resume_odometry(saved)
            self.log.info("resuming from the pose saved %.1f s ago: (%.2f, %.2f)%s", saved.age_s(), saved.x, saved.y,
                          ", carried by odometry" if carried else "")

    def _resume_odometry(self, saved: SavedPose) -> bool:
        """Seed the fusion with the odometry saved with the pose, so odometry carries the pose across the restart.
        Only when this host's monotonic clock agrees with the wall clock about the snapshot's age (no reboot
        since: the samples are stamped on this host's monotonic clock, `OdometryFusion._check`)."""
        samples, last = saved.odometry_snapshot()
        if last is None or self.fusion is None:
            return False
        if not ages_agree(time.monotonic() - last.t, saved.age_s(), self.tracker.clock_agreement_s):
            self.log.info("not carrying the saved pose by odometry: the monotonic clock restarted")
            return False
        return self.fusion.resume(samples, last)

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
            return load_model(stored, self.config)
        except ModelRefused as exc:
            # The active model was validated when it came in; if it is broken on disk now, roll back.
            self.record_error("model", f"active model {stored.ref} cannot load ({exc}); rolling back")
            target = self.store.rollback()
            return load_model(self.store.get(target), self.config)

    def _mismatch(self, stored: StoredModel) -> str:
        try:
            return deployment_mismatch(read_manifest(stored.model_path), self.config)
        except Exception:  # unreadable: load_model below says why
            return ""

    def _activate_bundled(self) -> StoredModel:
        """The bundled package for this deployment, as a store version (the existing copy when there is one)."""
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
    def on_message(self, topic: Topic, message: Edges | Odometry, delivery: Delivery) -> None:
        if isinstance(message, Odometry):  # fusion hook: odometry only fills the fusion's buffer
            if self.fusion is not None:
                self.fusion.offer(message, time.monotonic())
                self._odometry_seqs.append(message.source_seq)
            return
        fresh = self.is_fresh(message.header, topic)
        try:
            hits = edges_hits(message)
        except ValueError as exc:
            self.reject(topic.path, "bad_hits", str(exc))
            return
        try:
            marks = edges_marks(message)
        except ValueError as exc:
            self.reject(topic.path, "bad_marks", str(exc))
            return
        model = self.active  # one read: a swap between frames never splits a frame across two models
        assert model is not None
        if not fresh:
            # Old, or stamped in the future: never valid, and its capture time must not reach the
            # tracker's motion model (a frame "from" +1000 s would poison every later prediction).
            self.publish("infer/pose", Pose(header=message.header.forwarded(self.name, valid=False), x=0.0, y=0.0,
                                            model_name=model.ref.name, model_version=model.ref.version,
                                            infer_ms=0.0, reason="stale_input", odometry_seqs=self._odometry_taken()))
            return
        pose = self.make_pose(model, message, hits, fresh=fresh, tracker=self.tracker, marks=marks,
                              odometry_seqs=self._odometry_taken())
        self.publish("infer/pose", pose)
        if pose.header.valid and self.resume.due(pose.header.capture_wall_ns):
            prior = self.tracker.tracked_prior()
            fusion = self.fusion
            odometry = fusion.snapshot(prior.t) if fusion is not None and prior is not None and prior.t is not None \
                else ([], None)
            self.resume.offer(prior, model.manifest.court, pose.header.capture_wall_ns, odometry)
        shadow = self.shadow
        if shadow is not None:
            shadow.offer(message, hits, pose, marks)

    def _odometry_taken(self) -> list[int]:
        """The odometry taken in since the last answer (`Pose.odometry_seqs`), and a fresh count for the next."""
        seqs = list(self._odometry_seqs)
        self._odometry_seqs.clear()
        return seqs

    def make_pose(self, model: LoadedModel, edges: Edges, hits: np.ndarray, fresh: bool, tracker: Tracker,
                  marks: np.ndarray | None = None, odometry_seqs: list[int] | None = None) -> Pose:
        """The pose of one frame (`marks`: its colour marks, decoded; `odometry_seqs`: the odometry taken in since the
        last answer, `Pose.odometry_seqs`); `tracker` gives the start and learns from the result."""
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
        # A blind frame still steps a geometric model's tracker (it coasts, and is lost after its lost-frame
        # limit, as in `courtloc eval`): skipped, the track was found lost only by the time gap at the next
        # frame with hits, its prior as old as the blind spell (a 2 s blackout left it at exactly the spread that
        # decides nothing, and the twin's robot waited 25 s where the replay of the same frames recovered).
        if len(hits) == 0 and not isinstance(model.predictor, GeometricPredictor):
            reason = "no_hits"
        else:
            # Capture times on the camera's monotonic clock: the filter predicts over the real interval.
            pred = tracker.step(model.predictor, hits, edges.width, edges.height,
                                t=edges.header.capture_mono_ns * 1e-9, fusion=fusion,
                                capture_wall_ns=edges.header.capture_wall_ns, marks=marks)
            fusion_reason = tracker.odometry_reason
            covariance = motion.pose_covariance(tracker.motion)
            x, y, yaw, quality = float(pred.x), float(pred.y), pred.yaw, float(pred.quality)
            finite = all(math.isfinite(v) for v in (x, y, *(() if yaw is None else (yaw,))))
            if not finite:
                reason, x, y, yaw = "non_finite", 0.0, 0.0, None
            elif not is_on_court(model.court, x, y, self.config.on_court_margin_m):
                reason = "off_court"
            elif not pred.valid:
                reason = fusion_reason or pred.reason or ("no_hits" if len(hits) == 0 else "low_quality")
            ok = not reason
        if ok and not fresh:
            reason, ok = "stale_input", False
        if ok and not edges.header.valid:
            reason, ok = "invalid_input", False
        header = edges.header.forwarded(self.name, valid=ok)
        return Pose(header=header, x=x, y=y, yaw=None if yaw is None else float(yaw), quality=quality,
                    model_name=model.ref.name, model_version=model.ref.version,
                    infer_ms=(time.perf_counter() - start) * 1e3, reason=reason, covariance=covariance,
                    odometry_seqs=odometry_seqs or [])

    # ---- model control (the runtime's control thread) -------------------------------------------
    def on_control(self, control: Control, request: BaseModel) -> BaseModel:
        if control.name == "set_pose":
            return self.set_pose(request.body)
        return self._without_internals(self._control.handle(request))

    def _without_internals(self, reply: ModelReply) -> ModelReply:
        """The asker learns what went wrong, not where the robot keeps its files: the store's absolute
        folder becomes `<store>` in any text of the reply."""
        reason = reply.reason
        for root in {str(self.store.root.resolve()), str(self.store.root)}:
            reason = reason.replace(root, "<store>")
        return reply if reason == reply.reason else reply.model_copy(update={"reason": reason})

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
                                       lambda m, edges, hits, tracker, marks: self.make_pose(m, edges, hits, True, tracker, marks),
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
        self.start_shadow(None)

    def health_detail(self) -> dict[str, float | int | str]:
        model = self.active
        detail: dict[str, float | int | str] = {"swaps": self.swaps}
        if model is not None:
            detail.update(model=model.ref.name, model_version=model.ref.version)
        if self.fusion is not None:
            detail.update(self.fusion.health())
        return detail
