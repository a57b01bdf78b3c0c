"""The model store: a versioned model repository on disk.

    <store>/<name>/<version>/model.onnx (+ the package's other files)
    <store>/.active.json           the active (name, version) and the recent activation history
    <store>/.incoming/<upload_id>/ uploads in progress (resumable)

Two namespaces that cannot meet: every name a client gives (model names, file names) follows one rule,
`localizer.manifest.PLAIN_NAME_PATTERN`, which starts with a letter or digit; everything the store
writes for itself starts with '.'. So no model name can be the record, its temporary file or the
uploads folder.

A version folder appears only complete: uploads are written into `.incoming` and renamed into place
in one step, and `.active.json` is replaced atomically, so a process killed at any moment leaves a
consistent store. A write that fails (a full disk) raises StoreError and leaves the previous state.
"""
from __future__ import annotations

import hashlib
import logging
import os
import shutil
from dataclasses import dataclass
from pathlib import Path

from pydantic import BaseModel, ConfigDict, Field

from courtloc.localizer.manifest import MODEL_FILE, PLAIN_NAME_PATTERN, PLAIN_NAME_RULE, is_plain_name

log = logging.getLogger(__name__)

ACTIVE_FILE = ".active.json"
LEGACY_ACTIVE_FILE = "active.json"  # stores written before the record moved out of the names' namespace
INCOMING = ".incoming"
# Rollback needs the last few models, not every activation since the robot was built.
HISTORY_LIMIT = 16


class StoreError(RuntimeError):
    pass


MODEL_NAME_PATTERN = PLAIN_NAME_PATTERN


def check_name(name: str, what: str = "name") -> str:
    """`name` when it follows the store's one naming rule, else StoreError saying the rule."""
    if not isinstance(name, str) or not is_plain_name(name):
        shown = name if len(str(name)) <= 40 else f"{str(name)[:40]}... ({len(name)} characters)"
        raise StoreError(f"{what} {shown!r} is not {PLAIN_NAME_RULE}")
    return name


def disk_error(action: str, exc: OSError) -> StoreError:
    """One line for a failed write (ENOSPC, EFBIG, EIO...), without the store's paths."""
    return StoreError(f"{action}: {os.strerror(exc.errno) if exc.errno else type(exc).__name__}; store unchanged")


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
    """Replace `path` with `text` in one step; on any failure (a full disk) the old file stays, no temp file."""
    tmp = path.with_name(path.name + ".tmp")
    try:
        with tmp.open("w", encoding="utf-8") as handle:
            handle.write(text)
            handle.flush()
            os.fsync(handle.fileno())
        os.replace(tmp, path)
    except BaseException:
        tmp.unlink(missing_ok=True)
        raise
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
        self._migrate_record()

    def _migrate_record(self) -> None:
        """Move a record from the old `active.json` (a name a model could take) to `.active.json`."""
        legacy = self.root / LEGACY_ACTIVE_FILE
        if not legacy.is_file():
            return
        if not (self.root / ACTIVE_FILE).is_file():
            write_atomically(self.root / ACTIVE_FILE, legacy.read_text(encoding="utf-8"))
        legacy.unlink()
        _fsync_dir(self.root)

    # ---- reading ---------------------------------------------------------------------------
    def models(self) -> list[StoredModel]:
        found = []
        # Not every folder is a model name (.incoming, a filesystem's lost+found).
        for name_dir in sorted(p for p in self.root.iterdir() if p.is_dir() and is_plain_name(p.name)):
            for version_dir in name_dir.iterdir():
                if version_dir.name.isdigit() and (version_dir / MODEL_FILE).is_file():
                    found.append(StoredModel(ModelRef(name=name_dir.name, version=int(version_dir.name)),
                                             version_dir))
        return sorted(found, key=lambda m: (m.ref.name, m.ref.version))

    def get(self, ref: ModelRef) -> StoredModel:
        check_name(ref.name, "model name")
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
        """Put a complete model folder into the store as the next version of `name`; StoreError (and no
        version) when the disk refuses."""
        ref = ModelRef(name=check_name(name, "model name"), version=self.next_version(name))
        target = self.root / name / str(ref.version)
        staging = self.root / INCOMING / f"copy-{name}-{ref.version}"
        try:
            target.parent.mkdir(parents=True, exist_ok=True)
            if move:
                os.rename(source, target)  # one step: the version folder is never seen half-written
            else:
                shutil.rmtree(staging, ignore_errors=True)
                shutil.copytree(source, staging)
                os.rename(staging, target)
            _fsync_dir(target.parent)
        except OSError as exc:
            shutil.rmtree(staging, ignore_errors=True)
            raise disk_error(f"cannot store {ref}", exc) from None
        log.info("stored model %s", ref)
        return StoredModel(ref, target)

    def remove(self, ref: ModelRef) -> None:
        """Delete a stored version that is not the active one (undoing an add whose activation failed)."""
        if self.record().active == ref:
            raise StoreError(f"{ref} is the active model")
        shutil.rmtree(self.root / check_name(ref.name, "model name") / str(ref.version), ignore_errors=True)

    def _write_record(self, record: ActiveRecord) -> None:
        # Only the newest HISTORY_LIMIT earlier models are kept, without repeats (an A/B/A/B toggle
        # would otherwise fill the history with two names), and only versions still in the store.
        seen: set[ModelRef] = set()
        kept: list[ModelRef] = []
        for ref in reversed(record.history):
            if ref != record.active and ref not in seen and (self.root / ref.name / str(ref.version) / MODEL_FILE).is_file():
                seen.add(ref)
                kept.append(ref)
        record.history = list(reversed(kept[:HISTORY_LIMIT]))
        try:
            write_atomically(self.root / ACTIVE_FILE, record.model_dump_json(indent=2))
        except OSError as exc:
            raise disk_error("cannot record the active model", exc) from None

    def set_active(self, ref: ModelRef) -> ActiveRecord:
        self.get(ref)
        record = self.record()
        if record.active is not None and record.active != ref:
            record.history.append(record.active)
        record.active = ref
        self._write_record(record)
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
        self._write_record(record)
        return target

    def incoming_dir(self, upload_id: str) -> Path:
        if not (upload_id.isascii() and upload_id.isalnum() and len(upload_id) <= 64):
            raise StoreError("bad upload id")
        return self.root / INCOMING / upload_id
