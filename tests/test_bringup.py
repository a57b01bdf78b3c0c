"""Bring-up of a camera that is not a bundled one, on twin renders, through the CLI a team uses:
chessboard views -> `calibrate intrinsics`; frames at measured poses -> `calibrate mount`;
`localizer build` -> a package that localises that camera's frames (docs/bringup.md)."""
from __future__ import annotations

import json
import math
import re
from pathlib import Path

import cv2
import numpy as np
import pytest

from courtloc.cli import main
from courtloc.sim.board_render import board_pose_looking_at, render_board
from courtloc.world.camera import CameraModel, load_camera
from courtloc.world.court import load_court

COURT = "robocon2025"
BOARD = (9, 6, 0.03)  # inner corners, square side in metres
# Unlike the bundled cameras (f 382.56, no distortion, 0.52 / 0.55 m, pitch 0.001 / 0.08 rad): a longer,
# barrel-distorted lens with an off-centre principal point, lower, tilted and rolled, offset on the robot.
TRUE = CameraModel(name="team-cam", fx=455.0, fy=455.0, cx=322.0, cy=236.0, width=640, height=480,
                   k1=-0.21, k2=0.05, p1=0.0007, p2=-0.0004,
                   mount={"x": 0.15, "y": -0.05, "yaw": 0.02, "height": 0.42, "pitch": 0.17, "roll": 0.01})
MOUNT_POSES = [(3.6, 0.3, 0.1), (5.8, -2.6, 1.3)]  # tape-measured stances facing the key and its side


def _run(argv: list[str], capsys) -> tuple[int, str, str]:
    with pytest.raises(SystemExit) as exit_info:
        main(argv)
    captured = capsys.readouterr()
    return int(exit_info.value.code), captured.out, captured.err


@pytest.fixture(scope="module")
def board_views(tmp_path_factory) -> Path:
    folder = tmp_path_factory.mktemp("board")
    rng = np.random.default_rng(3)
    cols, rows, square = BOARD
    for i in range(10):
        rvec, tvec = board_pose_looking_at(rng.uniform(0.35, 0.6), rng.uniform(-0.5, 0.5), rng.uniform(-0.5, 0.5),
                                           rng.uniform(-0.3, 0.3), (rng.uniform(-0.08, 0.08), rng.uniform(-0.06, 0.06)),
                                           cols, rows, square)
        cv2.imwrite(str(folder / f"view{i:02d}.png"), render_board(TRUE, cols, rows, square, rvec, tvec))
    return folder


@pytest.fixture(scope="module")
def court_frames(tmp_path_factory) -> list[Path]:
    from courtloc.sim.render import Renderer

    renderer = Renderer(load_court(COURT), TRUE)
    folders = []
    for k, pose in enumerate(MOUNT_POSES):
        folder = tmp_path_factory.mktemp(f"pose{k}")
        cv2.imwrite(str(folder / "frame0.png"), renderer.render(pose))
        folders.append(folder)
    return folders


def test_intrinsics_mount_and_package_for_a_new_camera(board_views, court_frames, tmp_path, capsys):
    intrinsics = tmp_path / "intrinsics.json"
    code, out, err = _run(["calibrate", "intrinsics", "--images", str(board_views), "--board", "9x6",
                           "--square", "0.03", "--out", str(intrinsics)], capsys)
    assert code == 0, err
    assert "reprojection error RMS" in out
    cam = load_camera(intrinsics)
    assert cam.fx == pytest.approx(TRUE.fx, rel=0.01) and cam.fy == pytest.approx(TRUE.fy, rel=0.01)
    assert cam.k1 == pytest.approx(TRUE.k1, abs=0.02)

    mounted = tmp_path / "team-cam.json"
    argv = ["calibrate", "mount", "--court", COURT, "--camera", str(intrinsics), "--check", "--out", str(mounted)]
    for pose, folder in zip(MOUNT_POSES, court_frames):
        argv += ["--pose", ",".join(str(v) for v in pose), "--frames", str(folder)]
    code, out, err = _run(argv, capsys)
    assert code == 0, err
    assert "median_px" in out  # --check: the residual per line, pixels
    for name in ("height", "pitch", "roll", "mount_x", "mount_y", "mount_yaw"):  # each with its 1-sigma
        assert re.search(rf"^{name} +[-+][0-9.]+ \+- [0-9.]+ (m|deg)$", out, re.MULTILINE), (name, out)
    assert "edge x = +5.03 m (facing +x)" in out  # the key's front edge, residual per line
    fitted = load_camera(mounted)
    assert fitted.fx == cam.fx  # intrinsics kept from the chessboard
    assert fitted.mount.height == pytest.approx(TRUE.mount.height, abs=0.01)
    assert math.degrees(abs(fitted.mount.pitch - TRUE.mount.pitch)) <= 0.3
    assert fitted.mount.x == pytest.approx(TRUE.mount.x, abs=0.03)
    assert fitted.mount.y == pytest.approx(TRUE.mount.y, abs=0.03)
    assert math.degrees(abs(fitted.mount.roll - TRUE.mount.roll)) <= 0.3
    assert math.degrees(abs(fitted.mount.yaw - TRUE.mount.yaw)) <= 0.5

    package = tmp_path / "pkg"
    code, out, err = _run(["localizer", "build", "--court", COURT, "--camera", str(mounted), "--out", str(package)],
                          capsys)
    assert code == 0, err
    errors = _track_errors(package)
    assert len(errors) >= 20 and float(np.mean(errors)) <= 0.03, errors


