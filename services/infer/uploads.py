"""Receiving a model over the bus in chunks, resumable, into the store's incoming folder.

An upload is identified by the hash of its file list (names, sizes, sha256), so the same push after a
broken link or a restart of either side continues where the stored bytes end.
"""
from __future__ import annotations

import errno
import hashlib
import json
import os
import shutil
from pathlib import Path

from courtloc.common.control import FileSpec
from courtloc.services.infer.store import ModelStore, sha256_file

SPEC_FILE = ".files.json"


class UploadError(RuntimeError):
    pass


def upload_id_of(files: list[FileSpec]) -> str:
    text = json.dumps([f.model_dump() for f in files], sort_keys=True)
    return hashlib.sha256(text.encode()).hexdigest()[:32]


class Uploads:
    def __init__(self, store: ModelStore, max_bytes: int) -> None:
        self.store = store
        self.max_bytes = max_bytes

    def begin(self, files: list[FileSpec]) -> tuple[str, list[int]]:
        names = [f.path for f in files]
        if len(set(names)) != len(names):
            raise UploadError("duplicate file names in the push")
        if "model.onnx" not in names:
            raise UploadError("a model push must contain model.onnx")
        if sum(f.size for f in files) > self.max_bytes:
            raise UploadError(f"push of {sum(f.size for f in files)} bytes exceeds the {self.max_bytes}-byte limit")
        upload_id = upload_id_of(files)
        folder = self.store.incoming_dir(upload_id)
        try:
            folder.mkdir(parents=True, exist_ok=True)
            (folder / SPEC_FILE).write_text(json.dumps([f.model_dump() for f in files]))
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
        except OSError as exc:
            # A full disk must not leave a half-written chunk behind: cut back to what was stored.
            with path.open("ab") as handle:
                handle.truncate(have)
            if exc.errno == errno.ENOSPC:
                self.abort(upload_id)
                raise UploadError("disk full: push refused, store unchanged") from None
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
            with path.open("rb") as handle:
                os.fsync(handle.fileno())
        (folder / SPEC_FILE).unlink()
        return folder

    def abort(self, upload_id: str) -> None:
        shutil.rmtree(self.store.incoming_dir(upload_id), ignore_errors=True)
