"""Pose label CSVs in the seed format: image_filename, x, y, orientation_z (yaw = 2*asin(z), w >= 0).

Also the image->label lag correction: the seed's image at file-name time t matches the pose at t + lag.
"""
from __future__ import annotations

import csv
import math
import re
from pathlib import Path

import numpy as np
from pydantic import BaseModel, ConfigDict

SEED_COLUMNS = ("image_filename", "x", "y", "orientation_z")
# img_YYYYMMDD_HHMMSS_micro.jpg, the seed recorder's naming; the date part names the recording.
_STAMP = re.compile(r"(\d{8})_(\d{2})(\d{2})(\d{2})_(\d{6})")


class PoseLabels(BaseModel):
    """Rows of a pose CSV as arrays (yaw already converted from orientation_z)."""

    model_config = ConfigDict(arbitrary_types_allowed=True)
    filenames: list[str]
    x: np.ndarray
    y: np.ndarray
    yaw: np.ndarray

    def __len__(self) -> int:
        return len(self.filenames)


def yaw_to_orientation_z(yaw: float | np.ndarray) -> float | np.ndarray:
    """z of the yaw-only quaternion with w >= 0 (wrap yaw to (-pi, pi] first)."""
    wrapped = np.mod(np.asarray(yaw) + np.pi, 2 * np.pi) - np.pi
    return np.sin(wrapped / 2)


def orientation_z_to_yaw(z: float | np.ndarray) -> float | np.ndarray:
    return 2 * np.arcsin(np.clip(z, -1.0, 1.0))


def read_pose_csv(path: str | Path) -> PoseLabels:
    """Read a seed-format CSV; any malformed row is an error naming the file, line and column."""
    path = Path(path)
    if not path.is_file():
        raise ValueError(f"pose CSV {path} does not exist")
    names: list[str] = []
    values: list[tuple[float, float, float]] = []
    with path.open(newline="") as handle:
        reader = csv.DictReader(handle)
        missing = [c for c in SEED_COLUMNS if c not in (reader.fieldnames or [])]
        if missing:
            raise ValueError(f"{path}: missing columns {missing}; expected {list(SEED_COLUMNS)}")
        for line, row in enumerate(reader, start=2):
            try:
                x, y, z = (float(row[c]) for c in ("x", "y", "orientation_z"))
            except (TypeError, ValueError) as exc:
                raise ValueError(f"{path} line {line}: not a number in x, y or orientation_z ({exc})") from None
            if not all(math.isfinite(v) for v in (x, y, z)) or abs(z) > 1.0:
                raise ValueError(f"{path} line {line}: x, y must be finite and |orientation_z| <= 1")
            names.append(row["image_filename"])
            values.append((x, y, z))
    if not names:
        raise ValueError(f"{path}: no rows")
    arr = np.array(values)
    return PoseLabels(filenames=names, x=arr[:, 0], y=arr[:, 1], yaw=orientation_z_to_yaw(arr[:, 2]))


def filename_time(name: str) -> tuple[str, float] | None:
    """(recording, seconds of day) from a seed-style image name, or None if it carries no stamp."""
    match = _STAMP.search(name)
    if not match:
        return None
    day, hh, mm, ss, micro = match.groups()
    return day, int(hh) * 3600 + int(mm) * 60 + int(ss) + int(micro) * 1e-6


def lag_corrected(labels: PoseLabels, lag_s: float) -> PoseLabels:
    """Poses interpolated at each image's time + lag, within its recording (yaw unwrapped first).

    Rows without a time stamp, and the ends of a recording, keep their labelled pose.
    """
    stamps = [filename_time(n) for n in labels.filenames]
    x, y, yaw = labels.x.copy(), labels.y.copy(), labels.yaw.copy()
    recordings: dict[str, list[int]] = {}
    for i, stamp in enumerate(stamps):
        if stamp is not None:
            recordings.setdefault(stamp[0], []).append(i)
    for rows in recordings.values():
        idx = np.array(sorted(rows, key=lambda i: stamps[i][1]))  # type: ignore[index]
        t = np.array([stamps[i][1] for i in idx])  # type: ignore[index]
        unwrapped = np.unwrap(labels.yaw[idx])
        x[idx] = np.interp(t + lag_s, t, labels.x[idx])
        y[idx] = np.interp(t + lag_s, t, labels.y[idx])
        yaw[idx] = np.angle(np.exp(1j * np.interp(t + lag_s, t, unwrapped)))
    return PoseLabels(filenames=labels.filenames, x=x, y=y, yaw=yaw)
