"""Answers model-control requests (push, list, activate, rollback, shadow) for the infer service.

Runs on the service's control thread; validation and loading happen here, never on the inference
worker, and the worker only ever sees a complete, validated, warmed-up model.

The store's record is written before the served model changes: if the record cannot be written (a
full disk) the request is refused and nothing is swapped, and a crash after the write serves the
recorded model on restart. So the served model and the record never disagree.
"""
from __future__ import annotations

import logging
from typing import Protocol

from courtloc.common.control import (
    Activate,
    ListModels,
    ModelInfo,
    ModelReply,
    ModelRequest,
    PushBegin,
    PushChunk,
    PushCommit,
    Rollback,
    Shadow,
)
from courtloc.localizer.manifest import ManifestError, read_manifest
from courtloc.services.infer.engine import LoadedModel
from courtloc.services.infer.store import ModelRef, ModelStore, StoredModel, StoreError, check_name
from courtloc.services.infer.uploads import UploadError, Uploads
from courtloc.services.infer.validation import ModelRefused

log = logging.getLogger(__name__)


class ModelHost(Protocol):
    """What the control side needs from the infer service."""

    store: ModelStore

    def validate(self, stored: StoredModel, pushed: bool = False) -> LoadedModel: ...
    def swap_in(self, model: LoadedModel) -> None: ...
    def start_shadow(self, model: LoadedModel | None) -> None: ...
    def active_ref(self) -> ModelRef | None: ...
    def shadow_reply(self) -> ModelReply: ...


class ModelControl:
    def __init__(self, host: ModelHost, uploads: Uploads) -> None:
        self.host = host
        self.uploads = uploads

    def handle(self, request: ModelRequest) -> ModelReply:
        body = request.body
        try:
            if isinstance(body, PushBegin):
                upload_id, received = self.uploads.begin(body.files)
                return ModelReply(ok=True, upload_id=upload_id, received=received)
            if isinstance(body, PushChunk):
                received = self.uploads.chunk(body.upload_id, body.file_index, body.offset, body.data)
                return ModelReply(ok=True, upload_id=body.upload_id, received=received)
            if isinstance(body, PushCommit):
                return self._commit(body)
            if isinstance(body, ListModels):
                return self._list()
            if isinstance(body, Activate):
                name = check_name(body.name or self._active_name(), "model name")
                return self._activate(self.host.store.get(ModelRef(name=name, version=body.version)))
            if isinstance(body, Rollback):
                return self._activate(self.host.store.get(self.host.store.rollback_target()), rollback=True)
            if isinstance(body, Shadow):
                return self._shadow(body)
        except (UploadError, StoreError, ModelRefused, ValueError) as exc:  # ValueError: a bad name or version
            log.warning("model request %s refused: %s", body.op, exc)
            return ModelReply(ok=False, reason=str(exc))
        return ModelReply(ok=False, reason=f"unknown request {body.op}")

    def _active_name(self) -> str:
        ref = self.host.active_ref()
        if ref is None:
            raise StoreError("no active model: give the model name")
        return ref.name

    def _commit(self, body: PushCommit) -> ModelReply:
        folder = self.uploads.complete(body.upload_id)

        try:
            name = read_manifest(folder / "model.onnx").name
        except ManifestError as exc:
            self.uploads.abort(body.upload_id)
            raise ModelRefused(f"manifest: {exc}") from None
        except Exception as exc:
            self.uploads.abort(body.upload_id)
            raise ModelRefused(f"not a readable ONNX model: {type(exc).__name__}: {exc}") from None
        try:
            check_name(name, "manifest name")
        except StoreError as exc:
            self.uploads.abort(body.upload_id)
            raise ModelRefused(str(exc)) from None
        # Validate in place, before the version exists in the store: a refused model leaves no trace.
        candidate = StoredModel(ModelRef(name=name, version=self.host.store.next_version(name)), folder)
        try:
            loaded = self.host.validate(candidate, pushed=True)
            stored = self.host.store.add_folder(folder, name, move=True)
        except (ModelRefused, StoreError):
            self.uploads.abort(body.upload_id)
            raise
        loaded.ref = stored.ref
        if body.activate:
            try:
                self.host.store.set_active(stored.ref)
            except StoreError:
                self.host.store.remove(stored.ref)  # refused as a whole: no version that was never active
                raise
            self.host.swap_in(loaded)
        return ModelReply(ok=True, name=stored.ref.name, version=stored.ref.version,
                          reason="stored and active" if body.activate else "stored")

    def _activate(self, stored: StoredModel, rollback: bool = False) -> ModelReply:
        loaded = self.host.validate(stored)
        if rollback:
            self.host.store.rollback()
        else:
            self.host.store.set_active(stored.ref)
        self.host.swap_in(loaded)
        return ModelReply(ok=True, name=stored.ref.name, version=stored.ref.version, reason="active")

    def _shadow(self, body: Shadow) -> ModelReply:
        if body.version is None:
            reply = self.host.shadow_reply()
            self.host.start_shadow(None)
            return reply.model_copy(update={"reason": "shadow stopped"})
        name = check_name(body.name or self._active_name(), "model name")
        stored = self.host.store.get(ModelRef(name=name, version=body.version))
        self.host.start_shadow(self.host.validate(stored))
        return ModelReply(ok=True, name=stored.ref.name, version=stored.ref.version, reason="shadow running")

    def _list(self) -> ModelReply:
        active = self.host.active_ref()
        shadow = self.host.shadow_reply()
        infos = []
        for stored in self.host.store.models():
            try:
                kind = read_manifest(stored.model_path).input.kind
            except Exception:  # listing must not fail on one bad file
                kind = "unreadable"
            infos.append(ModelInfo(name=stored.ref.name, version=stored.ref.version, input_kind=kind,
                                   size_bytes=stored.size_bytes(), active=stored.ref == active,
                                   shadow=shadow.ok and shadow.name == stored.ref.name
                                   and shadow.version == stored.ref.version))
        return ModelReply(ok=True, models=infos, shadow=shadow.shadow)
