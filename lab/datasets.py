"""Labelled localization datasets in the seed format, split by recording (numpy + OpenCV only, no torch).

Layout (the paper authors' seed recordings and our twin-generated sets alike)::

    DIR/images/*.jpg|png          one file per frame
    DIR/pose_data.csv             image_filename, x, y, orientation_z [, recording] [, yaw]

x, y are metres from the court centre; yaw = 2*asin(orientation_z) (a yaw-only quaternion with w >= 0).
A `yaw` column, when present, is used as is. The recording of a frame is the CSV column `recording`
when present, else the file-name prefix `img_YYYYMMDD_` (seed recordings) or `img_synth_s{seed}_`
(`courtloc dataset synth`: recording `synth_s{seed}`).

A `courtloc dataset synth` folder also holds `synth_meta.json`: it gives the court the frames show
(`Dataset.court`), the image kind (raw frames, or edge-dot images for `--kind edges`) and says the
frames are independent poses, not a drive (`Dataset.sequential` is False: nothing to track between them).

Images come in two kinds:
- "dots": already preprocessed edge-dot images (white discs where the radial scan hit a line edge).
  The seed's are JPEGs, so they carry compression noise (values 1..15 around each dot); they are
  thresholded at `DOT_THRESHOLD` into a 0/1 image, which is what the paper network sees.
- "raw": camera frames; they go through `courtloc.scan.preprocessor.Preprocessor` (default
  config unless one is passed) and the
  hits are drawn as discs (`courtloc.localizer.paper_input.hits_to_dot_image`), giving the same 0/1 image.

Consecutive frames are near-duplicates, so validation must be across recordings: `split_by_recording`
is the only splitter here, on purpose.
"""
from __future__ import annotations

import csv
import hashlib
import json
import logging
import math
import re
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Iterable, Literal, Sequence

import cv2
import numpy as np
from pydantic import BaseModel

from courtloc.localizer.paper_input import hits_to_dot_image
from courtloc.scan.config import PreprocessConfig
from courtloc.scan.preprocessor import Preprocessor
from courtloc.scan.seed_dots import image_to_hits

log = logging.getLogger(__name__)

DEFAULT_CSV = "pose_data.csv"
DOT_THRESHOLD = 128  # JPEG noise in the seed tops out near 15; dots are ~255.
_RECORDING_PREFIX = re.compile(r"^img_(\d{8})_")
_SYNTH_PREFIX = re.compile(r"^img_synth_s(\d+)_")
SYNTH_META = "synth_meta.json"  # written by courtloc.sim.synth (the lab reads it, never imports the twin)
_SYNTH_KINDS: dict[str, str] = {"raw": "raw", "edges": "dots"}
ImageKind = Literal["dots", "raw"]


class DatasetError(ValueError):
    """A dataset that cannot be read as asked (missing file, bad column, unknown recording)."""


@dataclass(frozen=True)
class LabelRow:
    filename: str
    x: float
    y: float
    yaw: float
    recording: str


def recording_of(filename: str) -> str:
    """The recording id from a seed-style file name `img_YYYYMMDD_...` (the date part), or `synth_s{seed}`
    from a `courtloc dataset synth` name `img_synth_s{seed}_...`."""
    name = Path(filename).name
    match = _RECORDING_PREFIX.match(name)
    if match:
        return match.group(1)
    synth = _SYNTH_PREFIX.match(name)
    if synth:
        return f"synth_s{synth.group(1)}"
    raise DatasetError(f"cannot tell the recording of {filename!r}: no img_YYYYMMDD_ or img_synth_s<seed>_ prefix "
                       "and no 'recording' column")


def read_synth_meta(root: Path) -> dict[str, Any] | None:
    """`synth_meta.json` of a `courtloc dataset synth` folder (None when absent)."""
    path = Path(root) / SYNTH_META
    if not path.is_file():
        return None
    try:
        meta = json.loads(path.read_text())
    except (OSError, json.JSONDecodeError) as exc:
        raise DatasetError(f"{path}: unreadable ({exc})") from None
    if not isinstance(meta, dict) or meta.get("kind") not in _SYNTH_KINDS:
        raise DatasetError(f"{path}: expected a JSON object with kind 'raw' or 'edges'")
    return meta


def read_labels(csv_path: Path) -> list[LabelRow]:
    """Parse a seed-format label CSV; rows keep the file's order."""
    csv_path = Path(csv_path)
    if not csv_path.is_file():
        raise DatasetError(f"label file not found: {csv_path}")
    rows: list[LabelRow] = []
    with csv_path.open(newline="") as handle:
        reader = csv.DictReader(handle)
        fields = set(reader.fieldnames or ())
        missing = {"image_filename", "x", "y"} - fields
        if missing or not ({"orientation_z", "yaw"} & fields):
            raise DatasetError(f"{csv_path}: needs columns image_filename, x, y and orientation_z (or yaw); "
                               f"has {sorted(fields)}")
        for line_no, rec in enumerate(reader, start=2):
            try:
                yaw = float(rec["yaw"]) if "yaw" in fields and rec["yaw"] not in ("", None) \
                    else 2.0 * math.asin(float(rec["orientation_z"]))
                rows.append(LabelRow(
                    filename=rec["image_filename"], x=float(rec["x"]), y=float(rec["y"]), yaw=yaw,
                    recording=rec["recording"] if rec.get("recording") else recording_of(rec["image_filename"]),
                ))
            except (TypeError, ValueError) as exc:
                raise DatasetError(f"{csv_path}:{line_no}: {exc}") from exc
    if not rows:
        raise DatasetError(f"{csv_path}: no labelled frames")
    return rows


