"""`courtloc preprocess` and `courtloc bench preprocess`, run as real commands."""
from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import cv2
import numpy as np
import pytest
from cli_in_process import courtloc_in_process

from courtloc.scan.config import PreprocessConfig
from courtloc.scan.reference_scan import reference_preprocess
from courtloc.scan.synthetic import line_frame


def courtloc(*args: str) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "courtloc", *args], capture_output=True, text=True, timeout=120)


@pytest.fixture(scope="module")
def odd_image(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, np.ndarray]:
    frame = line_frame(np.random.default_rng(4), 333, 517)
    path = tmp_path_factory.mktemp("cli") / "frame.png"
    assert cv2.imwrite(str(path), frame)
    return path, frame


def test_preprocess_json_is_exactly_the_documented_format(odd_image: tuple[Path, np.ndarray]) -> None:
    path, frame = odd_image
    result = courtloc("preprocess", str(path), "--json", "-")
    assert result.returncode == 0, result.stderr
    report = json.loads(result.stdout)
    assert list(report) == ["width", "height", "hits"]
    assert (report["width"], report["height"]) == (517, 333)
    expected = reference_preprocess(frame, PreprocessConfig(frame_width=None, frame_height=None, crop_top=0))
    assert len(expected) > 10
    assert report["hits"] == expected.tolist()


def test_preprocess_text_output_lists_the_hits(odd_image: tuple[Path, np.ndarray]) -> None:
    path, _ = odd_image
    result = courtloc("preprocess", str(path))
    assert result.returncode == 0, result.stderr
    lines = result.stdout.splitlines()
    n_hits = int(lines[0].split(", ")[1].split()[0])
    assert lines[1] == "row col ray d" and len(lines) == 2 + n_hits
    assert all(len(line.split()) == 4 for line in lines[2:])


def test_preprocess_refuses_bad_files_with_the_reason(tmp_path: Path, capsys: pytest.CaptureFixture[str],
                                                      caplog: pytest.LogCaptureFixture) -> None:
    garbage = tmp_path / "garbage.jpg"
    garbage.write_bytes(b"not an image at all")
    empty = tmp_path / "empty.jpg"
    empty.write_bytes(b"")
    for path, words in ((garbage, "not a decodable image"), (empty, "is empty"), (tmp_path / "missing.jpg", "No such")):
        # in this process: the exit code and the printed lines are the proof (the other tests run the command)
        result = courtloc_in_process(["preprocess", str(path), "--json", "-"], capsys, caplog)
        assert result.returncode == 1
        assert words in result.stderr and result.stdout == ""


def test_preprocess_refuses_a_bad_config_naming_the_field(odd_image: tuple[Path, np.ndarray], tmp_path: Path,
                                                          capsys: pytest.CaptureFixture[str],
                                                          caplog: pytest.LogCaptureFixture) -> None:
    config = tmp_path / "pre.toml"
    config.write_text("[scan]\nangle_step_deg = -2\n")
    result = courtloc_in_process(["preprocess", str(odd_image[0]), "--config", str(config)], capsys, caplog)
    assert result.returncode == 2 and "angle_step_deg" in result.stderr


def test_bench_preprocess_reports_both_paths(tmp_path: Path) -> None:
    out = tmp_path / "bench.json"
    result = courtloc("bench", "preprocess", "--json", str(out), "--width", "160", "--height", "120",
                      "--frames", "2", "--reference-frames", "1", "--seconds", "0.3", "--rounds", "1")
    assert result.returncode == 0, result.stderr
    report = json.loads(out.read_text())
    assert report["identical_to_reference"] is True
    assert report["fast_fps"] > 0 and report["reference_fps"] > 0
    assert report["ratio"] == pytest.approx(report["fast_fps"] / report["reference_fps"], rel=0.01)
    assert (report["width"], report["height"]) == (160, 120)
