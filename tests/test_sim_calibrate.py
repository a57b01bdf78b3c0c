"""Calibration: recovers a known camera from twin edge images, and the seed camera from the seed recordings."""
from __future__ import annotations

import json

import numpy as np
import pytest

from courtloc.cli import main
from courtloc.lab.calibrate import (
    SEED_LAG_S,
    CalibrationOptions,
    calibrate,
    dot_reproduction,
    load_dot_frames,
    nominal_camera,
)
from courtloc.sim.labels import lag_corrected, read_pose_csv
from courtloc.sim.render import RenderOptions
from courtloc.sim.synth import SynthConfig, synth
from courtloc.world.camera import load_camera
from courtloc.world.court import load_court


@pytest.fixture(scope="module")
def twin_dataset(tmp_path_factory):
    """Edge images of the seed court seen by a camera unlike the seed's (higher, tilted, rolled, longer lens)."""
    out = tmp_path_factory.mktemp("calib")
    cam = load_camera("seed-gazebo").model_dump()
    cam.update(fx=420.0, fy=420.0)
    cam["mount"].update(height=0.61, pitch=0.05, roll=0.01, x=0.15, y=0.0, yaw=0.0)
    (out / "cam.json").write_text(json.dumps(cam))
    synth(SynthConfig(court="seed-gazebo", camera=str(out / "cam.json"), n=24, out=out, seed=1, kind="edges",
                      render=RenderOptions(), margin_m=1.0))
    return out


def test_recovers_a_known_camera_from_twin_edge_images(twin_dataset):
    dots = load_dot_frames(twin_dataset / "images", twin_dataset / "pose_data.csv", frames=24, lag_s=0.0)
    result = calibrate(load_court("seed-gazebo"), dots, nominal_camera(), CalibrationOptions())
    cam = result.camera
    assert cam.fx == pytest.approx(420.0, abs=3.0)
    assert cam.mount.height == pytest.approx(0.61, abs=0.01)
    assert cam.mount.pitch == pytest.approx(0.05, abs=0.005)
    assert cam.mount.roll == pytest.approx(0.01, abs=0.005)
    assert result.residual_px_median < 0.8


def test_calibrate_cli_reports_and_writes_camera(twin_dataset, tmp_path, capsys):
    out = tmp_path / "fitted.json"
    with pytest.raises(SystemExit) as exit_info:
        main(["calibrate", "--data", str(twin_dataset / "images"), "--csv", str(twin_dataset / "pose_data.csv"),
              "--court", "seed-gazebo", "--frames", "12", "--lag", "0", "--out", str(out)])
    assert exit_info.value.code == 0
    text = capsys.readouterr().out
    assert "residual px: median" in text and "residual floor m: median" in text
    fitted = load_camera(out)
    assert fitted.fx == pytest.approx(420.0, abs=5.0)


def test_calibrate_cli_missing_csv_is_a_clear_error(tmp_path, capsys):
    with pytest.raises(SystemExit) as exit_info:
        main(["calibrate", "--data", str(tmp_path), "--csv", str(tmp_path / "none.csv"), "--court", "seed-gazebo"])
    assert exit_info.value.code == 2
    assert "does not exist" in capsys.readouterr().err


@pytest.mark.seed
def test_recovers_the_seed_reference_camera_and_reproduces_seed_dots(seed_dir, seed_world):
    ref = json.loads(seed_world.read_text())["camera"]
    court = load_court("seed-gazebo")
    dots = load_dot_frames(seed_dir / "images", seed_dir / "pose_data.csv", frames=40, lag_s=SEED_LAG_S)
    result = calibrate(court, dots, nominal_camera(), CalibrationOptions())
    cam = result.camera
    assert cam.fx == pytest.approx(ref["f_px"], abs=3.0)
    assert cam.mount.height == pytest.approx(ref["height_m"], abs=0.01)
    assert cam.mount.pitch == pytest.approx(ref["pitch_down_rad"], abs=0.005)
    # The twin, with the fitted camera, run through the real preprocess stage at the labelled poses.
    labels = lag_corrected(read_pose_csv(seed_dir / "pose_data.csv"), SEED_LAG_S)
    picks = np.linspace(40, len(labels) - 1, 12).round().astype(int)
    dist = dot_reproduction(court, cam, seed_dir / "images", labels, picks)
    assert len(dist) > 800
    assert np.median(dist) <= 1.0


def test_optional_scale_and_line_width_stay_neutral_on_the_true_court(twin_dataset):
    dots = load_dot_frames(twin_dataset / "images", twin_dataset / "pose_data.csv", frames=16, lag_s=0.0)
    options = CalibrationOptions(fit_scale=True, fit_line_width=True)
    result = calibrate(load_court("seed-gazebo"), dots, nominal_camera(), options)
    assert result.court_scale == pytest.approx(1.0, abs=0.01)
    assert abs(result.line_width_change_m) < 0.006
    assert result.camera.fx == pytest.approx(420.0, abs=5.0)
