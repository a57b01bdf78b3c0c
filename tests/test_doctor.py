"""`courtloc doctor` reports what this machine has, checked against the libraries themselves, and what a
deployment needs; the Jetson profile's provider defaults."""
from __future__ import annotations

import copy
import importlib
import json
import re
import sys
from pathlib import Path

import pytest

from courtloc.cli import main
from courtloc.doctor import KERNELS, deployment_needs, machine_facts
from courtloc.services.infer.config import InferConfig, providers_for

PIPELINE = ("nvarguscamerasrc ! video/x-raw(memory:NVMM),width=640,height=480,framerate=30/1 ! nvvidconv ! "
            "video/x-raw,format=BGRx ! videoconvert ! video/x-raw,format=BGR ! appsink drop=1")


def _doctor(capsys: pytest.CaptureFixture[str], *args: str) -> tuple[int, str, str]:
    with pytest.raises(SystemExit) as exit_info:
        main(["doctor", *args])
    out, err = capsys.readouterr()
    return int(exit_info.value.code or 0), out, err


def test_the_table_graph_runs_on_the_cpu_by_default() -> None:
    config = InferConfig()
    assert providers_for(config, "scan_hits") == ["cpu"], "TensorRT cannot take the int16 table graph"
    assert providers_for(config, "sparse_hits") == ["cpu"]
    assert providers_for(config, "dense_image")[0] == "tensorrt", "the dense paper network may use a GPU"
    assert providers_for(InferConfig(providers=["cuda", "cpu"]), "scan_hits") == ["cuda", "cpu"]


def test_machine_facts_are_what_the_libraries_say(capsys: pytest.CaptureFixture[str]) -> None:
    import cv2
    import onnxruntime

    code, out, _ = _doctor(capsys, "--json", "-")
    report = json.loads(out)
    machine = report["machine"]
    gst = re.search(r"^\s*GStreamer:\s*(.+)$", cv2.getBuildInformation(), re.MULTILINE)
    assert gst is not None and machine["opencv"]["gstreamer_build"] == gst.group(1).strip()
    assert machine["opencv"]["version"] == cv2.__version__
    assert machine["onnxruntime"]["providers"] == onnxruntime.get_available_providers()
    for label, module in KERNELS.items():
        try:
            importlib.import_module(module)
            built = True
        except ImportError:
            built = False
        assert machine["kernels"][label] is built
    assert machine["shm"]["present"] == Path("/dev/shm").is_dir()
    assert machine["clock"]["synchronized"] in (True, False, None)
    from importlib import metadata

    assert machine["extras"]["rosbags"] == metadata.version("rosbags")
    assert code == (1 if any(n["level"] == "fail" for n in report["needs"]) else 0)
    infer = next(n for n in report["needs"] if n["what"] == "infer.providers")
    assert "CPUExecutionProvider" in infer["detail"]


def test_a_gstreamer_camera_needs_an_opencv_with_gstreamer(tmp_path: Path,
                                                          capsys: pytest.CaptureFixture[str]) -> None:
    config = tmp_path / "robot.toml"
    config.write_text(f'[camera]\nsource = "device"\n[camera.device]\ndevice = "{PIPELINE}"\n')
    has_gstreamer = machine_facts()["opencv"]["gstreamer"]
    code, out, _ = _doctor(capsys, "--config", str(config))
    line = next(line for line in out.splitlines() if "camera.device.device" in line)
    if has_gstreamer:
        assert line.startswith("  [ok") and code == 0
    else:
        assert line.startswith("  [FAIL]") and "system-site-packages" in line and code == 1


def test_two_onnxruntime_distributions_fail_the_deployment() -> None:
    from courtloc.services.deployment import load_deployment

    facts = copy.deepcopy(machine_facts())
    facts["onnxruntime"]["distributions"] = {"onnxruntime": "1.20.0", "onnxruntime-gpu": "1.20.0"}
    needs = deployment_needs(load_deployment(None), facts)
    assert any(n.level == "fail" and n.what == "onnxruntime" for n in needs)


def test_a_bad_config_is_one_line(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    config = tmp_path / "bad.toml"
    config.write_text('[infer]\nproviders = ["tpu"]\n')
    code, out, err = _doctor(capsys, "--config", str(config))
    assert code == 2 and out == "" and len(err.strip().splitlines()) == 1 and "providers" in err


def test_the_camera_names_a_missing_gstreamer() -> None:
    import cv2

    from courtloc.services.camera.config import DeviceSourceConfig
    from courtloc.services.camera.sources import DeviceSource, SourceError

    if cv2.videoio_registry.hasBackend(cv2.CAP_GSTREAMER):
        pytest.skip("this OpenCV has GStreamer")
    with pytest.raises(SourceError, match="no GStreamer.*docs/jetson.md"):
        DeviceSource(DeviceSourceConfig(device=PIPELINE)).open()


def test_a_shadowed_opencv_is_named(tmp_path: Path, monkeypatch: pytest.MonkeyPatch,
                                    capsys: pytest.CaptureFixture[str]) -> None:
    """JetPack's cv2 behind pip's (venv with system site packages, pip's OpenCV not uninstalled)."""
    system = tmp_path / "dist-packages"
    (system / "cv2").mkdir(parents=True)
    (system / "cv2" / "__init__.py").write_text("raise ImportError('never imported by the doctor')\n")
    monkeypatch.setattr(sys, "path", [*sys.path, str(system)])
    facts = machine_facts()
    assert facts["opencv"]["shadowed"] == [str((system / "cv2").resolve())]
    config = tmp_path / "robot.toml"
    config.write_text(f'[camera]\nsource = "device"\n[camera.device]\ndevice = "{PIPELINE}"\n')
    if not facts["opencv"]["gstreamer"]:
        code, out, _ = _doctor(capsys, "--config", str(config))
        assert code == 1 and "pip uninstall opencv-python-headless" in out
