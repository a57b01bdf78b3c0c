"""Receiving a model over the bus in chunks, resumable, into the store's incoming folder.

An upload is identified by the hash of its file list (names, sizes, sha256), so the same push after a
broken link or a restart of either side continues where the stored bytes end.

Open uploads are bounded: at most `max_open` at a time (a new one evicts the one written least
recently) and none older than `ttl_s` since its last byte (swept at start and at every new push).
Anything else in the incoming folder (a staging copy, a folder whose commit was cut short) is
swept too: it can never complete.
"""
from __future__ import annotations

import errno
import hashlib
import json
import logging
import os
import shutil
import time
from pathlib import Path

from courtloc.common.control import FileSpec
from courtloc.services.infer.store import INCOMING, ModelStore, StoreError, check_name, sha256_file

log = logging.getLogger(__name__)
SPEC_FILE = ".files.json"  # dot-named: no pushed file can take its name
MAX_FILES = 64


class UploadError(RuntimeError):
    pass


def upload_id_of(files: list[FileSpec]) -> str:
    text = json.dumps([f.model_dump() for f in files], sort_keys=True)
    return hashlib.sha256(text.encode()).hexdigest()[:32]


def _last_write(folder: Path) -> float:
    """When the upload last received a byte (chunks append to files; the folder's own time is its start)."""
    times = [folder.stat().st_mtime]
    times.extend(p.stat().st_mtime for p in folder.iterdir() if p.is_file())
    return max(times)


class Uploads:
    def __init__(self, store: ModelStore, max_bytes: int, max_open: int = 2, ttl_s: float = 24 * 3600.0) -> None:
        self.store = store
        self.max_bytes = max_bytes
        self.max_open = max_open
        self.ttl_s = ttl_s
        self.sweep()

    def sweep(self, keep: str = "") -> None:
        """Remove what can never complete: expired uploads, and folders that are not open uploads."""
        incoming = self.store.root / INCOMING
        now = time.time()
        for entry in list(incoming.iterdir()):
            try:
                stale = (entry.name != keep and (not entry.is_dir() or not (entry / SPEC_FILE).is_file()
                                                 or now - _last_write(entry) > self.ttl_s))
            except OSError:  # vanished meanwhile
                continue
            if stale:
                log.info("removing abandoned upload %s", entry.name)
                shutil.rmtree(entry, ignore_errors=True) if entry.is_dir() else entry.unlink(missing_ok=True)

    def _make_room(self, keep: str) -> None:
        """Evict the least recently written open uploads until a new one fits under max_open."""
        incoming = self.store.root / INCOMING
        others = sorted((p for p in incoming.iterdir() if p.is_dir() and p.name != keep), key=_last_write)
        for folder in others[: max(0, len(others) - self.max_open + 1)]:
            log.info("evicting open upload %s (at most %d open)", folder.name, self.max_open)
            shutil.rmtree(folder, ignore_errors=True)

    def begin(self, files: list[FileSpec]) -> tuple[str, list[int]]:
        names = [f.path for f in files]
        if len(names) > MAX_FILES:
            raise UploadError(f"a push holds at most {MAX_FILES} files, this one {len(names)}")
        try:
            for name in names:
                check_name(name, "file name")
        except StoreError as exc:
            raise UploadError(str(exc)) from None
        if len(set(names)) != len(names):
            raise UploadError("duplicate file names in the push")
        if "model.onnx" not in names:
            raise UploadError("a model push must contain model.onnx")
        if sum(f.size for f in files) > self.max_bytes:
            raise UploadError(f"push of {sum(f.size for f in files)} bytes exceeds the {self.max_bytes}-byte limit")
        upload_id = upload_id_of(files)
        folder = self.store.incoming_dir(upload_id)
        self.sweep(keep=upload_id)
        if not folder.is_dir():
            self._make_room(keep=upload_id)
        try:
            folder.mkdir(parents=True, exist_ok=True)
            if not (folder / SPEC_FILE).is_file():
                spec = folder / (SPEC_FILE + ".tmp")
                spec.write_text(json.dumps([f.model_dump() for f in files]))
                os.replace(spec, folder / SPEC_FILE)  # a folder with a spec file is a whole upload
        except OSError as exc:
            shutil.rmtree(folder, ignore_errors=True)
            raise UploadError(f"cannot stage the upload: {os.strerror(exc.errno or 0)}") from None
        return upload_id, self.received(upload_id)

    def _specs(self, upload_id: str) -> list[FileSpec]:
        path = self.store.incoming_dir(upload_id) / SPEC_FILE
        if not path.is_file():
            raise UploadError(f"unknown upload {upload_id} (begin it first)")
        return [FileSpec.model_validate(item) for item in json.loads(path.read_text())]

    def received(self, upload_id: str) -> list[int]:
        folder = self.store.incoming_dir(upload_id)
        return [(folder / f.path).stat().st_size if (folder / f.path).is_file() else 0
                for f in self._specs(upload_id)]

    def chunk(self, upload_id: str, file_index: int, offset: int, data: bytes) -> list[int]:
        specs = self._specs(upload_id)
        if file_index >= len(specs):
            raise UploadError(f"file index {file_index} out of range")
        spec = specs[file_index]
        path = self.store.incoming_dir(upload_id) / spec.path
        have = path.stat().st_size if path.is_file() else 0
        if offset != have:
            raise UploadError(f"{spec.path}: chunk at {offset}, stored bytes end at {have}")
        if offset + len(data) > spec.size:
            raise UploadError(f"{spec.path}: chunk goes past the announced size {spec.size}")
        try:
            with path.open("ab") as handle:
                handle.write(data)
                handle.flush()
        except OSError as exc:
            # A full disk must not leave a half-written chunk behind: the upload goes, space comes back.
            if exc.errno in (errno.ENOSPC, errno.EFBIG, errno.EDQUOT):
                self.abort(upload_id)
                raise UploadError(f"disk full ({os.strerror(exc.errno)}): push refused, store unchanged") from None
            try:
                with path.open("ab") as handle:
                    handle.truncate(have)
            except OSError:
                self.abort(upload_id)
            raise UploadError(f"cannot store chunk: {os.strerror(exc.errno or 0)}") from None
        return self.received(upload_id)

    def complete(self, upload_id: str) -> Path:
        """The upload's folder once every file is whole and matches its sha256."""
        folder = self.store.incoming_dir(upload_id)
        for spec in self._specs(upload_id):
            path = folder / spec.path
            if not path.is_file() or path.stat().st_size != spec.size:
                raise UploadError(f"{spec.path} is incomplete")
            if sha256_file(path) != spec.sha256:
                self.abort(upload_id)
                raise UploadError(f"{spec.path}: content does not match its sha256; upload discarded")
            try:
                with path.open("rb") as handle:
                    os.fsync(handle.fileno())
            except OSError as exc:
                self.abort(upload_id)
                raise UploadError(f"cannot store {spec.path}: {os.strerror(exc.errno or 0)}") from None
        (folder / SPEC_FILE).unlink()
        return folder

    def abort(self, upload_id: str) -> None:
        shutil.rmtree(self.store.incoming_dir(upload_id), ignore_errors=True)
