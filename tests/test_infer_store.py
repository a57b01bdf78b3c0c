"""The model store and resumable uploads, on real files."""
from __future__ import annotations

import hashlib
from pathlib import Path

import pytest

from courtloc.common.control import FileSpec
from courtloc.services.infer.store import ActiveRecord, ModelRef, ModelStore, StoreError
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


def test_history_is_bounded_and_keeps_the_rollback_order(tmp_path: Path) -> None:
    from courtloc.services.infer.store import HISTORY_LIMIT

    store = ModelStore(tmp_path / "store")
    refs = [store.add_folder(_package(tmp_path / f"p{i}", bytes([i])), f"m{i % 20}").ref for i in range(40)]
    for _ in range(3):
        for ref in refs:
            store.set_active(ref)
    history = store.record().history
    assert len(history) == HISTORY_LIMIT
    assert len(set(history)) == len(history)
    assert history == refs[-1 - HISTORY_LIMIT:-1], "the newest earlier models, oldest first"
    assert store.rollback() == refs[-2]
    assert store.record().active == refs[-2]


def test_a_legacy_record_moves_out_of_the_names_namespace(tmp_path: Path) -> None:
    store = ModelStore(tmp_path / "store")
    ref = store.add_folder(_package(tmp_path / "a"), "loc").ref
    (tmp_path / "store" / "active.json").write_text(ActiveRecord(active=ref).model_dump_json())
    reopened = ModelStore(tmp_path / "store")
    assert reopened.record().active == ref
    assert not (tmp_path / "store" / "active.json").exists()
    # and now a model may be called like the old record
    other = reopened.add_folder(_package(tmp_path / "b"), "active.json").ref
    reopened.set_active(other)
    assert ModelStore(tmp_path / "store").record().active == other


@pytest.mark.parametrize("name", [".", "..", ".files.json", "a/b", "x" * 300, "", "-x"])
def test_one_naming_rule_for_pushed_files(tmp_path: Path, name: str) -> None:
    uploads = Uploads(ModelStore(tmp_path), 1 << 20)
    with pytest.raises(UploadError, match="is not a plain name"):
        uploads.begin([_spec("model.onnx", b"m"), FileSpec.model_construct(path=name, size=1, sha256="0" * 64)])
    assert not any((tmp_path / ".incoming").iterdir())


def _package_with_part(tmp_path: Path, court_file: str) -> Path:
    """The bundled package with its manifest's court_file changed (sha256 unchanged)."""
    import shutil

    from courtloc.localizer.manifest import read_manifest, write_manifest
    from courtloc.models import bundled_package as bundled_default

    folder = tmp_path / "pkg"
    shutil.copytree(bundled_default(), folder)
    manifest = read_manifest(folder / "model.onnx")
    write_manifest(folder / "model.onnx",
                   manifest.model_copy(update={"extra": {**manifest.extra, "court_file": court_file}}))
    return folder


def test_package_parts_resolve_inside_the_folder_with_one_error_text(tmp_path: Path) -> None:
    from courtloc.localizer.manifest import ManifestError
    from courtloc.localizer.package import load_package

    cases = {}
    for case in ("absolute", "dotdot", "symlink", "missing", "wrong"):
        case_dir = tmp_path / case
        case_dir.mkdir()
        if case == "absolute":
            folder = _package_with_part(case_dir, str(case_dir / "pkg" / "court.json"))
        elif case == "dotdot":
            folder = _package_with_part(case_dir, "../pkg/court.json")
        elif case == "symlink":
            folder = _package_with_part(case_dir, "link.json")
            (case_dir / "court-elsewhere.json").write_bytes((folder / "court.json").read_bytes())
            (folder / "link.json").symlink_to(case_dir / "court-elsewhere.json")
        elif case == "missing":
            folder = _package_with_part(case_dir, "nothere.json")
        else:
            folder = _package_with_part(case_dir, "camera.json")  # exists, another part's content
        with pytest.raises(ManifestError) as caught:
            load_package(folder)
        cases[case] = str(caught.value)
    assert len(set(cases.values())) == 1, cases
    assert str(tmp_path) not in next(iter(cases.values())), "the reply names a path of the robot"
    assert load_package(_package_with_part(tmp_path / "ok", "court.json")).court is not None
