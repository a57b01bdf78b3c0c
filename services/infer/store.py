"""The model store: a versioned model repository on disk.

    <store>/<name>/<version>/model.onnx (+ the package's other files)
    <store>/active.json            the active (name, version) and the activation history
    <store>/.incoming/<upload_id>/ uploads in progress (resumable)

A version folder appears only complete: uploads are written into `.incoming` and renamed into place
in one step, and `active.json` is replaced atomically, so a process killed at any moment leaves a
consistent store.
"""
from __future__ import annotations

import hashlib
import logging
import os
import re
import shutil
from dataclasses import dataclass
from pathlib import Path

from pydantic import BaseModel, ConfigDict, Field

from courtloc.localizer.manifest import MODEL_FILE

log = logging.getLogger(__name__)

ACTIVE_FILE = "active.json"
INCOMING = ".incoming"


class StoreError(RuntimeError):
    pass


MODEL_NAME_PATTERN = r"^[A-Za-z0-9][A-Za-z0-9_.-]{0,127}$"


class ModelRef(BaseModel):
    model_config = ConfigDict(extra="forbid", frozen=True)
    # A folder name in the store: a manifest name like "../x" or "a/b" must not place files outside it.
    name: str = Field(pattern=MODEL_NAME_PATTERN)
    version: int = Field(ge=1)

    def __str__(self) -> str:
        return f"{self.name}/{self.version}"


class ActiveRecord(BaseModel):
    model_config = ConfigDict(extra="forbid")
    active: ModelRef | None = None
    history: list[ModelRef] = Field(default_factory=list, description="earlier active models, newest last")


def sha256_file(path: Path, block: int = 1 << 20) -> str:
    digest = hashlib.sha256()
    with path.open("rb") as handle:
        while chunk := handle.read(block):
            digest.update(chunk)
    return digest.hexdigest()


def _fsync_dir(path: Path) -> None:
    fd = os.open(path, os.O_RDONLY)
    try:
        os.fsync(fd)
    finally:
        os.close(fd)


def write_atomically(path: Path, text: str) -> None:
    tmp = path.with_name(path.name + ".tmp")
    with tmp.open("w", encoding="utf-8") as handle:
        handle.write(text)
        handle.flush()
        os.fsync(handle.fileno())
    os.replace(tmp, path)
    _fsync_dir(path.parent)


@dataclass(frozen=True)
class StoredModel:
    ref: ModelRef
    folder: Path

    @property
    def model_path(self) -> Path:
        return self.folder / MODEL_FILE

    def size_bytes(self) -> int:
        return sum(p.stat().st_size for p in self.folder.iterdir() if p.is_file())


class ModelStore:
    def __init__(self, root: Path) -> None:
        self.root = Path(root)
        self.root.mkdir(parents=True, exist_ok=True)
        (self.root / INCOMING).mkdir(exist_ok=True)

    # ---- reading ---------------------------------------------------------------------------
    def models(self) -> list[StoredModel]:
        found = []
        # Not every folder is a model name (.incoming, a filesystem's lost+found).
        for name_dir in sorted(p for p in self.root.iterdir() if p.is_dir() and re.match(MODEL_NAME_PATTERN, p.name)):
            for version_dir in name_dir.iterdir():
                if version_dir.name.isdigit() and (version_dir / MODEL_FILE).is_file():
                    found.append(StoredModel(ModelRef(name=name_dir.name, version=int(version_dir.name)),
                                             version_dir))
        return sorted(found, key=lambda m: (m.ref.name, m.ref.version))

    def get(self, ref: ModelRef) -> StoredModel:
        folder = self.root / ref.name / str(ref.version)
        if not (folder / MODEL_FILE).is_file():
            raise StoreError(f"no model {ref} in the store")
        return StoredModel(ref, folder)

    def record(self) -> ActiveRecord:
        path = self.root / ACTIVE_FILE
        if not path.is_file():
            return ActiveRecord()
        try:
            return ActiveRecord.model_validate_json(path.read_text(encoding="utf-8"))
        except ValueError as exc:
            raise StoreError(f"{path} is damaged: {exc}") from None

    def active(self) -> StoredModel | None:
        ref = self.record().active
        return self.get(ref) if ref is not None else None

    def next_version(self, name: str) -> int:
        versions = [m.ref.version for m in self.models() if m.ref.name == name]
        return max(versions, default=0) + 1

    # ---- writing ---------------------------------------------------------------------------
    def add_folder(self, source: Path, name: str, move: bool = False) -> StoredModel:
        """Put a complete model folder into the store as the next version of `name`."""
        ref = ModelRef(name=name, version=self.next_version(name))
        target = self.root / name / str(ref.version)
        target.parent.mkdir(parents=True, exist_ok=True)
        if move:
            os.rename(source, target)  # one step: the version folder is never seen half-written
        else:
            staging = self.root / INCOMING / f"copy-{name}-{ref.version}"
            shutil.rmtree(staging, ignore_errors=True)
            shutil.copytree(source, staging)
            os.rename(staging, target)
        _fsync_dir(target.parent)
        log.info("stored model %s", ref)
        return StoredModel(ref, target)

    def set_active(self, ref: ModelRef) -> ActiveRecord:
        self.get(ref)
        record = self.record()
        if record.active is not None and record.active != ref:
            record.history.append(record.active)
        record.active = ref
        write_atomically(self.root / ACTIVE_FILE, record.model_dump_json(indent=2))
        return record

    def rollback_target(self) -> ModelRef:
        record = self.record()
        for ref in reversed(record.history):
            if ref != record.active and (self.root / ref.name / str(ref.version) / MODEL_FILE).is_file():
                return ref
        raise StoreError("nothing to roll back to")

    def rollback(self) -> ModelRef:
        """Activate the previous model and forget the current one in the history."""
        target = self.rollback_target()
        record = self.record()
        while record.history and record.history[-1] != target:
            record.history.pop()
        if record.history:
            record.history.pop()
        record.active = target
        write_atomically(self.root / ACTIVE_FILE, record.model_dump_json(indent=2))
        return target

    def incoming_dir(self, upload_id: str) -> Path:
        if not upload_id.isalnum():
            raise StoreError("bad upload id")
        return self.root / INCOMING / upload_id


