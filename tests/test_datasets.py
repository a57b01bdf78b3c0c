"""Seed-format loading, recording splits, paper inputs and the duplicate-frame report."""
from __future__ import annotations

import csv
import math
from pathlib import Path

import numpy as np
import pytest

from courtloc.lab.datasets import (
    DatasetError,
    duplicate_report,
    load_dataset,
    read_labels,
    recording_of,
    split_by_recording,
)
from courtloc.localizer import paper_input
from courtloc.training.toy_data import write_toy_dataset


def test_labels_yaw_and_recording(tmp_path: Path) -> None:
    root = write_toy_dataset(tmp_path / "toy", frames_per_recording=5)
    ds = load_dataset(root)
    assert len(ds) == 10
    assert ds.recording_ids() == ["20240101", "20240102"]
    with (root / "pose_data.csv").open() as handle:
        first = next(csv.DictReader(handle))
    assert ds.yaw[0] == pytest.approx(2 * math.asin(float(first["orientation_z"])))
    assert ds.xy[0, 0] == pytest.approx(float(first["x"]))


def test_recording_column_overrides_file_name(tmp_path: Path) -> None:
    path = tmp_path / "labels.csv"
    path.write_text("image_filename,x,y,orientation_z,recording\n"
                    "img_20250101_0.png,1,2,0.5,runA\nframe_7.png,0,0,0,runB\n")
    rows = read_labels(path)
    assert [r.recording for r in rows] == ["runA", "runB"]
    assert rows[0].yaw == pytest.approx(math.pi / 3)


def test_missing_recording_and_columns_are_clear_errors(tmp_path: Path) -> None:
    with pytest.raises(DatasetError, match="recording"):
        recording_of("frame_7.png")
    path = tmp_path / "bad.csv"
    path.write_text("image_filename,x\nimg_20250101_0.png,1\n")
    with pytest.raises(DatasetError, match="orientation_z"):
        read_labels(path)


def test_split_by_recording_never_mixes() -> None:
    recs = np.array(["a", "a", "b", "c", "b", "a", "c"])
    train, val = split_by_recording(recs, val=["b"])
    assert set(recs[val]) == {"b"} and set(recs[train]) == {"a", "c"}
    assert len(train) + len(val) == len(recs) and not set(train) & set(val)
    train, val = split_by_recording(recs, val=["c"], train=["a"])
    assert set(recs[train]) == {"a"} and set(recs[val]) == {"c"}
    train, val = split_by_recording(recs)  # default: hold out the last recording seen
    assert set(recs[val]) == {"c"}
    with pytest.raises(DatasetError, match="both sides"):
        split_by_recording(recs, val=["a"], train=["a", "b"])
    with pytest.raises(DatasetError, match="not in the data"):
        split_by_recording(recs, val=["zzz"])


def test_dot_image_thresholds_jpeg_noise(tmp_path: Path) -> None:
    root = write_toy_dataset(tmp_path / "toy", frames_per_recording=3, jpeg=True)
    ds = load_dataset(root)
    dots = ds.dot_image(0)
    assert set(np.unique(dots).tolist()) <= {0, 1}
    # three radius-2 discs of 13 pixels each; JPEG ringing must not add pixels
    assert 30 <= int(dots.sum()) <= 39


def test_paper_inputs_dense_and_sparse_agree() -> None:
    hits = np.array([[250, 10, 0, 0], [479, 639, 5, 9], [100, 300, 3, 3]], dtype=np.int16)
    dense = paper_input.hits_to_dense_input(hits)
    assert dense.shape == (1, 280, 640) and dense.dtype == np.float32
    idx, val = paper_input.hits_to_sparse_input(hits)
    rebuilt = np.zeros(280 * 640, np.float32)
    rebuilt[idx] = val
    assert np.array_equal(rebuilt.reshape(280, 640), dense[0])
    # the hit at row 100 is above the crop; the corner disc is clipped to 6 pixels
    assert len(idx) == 13 + 6


def test_duplicate_report_counts_repeats(tmp_path: Path) -> None:
    root = write_toy_dataset(tmp_path / "toy", recordings=("20240101",), frames_per_recording=6)
    images = sorted((root / "images").iterdir())
    # make frames 1 and 2 copies of frame 0: two identical consecutive frames
    for target in images[1:3]:
        target.write_bytes(images[0].read_bytes())
    report = duplicate_report(load_dataset(root))
    assert report.n == 6
    assert report.identical == 2
    assert report.longest_identical_run == 2
    assert report.per_recording["20240101"]["identical"] == 2


def test_seed_dataset_loads(seed_dir: Path) -> None:
    ds = load_dataset(seed_dir)
    assert len(ds) == 5740
    assert ds.recording_ids() == ["20250622", "20250625"]
    train, val = split_by_recording(ds.recordings, val=["20250625"])
    assert len(train) == 3138 and len(val) == 2602
    assert np.all(np.abs(ds.yaw) <= math.pi)


def test_raw_frames_go_through_the_preprocessor(tmp_path: Path) -> None:
    import cv2

    from courtloc.scan.config import PreprocessConfig
    from courtloc.scan.preprocessor import Preprocessor
    from courtloc.scan.synthetic import line_frame

    root = tmp_path / "raw"
    (root / "images").mkdir(parents=True)
    frame = line_frame(np.random.default_rng(3), noise=0)
    cv2.imwrite(str(root / "images" / "img_20240301_000001.png"), frame)
    (root / "pose_data.csv").write_text("image_filename,x,y,orientation_z\nimg_20240301_000001.png,1,2,0\n")
    dots = load_dataset(root, kind="raw").dot_image(0)
    hits = Preprocessor(PreprocessConfig()).process(frame)
    assert len(hits) > 10  # the frame has lines, so the scan must find edges
    assert dots.shape == (480, 640) and set(np.unique(dots).tolist()) == {0, 1}
    assert np.all(dots[hits[:, 0], hits[:, 1]] == 1)  # a disc at every hit
    assert int(dots.sum()) <= 13 * len(hits)
