"""Seed-format recordings as the localizer's lab sees them: scan hits of each frame and the lag-corrected
true poses (the seed's labels lag its images by ~15 ms, see its README)."""
from __future__ import annotations

import re
from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np

from courtloc.lab.datasets import load_dataset
from courtloc.world.angles import wrap_angle

_STAMP = re.compile(r"_(\d{2})(\d{2})(\d{2})_(\d{6})\.")


@dataclass
class SeedFrames:
    filenames: list[str]
    recordings: np.ndarray
    hits: list[np.ndarray]  # int16 (N, 4) per frame
    truth: np.ndarray  # (n, 3) x, y, yaw (lag-corrected when time stamps allow)
    width: int
    height: int


def _stamp(filename: str) -> float | None:
    m = _STAMP.search(filename)
    if not m:
        return None
    hh, mm, ss, us = (int(g) for g in m.groups())
    return hh * 3600 + mm * 60 + ss + us * 1e-6


def lag_corrected(poses: np.ndarray, filenames: list[str], recordings: np.ndarray, lag_s: float) -> np.ndarray:
    """Labels interpolated at image time + lag_s within each recording (unchanged where no time stamp)."""
    out = poses.copy()
    stamps = [_stamp(f) for f in filenames]
    if lag_s == 0 or any(s is None for s in stamps):
        return out
    t_all = np.array(stamps, np.float64)
    for rec in np.unique(recordings):
        idx = np.nonzero(recordings == rec)[0]
        idx = idx[np.argsort(t_all[idx], kind="stable")]
        t = t_all[idx]
        yaw = np.unwrap(poses[idx, 2])
        for k, column in enumerate((poses[idx, 0], poses[idx, 1], yaw)):
            out[idx, k] = np.interp(t + lag_s, t, column)
    out[:, 2] = wrap_angle(out[:, 2])
    return out


def dot_blob_hits(dots: np.ndarray) -> np.ndarray:
    """int16 (N, 4) hits (row, col, 0, 0) at the rounded centroid of each connected dot blob.

    Deliberately not `preprocess.seed_dots.image_to_hits`, which splits touching dots into guessed
    centres: on the first 1500 frames of 20250622 that raised the tracking mean error from 3.1 cm to
    58 cm (guessed centres a pixel off on far rows move hits by decimetres). A merged blob's centroid
    lies on the same edge, which is all the fit needs.
    """

    n, _, _, centroids = cv2.connectedComponentsWithStats((dots > 0).astype(np.uint8))
    rc = np.rint(centroids[1:, ::-1])
    out = np.zeros((len(rc), 4), np.int16)
    out[:, :2] = rc
    return out


def load_seed_frames(data_dir: Path, csv_path: Path | None = None, lag_s: float = 0.0147,
                     step: int = 1, indices: list[int] | None = None) -> SeedFrames:
    """Hits and (lag-corrected) truth of every step-th frame, or of the given frame indices."""

    ds = load_dataset(Path(data_dir), csv_path, kind="dots")
    chosen = np.arange(0, len(ds), step) if indices is None else np.asarray(indices, np.int64)
    hits, width, height = [], 0, 0
    for i in chosen:
        dots = ds.dot_image(int(i))
        height, width = dots.shape
        hits.append(dot_blob_hits(dots))
    poses = np.column_stack([ds.xy, ds.yaw])
    truth = lag_corrected(poses, ds.filenames, ds.recordings, lag_s)[chosen]
    return SeedFrames(filenames=[ds.filenames[i] for i in chosen], recordings=ds.recordings[chosen], hits=hits,
                      truth=truth, width=width, height=height)


def frame_time(filename: str) -> float | None:
    """Seconds of the file name's time stamp (None without one: the filter assumes its frame period)."""
    return _stamp(filename)