def threshold_dots(gray: np.ndarray, threshold: int = DOT_THRESHOLD) -> np.ndarray:
    """0/1 uint8 dot image from a grey (or BGR) edge-dot image, removing JPEG noise."""
    if gray.ndim == 3:
        gray = cv2.cvtColor(gray, cv2.COLOR_BGR2GRAY)
    return (gray >= threshold).astype(np.uint8)


class Dataset:
    """Labelled frames of one directory. Images are read lazily; labels are arrays.

    `dot_image(i)` is the full-frame 0/1 edge-dot image for frame i, whatever the image kind.
    """

    def __init__(self, root: Path, csv_path: Path | None = None, kind: ImageKind | None = "dots",
                 images_subdir: str = "images", preprocessor: Any | None = None) -> None:
        """`kind` None: what a synth folder's meta says, else "dots"."""
        self.root = Path(root)
        self.images_dir = self.root / images_subdir
        if not self.images_dir.is_dir():
            raise DatasetError(f"image folder not found: {self.images_dir}")
        self.csv_path = Path(csv_path) if csv_path else self.root / DEFAULT_CSV
        self.synth_meta = read_synth_meta(self.root)
        if self.synth_meta is not None:
            synth_kind = _SYNTH_KINDS[self.synth_meta["kind"]]
            if kind is not None and kind != synth_kind:
                raise DatasetError(f"{self.root} is a 'dataset synth --kind {self.synth_meta['kind']}' folder: "
                                   f"its images are {synth_kind}, not {kind} (leave out --kind)")
            kind = synth_kind
        kind = kind or "dots"
        if kind not in ("dots", "raw"):
            raise DatasetError(f"kind must be 'dots' or 'raw', got {kind!r}")
        self.kind: ImageKind = kind
        # The court the frames show when the data says (synth); None: not recorded with the data.
        self.court: str | None = self.synth_meta.get("court") if self.synth_meta else None
        # Frames of one recording follow each other in time (a drive), or are independent poses (synth).
        self.sequential = self.synth_meta is None
        self.rows = read_labels(self.csv_path)
        self.filenames = [r.filename for r in self.rows]
        self.xy = np.array([(r.x, r.y) for r in self.rows], dtype=np.float64)
        self.yaw = np.array([r.yaw for r in self.rows], dtype=np.float64)
        self.recordings = np.array([r.recording for r in self.rows])
        self._preprocessor = preprocessor

    def __len__(self) -> int:
        return len(self.rows)

    def image_path(self, i: int) -> Path:
        return self.images_dir / self.filenames[i]

    def read_image(self, i: int) -> np.ndarray:
        """The stored image as OpenCV reads it (BGR)."""
        path = self.image_path(i)
        image = cv2.imread(str(path), cv2.IMREAD_COLOR)
        if image is None:
            raise DatasetError(f"cannot read image {path}")
        return image

    def dot_image(self, i: int) -> np.ndarray:
        """Full-frame 0/1 uint8 edge-dot image of frame i."""
        if self.kind == "dots":
            path = self.image_path(i)
            gray = cv2.imread(str(path), cv2.IMREAD_GRAYSCALE)
            if gray is None:
                raise DatasetError(f"cannot read image {path}")
            return threshold_dots(gray)

        frame = self.read_image(i)
        hits = self._preprocess(frame)
        return hits_to_dot_image(hits, frame.shape[0], frame.shape[1])

    def hits(self, i: int) -> tuple[np.ndarray, int, int]:
        """(hits N x 4 int16 (row, col, ray, d), frame height, frame width) of frame i.

        Raw frames: the preprocessor's hits. Dot images: each dot blob's centroid turned back into a
        hit by the preprocess stage's `image_to_hits` (touching dots are not split into guessed
        centres), so hit-based models can be evaluated on the seed data.
        """
        if self.kind == "raw":
            frame = self.read_image(i)
            return self._preprocess(frame), frame.shape[0], frame.shape[1]

        dots = self.dot_image(i)
        return image_to_hits(dots * np.uint8(255), split_touching=False), dots.shape[0], dots.shape[1]

    def _preprocess(self, frame: np.ndarray) -> np.ndarray:
        """Hits (N x 4 int16: row, col, ray, d) of a raw frame through the runtime preprocessor."""
        if self._preprocessor is None:
            self._preprocessor = Preprocessor(PreprocessConfig(frame_width=None, frame_height=None))
        return np.asarray(self._preprocessor.process(frame))

    def recording_ids(self) -> list[str]:
        """Distinct recordings in first-seen order."""
        return list(dict.fromkeys(self.recordings.tolist()))

    def indices_of(self, recordings: Iterable[str]) -> np.ndarray:
        wanted = list(recordings)
        unknown = set(wanted) - set(self.recording_ids())
        if unknown:
            raise DatasetError(f"unknown recording(s) {sorted(unknown)}; have {self.recording_ids()}")
        return np.flatnonzero(np.isin(self.recordings, wanted))

    def fingerprint(self, indices: Sequence[int] | np.ndarray | None = None) -> str:
        """sha256 over the chosen frames' file names, labels (repr of floats) and image-file bytes.

        Frames are taken in file-name order so the fingerprint does not depend on CSV row order.
        """
        chosen = range(len(self)) if indices is None else [int(i) for i in indices]
        digest = hashlib.sha256()
        for i in sorted(chosen, key=lambda k: self.filenames[k]):
            row = self.rows[i]
            digest.update(f"{row.filename}\t{row.x!r}\t{row.y!r}\t{row.yaw!r}\t{row.recording}\n".encode())
            digest.update(hashlib.sha256(self.image_path(i).read_bytes()).digest())
        return digest.hexdigest()