def _track_errors(package: Path) -> list[float]:
    """Position error of every valid pose the package reports while the TRUE camera drives past the key."""
    from courtloc.localizer import acquire
    from courtloc.localizer.predictor import load_predictor
    from courtloc.sim.edges import scan_hits
    from courtloc.sim.render import Renderer

    renderer = Renderer(load_court(COURT), TRUE)
    predictor = load_predictor(package)
    # The team starts the robot at a known pose (`[infer] start`): the evidence acquisition decides on.
    start = acquire.Prior(source="start", pose=np.array([3.2, -0.6, 0.2]), std_m=0.3, yaw_std_rad=0.2)
    state, errors = acquire.Acquiring(prior=start), []
    for i in range(30):  # 1.5 m/s for 1 s at 30 Hz, turning slowly, in front of the key
        t = i / 30.0
        pose = (3.2 + 1.5 * t * math.cos(0.4), -0.6 + 1.5 * t * math.sin(0.4), 0.2 + 0.3 * t)
        hits = scan_hits(renderer.render(pose))
        pred, state = predictor.track(hits, 640, 480, state, t=t)
        if pred.valid:
            errors.append(math.hypot(pred.x - pose[0], pred.y - pose[1]))
    return errors


def test_too_few_or_blurred_views_are_refused_with_the_reason(board_views, tmp_path, capsys):
    blurred = tmp_path / "blurred"
    blurred.mkdir()
    for path in sorted(board_views.glob("*.png"))[:9]:
        image = cv2.imread(str(path), cv2.IMREAD_GRAYSCALE)
        cv2.imwrite(str(blurred / path.name), cv2.GaussianBlur(image, (0, 0), 2.0) if path.name < "view05" else image)
    code, out, err = _run(["calibrate", "intrinsics", "--images", str(blurred), "--board", "9x6", "--square", "0.03",
                           "--out", str(tmp_path / "c.json")], capsys)
    assert code == 2 and "4 usable views, 8 needed" in err and "view00.png: blurred: edge width" in err
    assert len(err.strip().splitlines()) == 1 and not (tmp_path / "c.json").exists()
    code, _, err = _run(["calibrate", "intrinsics", "--images", str(board_views), "--board", "9", "--square", "0.03",
                         "--out", str(tmp_path / "c.json")], capsys)
    assert code == 2 and "COLSxROWS" in err


