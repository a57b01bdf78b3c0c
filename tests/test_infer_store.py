"""The model store and resumable uploads, on real files."""
from __future__ import annotations

import hashlib
from pathlib import Path

import pytest

from courtloc.common.control import FileSpec
from courtloc.services.infer.store import ModelRef, ModelStore, StoreError
from courtloc.services.infer.uploads import UploadError, Uploads


def _package(folder: Path, content: bytes = b"onnx-bytes") -> Path:
    folder.mkdir(parents=True)
    (folder / "model.onnx").write_bytes(content)
    (folder / "court.json").write_text("{}")
    return folder


def _spec(name: str, data: bytes) -> FileSpec:
    return FileSpec(path=name, size=len(data), sha256=hashlib.sha256(data).hexdigest())


def test_versions_and_active_record_survive_a_new_store_object(tmp_path: Path) -> None:
    store = ModelStore(tmp_path / "store")
    first = store.add_folder(_package(tmp_path / "a"), "loc")
    second = store.add_folder(_package(tmp_path / "b", b"v2"), "loc")
    assert (first.ref.version, second.ref.version) == (1, 2)
    store.set_active(first.ref)
    store.set_active(second.ref)
    reopened = ModelStore(tmp_path / "store")
    assert reopened.record().active == second.ref
    assert [m.ref.version for m in reopened.models()] == [1, 2]
    assert reopened.rollback() == first.ref
    assert reopened.record().active == first.ref
    with pytest.raises(StoreError):
        reopened.rollback()


def test_activating_a_missing_version_is_refused(tmp_path: Path) -> None:
    store = ModelStore(tmp_path)
    with pytest.raises(StoreError):
        store.set_active(ModelRef(name="loc", version=3))


def test_upload_resumes_where_the_stored_bytes_end(tmp_path: Path) -> None:
    store = ModelStore(tmp_path / "store")
    data = bytes(range(256)) * 40
    uploads = Uploads(store, max_bytes=1 << 20)
    upload_id, received = uploads.begin([_spec("model.onnx", data)])
    assert received == [0]
    uploads.chunk(upload_id, 0, 0, data[:1000])
    # the link broke; a new push of the same file learns where to continue
    again_id, received = Uploads(store, 1 << 20).begin([_spec("model.onnx", data)])
    assert again_id == upload_id and received == [1000]
    with pytest.raises(UploadError, match="stored bytes end at 1000"):
        uploads.chunk(upload_id, 0, 0, data[:10])
    uploads.chunk(upload_id, 0, 1000, data[1000:])
    folder = uploads.complete(upload_id)
    assert (folder / "model.onnx").read_bytes() == data


def test_corrupted_upload_is_discarded(tmp_path: Path) -> None:
    store = ModelStore(tmp_path / "store")
    data = b"x" * 100
    uploads = Uploads(store, max_bytes=1 << 20)
    upload_id, _ = uploads.begin([_spec("model.onnx", data)])
    uploads.chunk(upload_id, 0, 0, b"y" * 100)
    with pytest.raises(UploadError, match="sha256"):
        uploads.complete(upload_id)
    assert not store.incoming_dir(upload_id).exists()
    assert store.models() == []


def test_upload_limits(tmp_path: Path) -> None:
    uploads = Uploads(ModelStore(tmp_path), max_bytes=10)
    with pytest.raises(UploadError, match="limit"):
        uploads.begin([_spec("model.onnx", b"x" * 11)])
    with pytest.raises(UploadError, match="model.onnx"):
        Uploads(ModelStore(tmp_path), 100).begin([_spec("other.bin", b"x")])
    with pytest.raises(ValueError):
        FileSpec(path="../escape", size=1, sha256="0" * 64)
