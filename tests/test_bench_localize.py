"""`courtloc bench localize`: what it reports of the colour-marks search (marks_search.py), on a court with colour marks
and on one without. Times are the bench's to report, not this test's to judge."""
from __future__ import annotations

import json
from pathlib import Path

import pytest
from cli_in_process import courtloc_in_process

from courtloc.localizer.package import bundled_package


def _bench(package: Path, out: Path, capsys: pytest.CaptureFixture[str], caplog: pytest.LogCaptureFixture) -> dict:
    done = courtloc_in_process(["bench", "localize", "--package", str(package), "--frames", "3", "--repeats", "1",
                                "--cold-repeats", "1", "--json", str(out)], capsys, caplog)
    assert done.returncode == 0, done.stderr
    return json.loads(out.read_text())


def test_the_marks_search_is_timed_on_the_frames_that_show_enough_marks(tmp_path: Path,
                                                                         capsys: pytest.CaptureFixture[str],
                                                                         caplog: pytest.LogCaptureFixture) -> None:
    result = _bench(bundled_package("robocon2025", "robocon2025"), tmp_path / "r25.json", capsys, caplog)
    assert result["marks_per_frame_median"] > 0
    assert 1 <= result["marks_search"]["n"] <= result["frames"] and result["marks_search"]["median_ms"] > 0
    assert result["marks_search_max_points"] == 30


def test_a_court_without_colour_marks_times_no_marks_search(tmp_path: Path, capsys: pytest.CaptureFixture[str],
                                                             caplog: pytest.LogCaptureFixture) -> None:
    result = _bench(bundled_package("seed-gazebo", "seed-gazebo"), tmp_path / "seed.json", capsys, caplog)
    assert result["marks_per_frame_median"] == 0 and result["marks_search"] == {"n": 0}
    assert result["global_search"]["n"] == 3
