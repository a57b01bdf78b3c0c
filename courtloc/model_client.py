"""Talking to a robot's model store over Zenoh: push (chunked, resumable), list, activate, rollback, shadow."""
from __future__ import annotations

import logging
import threading
from pathlib import Path
from typing import Callable

import zenoh

from courtloc.common import codec
from courtloc.common.control import (
    Activate,
    FileSpec,
    ListModels,
    ModelReply,
    ModelRequest,
    ModelRequestBody,
    PushBegin,
    PushChunk,
    PushCommit,
    Rollback,
    Shadow,
)
from courtloc.common.services_table import CONTROLS
from courtloc.common.signing import signature_path
from courtloc.localizer.golden import GOLDEN_FILE, sidecar_path
from courtloc.services.infer.store import MODEL_FILE, StoreError, check_name, sha256_file

log = logging.getLogger(__name__)
CHUNK_TIMEOUT_S = 30.0


class ModelClientError(RuntimeError):
    pass


def push_files(source: Path) -> dict[str, Path]:
    """Store file name -> local path: a lone ONNX file becomes model.onnx (with its signature and golden
    inputs beside it); a package folder is sent flat. Every name follows the store's naming rule."""
    if source.is_dir():
        # Hidden files (an editor's or a file manager's) are not package parts.
        files = {p.name: p for p in sorted(source.iterdir()) if p.is_file() and not p.name.startswith(".")}
        if MODEL_FILE not in files:
            raise ModelClientError(f"{source} has no {MODEL_FILE}")
    elif source.is_file():
        files = {MODEL_FILE: source}
        signature = signature_path(source)
        if signature.is_file():  # a signed model travels with its signature
            files[signature_path(Path(MODEL_FILE)).name] = signature
        golden = sidecar_path(source)
        if golden.is_file():
            files[GOLDEN_FILE] = golden
    else:
        raise ModelClientError(f"{source} not found")
    for name in files:
        try:
            check_name(name, f"{source}: file name")
        except StoreError as exc:  # the robot would refuse it: say so before sending anything
            raise ModelClientError(str(exc)) from None
    return files


class ModelClient:
    def __init__(self, session: zenoh.Session, robot_id: str) -> None:
        self.session = session
        self.control = CONTROLS["infer/model"]
        self.key = self.control.key(robot_id)
        self._reachable = False

    def _wait_reachable(self, timeout_s: float) -> None:
        """Until the router routes our queries to an infer stage (a query sent before reaches nobody)."""
        if self._reachable:
            return
        matched = threading.Event()
        querier = self.session.declare_querier(self.key)
        listener = querier.declare_matching_listener(lambda status: matched.set() if status.matching else None)
        try:
            self._reachable = querier.matching_status.matching or matched.wait(timeout_s)
        finally:
            listener.undeclare()
            querier.undeclare()

    def request(self, body: ModelRequestBody, timeout_s: float | None = None) -> ModelReply:
        self._wait_reachable(timeout_s or self.control.timeout_s)
        payload = codec.encode(ModelRequest(body=body))
        replies = self.session.get(self.key, payload=payload, timeout=timeout_s or self.control.timeout_s)
        for reply in replies:
            if reply.ok is not None:
                return codec.decode(bytes(reply.ok.payload), ModelReply)
            raise ModelClientError(f"error reply: {reply.err.payload.to_string()}")
        raise ModelClientError("no answer from the robot's infer service (is it running, and is this the right robot?)")

    def push(self, source: Path, activate: bool = True, chunk_bytes: int = 4 << 20,
             progress: Callable[[int, int], None] | None = None) -> ModelReply:
        files = push_files(source)
        specs = [FileSpec(path=name, size=path.stat().st_size, sha256=sha256_file(path)) for name, path in files.items()]
        begun = self.request(PushBegin(files=specs))
        if not begun.ok:
            return begun
        total = sum(s.size for s in specs)
        done = sum(begun.received)
        if done:
            log.info("resuming push %s at %d of %d bytes", begun.upload_id, done, total)
        for index, (spec, path) in enumerate(zip(specs, files.values())):
            offset = begun.received[index]
            with path.open("rb") as handle:
                handle.seek(offset)
                while offset < spec.size:
                    data = handle.read(chunk_bytes)
                    reply = self.request(PushChunk(upload_id=begun.upload_id, file_index=index, offset=offset,
                                                   data=data), CHUNK_TIMEOUT_S)
                    if not reply.ok:
                        return reply
                    offset += len(data)
                    done += len(data)
                    if progress is not None:
                        progress(done, total)
        return self.request(PushCommit(upload_id=begun.upload_id, activate=activate))

    def list(self) -> ModelReply:
        return self.request(ListModels())

    def activate(self, version: int, name: str | None = None) -> ModelReply:
        return self.request(Activate(name=name, version=version))

    def rollback(self) -> ModelReply:
        return self.request(Rollback())

    def shadow(self, version: int | None, name: str | None = None) -> ModelReply:
        return self.request(Shadow(name=name, version=version))