def test_camera_info_yaml_imports_from_ros_and_opencv(tmp_path, capsys):
    ros = tmp_path / "ros.yaml"
    ros.write_text("image_width: 640\nimage_height: 480\ncamera_name: front\ncamera_matrix:\n  rows: 3\n  cols: 3\n"
                   "  data: [500.5, 0, 321.2, 0, 501.0, 238.9, 0, 0, 1]\ndistortion_model: plumb_bob\n"
                   "distortion_coefficients:\n  rows: 1\n  cols: 5\n  data: [-0.28, 0.07, 0.0001, -0.0002, 0]\n")
    code, _, err = _run(["calibrate", "intrinsics", "--camera-info", str(ros), "--out", str(tmp_path / "r.json")],
                        capsys)
    assert code == 0, err
    cam = load_camera(tmp_path / "r.json")
    assert (cam.fx, cam.fy, cam.cx, cam.cy, cam.k1, cam.k2, cam.p1, cam.p2) == (500.5, 501.0, 321.2, 238.9, -0.28,
                                                                                 0.07, 0.0001, -0.0002)
    opencv = tmp_path / "opencv.yaml"
    storage = cv2.FileStorage(str(opencv), cv2.FILE_STORAGE_WRITE)
    storage.write("image_width", 800)
    storage.write("image_height", 600)
    storage.write("camera_matrix", np.array([[610.0, 0, 401.0], [0, 612.0, 299.0], [0, 0, 1]]))
    storage.write("distortion_coefficients", np.array([[-0.1, 0.01, 0.0, 0.0, 0.002]]))
    storage.release()
    code, _, err = _run(["calibrate", "intrinsics", "--camera-info", str(opencv), "--out", str(tmp_path / "o.json")],
                        capsys)
    assert code == 0, err
    cam = load_camera(tmp_path / "o.json")
    assert (cam.width, cam.height, cam.fx, cam.fy, cam.k3) == (800, 600, 610.0, 612.0, 0.002)
    fisheye = tmp_path / "fisheye.yaml"
    fisheye.write_text(ros.read_text().replace("plumb_bob", "equidistant"))
    code, _, err = _run(["calibrate", "intrinsics", "--camera-info", str(fisheye), "--out", str(tmp_path / "f.json")],
                        capsys)
    assert code == 2 and "equidistant" in err


def test_mount_cli_mistakes_are_one_line(tmp_path, capsys):
    (tmp_path / "cam.json").write_text(json.dumps(TRUE.model_dump()))
    code, _, err = _run(["calibrate", "mount", "--court", COURT, "--camera", str(tmp_path / "cam.json"),
                         "--pose", "1,2", "--frames", str(tmp_path)], capsys)
    assert code == 2 and "X,Y,YAW" in err and len(err.strip().splitlines()) == 1
    code, _, err = _run(["calibrate", "mount", "--court", COURT, "--camera", str(tmp_path / "cam.json"),
                         "--pose", "1,2,0", "--frames", str(tmp_path)], capsys)
    assert code == 2 and "no image files" in err


@pytest.mark.integration
def test_mount_live_takes_frames_from_the_running_camera_topic(tmp_path, capsys) -> None:
    """`calibrate mount --live` as its own process, joining a real router where frames of the new camera,
    standing at a measured pose, are being published as the camera stage would."""
    import subprocess
    import threading

    from buskit import PYTHON, BusClient, free_port, start_router, write_config

    from courtloc.common import codec
    from courtloc.common.messages import Frame, Header
    from courtloc.sim.render import Renderer

    port = free_port()
    config = write_config(tmp_path / "robot.toml", port)
    (tmp_path / "cam.json").write_text(json.dumps(TRUE.model_dump()))
    image = Renderer(load_court(COURT), TRUE).render(MOUNT_POSES[0])
    router = start_router(port)
    client = BusClient(port)
    stop = threading.Event()

    def camera() -> None:  # the camera stage's stream, 10 Hz
        seq = 0
        while not stop.wait(0.1):
            header = Header.now("robot1", seq, "camera")
            header.valid = True
            frame = Frame(header=header, width=640, height=480, encoding="bgr8", data=image.tobytes())
            client.put_raw("camera/frame", codec.encode(frame))
            seq += 1

    streamer = threading.Thread(target=camera, daemon=True)
    streamer.start()
    try:
        done = subprocess.run([*PYTHON, "calibrate", "mount", "--court", COURT, "--camera", str(tmp_path / "cam.json"),
                               "--pose", ",".join(str(v) for v in MOUNT_POSES[0]), "--live", "--live-frames", "3",
                               "--save", str(tmp_path / "live"), "--config", str(config),
                               "--out", str(tmp_path / "mounted.json")],
                              capture_output=True, text=True, timeout=180)
    finally:
        stop.set()
        streamer.join(2.0)
        client.close()
        router.stop()
    assert done.returncode == 0, done.stderr
    assert len(list((tmp_path / "live").glob("live*.png"))) == 3
    fitted = load_camera(tmp_path / "mounted.json")
    assert fitted.mount.height == pytest.approx(TRUE.mount.height, abs=0.01)
    assert math.degrees(abs(fitted.mount.pitch - TRUE.mount.pitch)) <= 0.3
