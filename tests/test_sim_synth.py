"""Synthetic datasets: seed format, labels consistent with the images, resumable, CLI."""
from __future__ import annotations

import csv
import math

import cv2
import numpy as np
import pytest

from courtloc.cli import main
from courtloc.sim.labels import read_pose_csv
from courtloc.sim.synth import SynthConfig, image_name, synth
from courtloc.world.court import load_court


def _rows(path):
    with open(path, newline="") as handle:
        return list(csv.reader(handle))


def test_synth_writes_seed_format_and_resumes(tmp_path):
    out = tmp_path / "ds"
    first = synth(SynthConfig(court="robocon2025", n=4, out=out, seed=2, kind="edges"))
    assert first["written"] == 4
    rows = _rows(out / "pose_data.csv")
    assert rows[0] == ["image_filename", "x", "y", "orientation_z"] and len(rows) == 5
    images = [cv2.imread(str(out / "images" / row[0]), cv2.IMREAD_GRAYSCALE) for row in rows[1:]]
    assert all(image.shape == (480, 640) for image in images)
    assert sum(int((image > 127).sum()) for image in images) > 13 * 40  # dots were found and drawn
    before = (out / "images" / image_name(2, 3)).read_bytes()
    (out / "images" / image_name(2, 3)).unlink()
    second = synth(SynthConfig(court="robocon2025", n=6, out=out, seed=2, kind="edges"))
    assert second == {"total": 6, "written": 3, "skipped": 3, "out": str(out)}
    assert (out / "images" / image_name(2, 3)).read_bytes() == before  # same frame again, bit for bit
    labels = read_pose_csv(out / "pose_data.csv")
    assert len(labels) == 6 and len(set(labels.filenames)) == 6
    court = load_court("robocon2025")
    assert np.all(court.contains(labels.x, labels.y))
    with pytest.raises(ValueError, match="other settings"):
        synth(SynthConfig(court="robocon2025", n=6, out=out, seed=3, kind="edges"))


def test_synth_labels_match_the_rendered_frame(tmp_path):
    """The CSV pose, through yaw = 2*asin(z), re-renders the stored raw frame."""
    from courtloc.sim.render import Renderer, RenderOptions
    from courtloc.world.camera import load_camera

    out = tmp_path / "raw"
    synth(SynthConfig(court="seed-gazebo", n=2, out=out, kind="raw", render=RenderOptions(), jpeg_quality=100))
    labels = read_pose_csv(out / "pose_data.csv")
    court = load_court("seed-gazebo")
    renderer = Renderer(court, load_camera("seed-gazebo"))
    for i, name in enumerate(labels.filenames):
        stored = cv2.imread(str(out / "images" / name)).astype(int)
        again = renderer.render((labels.x[i], labels.y[i], labels.yaw[i])).astype(int)
        turned = renderer.render((labels.x[i], labels.y[i], labels.yaw[i] + 0.05)).astype(int)
        assert np.abs(stored - again).mean() < 2.0 < np.abs(stored - turned).mean()


def test_synth_covers_court_and_headings(tmp_path):
    from courtloc.sim.synth import sample_pose

    court = load_court("robocon2025")
    poses = np.array([sample_pose(court, 0, i, 0.2) for i in range(2000)])
    assert np.all(court.contains(poses[:, 0], poses[:, 1], margin=0.19))
    assert np.ptp(poses[:, 0]) > 14 and np.ptp(poses[:, 1]) > 7
    counts, _ = np.histogram(poses[:, 2], bins=8, range=(-math.pi, math.pi))
    assert counts.min() > 150


def test_dataset_synth_cli(tmp_path, capsys):
    out = tmp_path / "cli"
    with pytest.raises(SystemExit) as exit_info:
        main(["dataset", "synth", "--court", "seed-gazebo", "--n", "3", "--out", str(out), "--kind", "edges", "--seed", "5"])
    assert exit_info.value.code == 0
    captured = capsys.readouterr()
    assert '"written": 3' in captured.out and "3/3" in captured.err
    assert len(list((out / "images").glob("*.jpg"))) == 3
    with pytest.raises(SystemExit) as exit_info:
        main(["dataset", "synth", "--court", "atlantis", "--n", "3", "--out", str(out)])
    assert exit_info.value.code == 2
    assert "unknown court 'atlantis'" in capsys.readouterr().err