def load_dataset(root: Path, csv_path: Path | None = None, kind: ImageKind = "dots") -> Dataset:
    return Dataset(root, csv_path=csv_path, kind=kind)


def split_by_recording(recordings: Sequence[str] | np.ndarray, val: Iterable[str] | None = None,
                       train: Iterable[str] | None = None) -> tuple[np.ndarray, np.ndarray]:
    """(train_indices, val_indices) with every recording wholly on one side.

    `val` names the held-out recordings (default: the last recording in first-seen order); `train`
    defaults to all the others. A recording named on both sides, or unknown, is an error.
    """
    recs = np.asarray(recordings)
    present = list(dict.fromkeys(recs.tolist()))
    if len(present) < 2 and val is None:
        raise DatasetError(f"need at least two recordings to split, have {present}")
    val_set = set(val) if val is not None else {present[-1]}
    train_set = set(train) if train is not None else set(present) - val_set
    for name, chosen in (("val", val_set), ("train", train_set)):
        unknown = chosen - set(present)
        if unknown:
            raise DatasetError(f"{name} recording(s) {sorted(unknown)} not in the data; have {present}")
    overlap = val_set & train_set
    if overlap:
        raise DatasetError(f"recording(s) {sorted(overlap)} on both sides of the split")
    return np.flatnonzero(np.isin(recs, list(train_set))), np.flatnonzero(np.isin(recs, list(val_set)))


class DuplicateReport(BaseModel):
    n: int
    identical: int  # frames whose dot image equals the previous frame's (same recording)
    near_identical: int  # differ from the previous frame, but by less than the Jaccard threshold
    longest_identical_run: int
    jaccard_threshold: float
    per_recording: dict[str, dict[str, int]]


def _dot_hash(dots: np.ndarray) -> bytes:
    return hashlib.sha1(np.packbits(dots.astype(bool)).tobytes() + str(dots.shape).encode()).digest()


def duplicate_report(dataset: Dataset, jaccard_threshold: float = 0.1,
                     indices: Sequence[int] | None = None) -> DuplicateReport:
    """Count consecutive identical / near-identical frames, by file-name order within each recording.

    Identical: the thresholded dot images hash equal. Near-identical: the Jaccard distance between the
    two frames' dot-pixel sets is below `jaccard_threshold` (so the frames carry almost the same hits).
    """
    chosen = list(range(len(dataset))) if indices is None else [int(i) for i in indices]
    order = sorted(chosen, key=lambda i: (dataset.recordings[i], dataset.filenames[i]))
    identical = near = longest = run = 0
    per_rec: dict[str, dict[str, int]] = {}
    prev_rec, prev_hash, prev_dots = None, None, None
    for i in order:
        rec = str(dataset.recordings[i])
        stats = per_rec.setdefault(rec, {"n": 0, "identical": 0, "near_identical": 0})
        stats["n"] += 1
        dots = dataset.dot_image(i).astype(bool)
        digest = _dot_hash(dots)
        if rec == prev_rec and prev_dots is not None:
            if digest == prev_hash:
                identical += 1
                stats["identical"] += 1
                run += 1
                longest = max(longest, run)
            else:
                run = 0
                union = np.count_nonzero(dots | prev_dots)
                inter = np.count_nonzero(dots & prev_dots)
                if union and 1.0 - inter / union < jaccard_threshold:
                    near += 1
                    stats["near_identical"] += 1
        else:
            run = 0
        prev_rec, prev_hash, prev_dots = rec, digest, dots
    return DuplicateReport(n=len(order), identical=identical, near_identical=near,
                           longest_identical_run=longest, jaccard_threshold=jaccard_threshold,
                           per_recording=per_rec)
