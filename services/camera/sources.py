"""Frame sources of the camera service: a device, a video file, a folder of images.

Every source raises `SourceError` when it cannot deliver; the service closes it and reopens with
back-off, so an unplugged camera never crashes the process. A source is made from the camera config by
the factory of its kind (`ROBOT_SOURCES`); the simulated camera ("sim") is the digital twin's, which the
robot side never imports: the twin's camera stage (courtloc.sim.camera_stage) runs the same service with
its own source added to these kinds.
"""
from __future__ import annotations

import csv
import math
from dataclasses import dataclass
from pathlib import Path
from typing import Callable, Mapping, Protocol

import cv2
import numpy as np

from courtloc.services.camera.config import CameraConfig, DeviceSourceConfig, FileSourceConfig, FolderSourceConfig


class SourceError(RuntimeError):
    pass


@dataclass
class Capture:
    frame: np.ndarray  # BGR uint8, H x W x 3
    truth: tuple[float, float, float] | None  # x, y, yaw when the source knows it
    taken_mono_ns: int | None = None  # when the frame was taken (monotonic), when the source knows it better than now


class FrameSource(Protocol):
    """open() -> read() ... -> close(); read() gives the frame, the true pose when the source knows it and,
    when it knows better than now, the instant the frame shows (Capture)."""

    def open(self) -> None: ...
    def read(self, out: np.ndarray | None = None) -> Capture:
        """The next frame; a source that decodes may write it into `out` (when the shape fits) and return it."""

    def close(self) -> None: ...


class DeviceSource:
    def __init__(self, config: DeviceSourceConfig) -> None:
        self.config = config
        self._cap: cv2.VideoCapture | None = None

    def open(self) -> None:
        dev = self.config.device
        if not dev.isdigit() and not cv2.videoio_registry.hasBackend(cv2.CAP_GSTREAMER):
            # pip's opencv-python has no GStreamer: say so instead of "cannot open" (docs/jetson.md)
            raise SourceError("camera.device.device is a GStreamer pipeline, but this OpenCV has no GStreamer: use "
                              "JetPack's OpenCV or a V4L2 index (docs/jetson.md)")
        cap = cv2.VideoCapture(int(dev)) if dev.isdigit() else cv2.VideoCapture(dev, cv2.CAP_GSTREAMER)
        if not cap.isOpened():
            raise SourceError(f"cannot open camera device {dev!r}")
        cap.set(cv2.CAP_PROP_FRAME_WIDTH, self.config.width)
        cap.set(cv2.CAP_PROP_FRAME_HEIGHT, self.config.height)
        cap.set(cv2.CAP_PROP_FPS, self.config.fps)
        self._cap = cap

    def read(self, out: np.ndarray | None = None) -> Capture:
        if self._cap is None:
            raise SourceError("device not open")
        ok, frame = self._cap.read(out) if out is not None else self._cap.read()
        if not ok or frame is None:
            raise SourceError(f"camera {self.config.device!r} returned no frame")
        return Capture(frame, None)

    def close(self) -> None:
        if self._cap is not None:
            self._cap.release()
            self._cap = None


class FileSource:
    def __init__(self, config: FileSourceConfig) -> None:
        self.config = config
        self._cap: cv2.VideoCapture | None = None

    def open(self) -> None:
        if not self.config.path.is_file():
            raise SourceError(f"video file {self.config.path} not found")
        cap = cv2.VideoCapture(str(self.config.path))
        if not cap.isOpened():
            raise SourceError(f"cannot decode video file {self.config.path}")
        self._cap = cap

    def read(self, out: np.ndarray | None = None) -> Capture:
        if self._cap is None:
            raise SourceError("file not open")
        ok, frame = self._cap.read(out) if out is not None else self._cap.read()
        if not ok and self.config.loop:
            self._cap.set(cv2.CAP_PROP_POS_FRAMES, 0)
            ok, frame = self._cap.read(out) if out is not None else self._cap.read()
        if not ok or frame is None:
            raise SourceError(f"end of {self.config.path}")
        return Capture(frame, None)

    def close(self) -> None:
        if self._cap is not None:
            self._cap.release()
            self._cap = None


def read_seed_poses(path: Path) -> dict[str, tuple[float, float, float]]:
    """image_filename -> (x, y, yaw) from a seed-format CSV (yaw = 2 asin(orientation_z))."""
    poses: dict[str, tuple[float, float, float]] = {}
    try:
        with path.open(newline="") as handle:
            for line_no, row in enumerate(csv.DictReader(handle), start=2):
                try:
                    z = float(row["orientation_z"])
                    poses[row["image_filename"]] = (float(row["x"]), float(row["y"]), 2.0 * math.asin(z))
                except (KeyError, TypeError, ValueError) as exc:
                    raise SourceError(f"{path}:{line_no}: bad pose row ({exc})") from None
    except OSError as exc:
        raise SourceError(f"cannot read {path}: {exc.strerror}") from None
    return poses


class FolderSource:
    def __init__(self, config: FolderSourceConfig) -> None:
        self.config = config
        self._files: list[Path] = []
        self._poses: dict[str, tuple[float, float, float]] = {}
        self._index = 0

    def open(self) -> None:
        if not self.config.path.is_dir():
            raise SourceError(f"image folder {self.config.path} not found")
        self._files = sorted(self.config.path.glob(self.config.pattern))
        if not self._files:
            raise SourceError(f"no {self.config.pattern} images in {self.config.path}")
        self._poses = read_seed_poses(self.config.csv) if self.config.csv else {}
        self._index = 0

    def read(self, out: np.ndarray | None = None) -> Capture:
        if self._index >= len(self._files):
            if not self.config.loop:
                raise SourceError(f"end of folder {self.config.path}")
            self._index = 0
        path = self._files[self._index]
        self._index += 1
        frame = cv2.imread(str(path), cv2.IMREAD_COLOR)
        if frame is None:
            raise SourceError(f"cannot decode {path}")
        return Capture(frame, self._poses.get(path.name))

    def close(self) -> None:
        self._files = []


SourceFactory = Callable[[CameraConfig], FrameSource]


def _file_source(config: CameraConfig) -> FrameSource:
    assert config.file is not None  # CameraConfig requires the section of its source
    return FileSource(config.file)


def _folder_source(config: CameraConfig) -> FrameSource:
    assert config.folder is not None
    return FolderSource(config.folder)


ROBOT_SOURCES: Mapping[str, SourceFactory] = {
    "device": lambda config: DeviceSource(config.device),
    "file": _file_source,
    "folder": _folder_source,
}


def make_source(config: CameraConfig, kinds: Mapping[str, SourceFactory] = ROBOT_SOURCES) -> FrameSource:
    """The source of `config.source` from its factory in `kinds`; a kind not there is a ValueError that says
    where it lives (the process stops at start with it)."""
    factory = kinds.get(config.source)
    if factory is None:
        where = ("the digital twin's: its camera stage is `python -m courtloc.sim.camera_stage`, which "
                 "`courtloc up` and `courtloc run camera` start" if config.source == "sim" else "unknown")
        raise ValueError(f"camera source {config.source!r} is not one of this camera stage's "
                         f"({', '.join(kinds)}): it is {where}")
    return factory(config)
