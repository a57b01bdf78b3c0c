"""The camera thumbnail with the edge hits drawn on it, made on the monitor's own thread.

Preferred source: the preprocess stage's preview (hits already drawn); while one arrives, the raw
frame subscription is dropped. Without one, the newest edge message is paired with the frame of the
same sequence number; a frame without edges is shown bare.
Work is rate-limited and only done when something new arrived.
"""
from __future__ import annotations

import logging
import threading
import time
from dataclasses import dataclass

import cv2
import numpy as np

from courtloc.common import codec
from courtloc.common.messages import Edges, Frame
from courtloc.common.payloads import HIT_DTYPE, FrameError, edges_hits, frame_pixels
from courtloc.monitor.watcher import MonitorWatcher

log = logging.getLogger("courtloc.monitor")
PREVIEW_FRESH_S = 3.0  # a preview older than this is ignored in favour of frame + edges


@dataclass(frozen=True)
class Thumbnail:
    jpeg: bytes
    seq: int
    source: str  # "preview" | "frame+edges" | "frame"
    n_hits: int
    made_at: float  # monotonic
    ident: int  # increases with every new thumbnail: the page reloads the image when it changes


def frame_image(frame: Frame) -> np.ndarray | None:
    """BGR pixels of a frame message, or None when its bytes do not make one."""
    try:
        return frame_pixels(frame)
    except FrameError:
        return None


def edge_hits(edges: Edges) -> np.ndarray:
    """(N, 4) int16 rows of (row, col, ray, d); empty when the payload disagrees with n_hits."""
    try:
        return edges_hits(edges)
    except ValueError:
        return np.zeros((0, 4), HIT_DTYPE)


def render(image: np.ndarray, hits: np.ndarray | None, width: int, quality: int = 80) -> bytes:
    scale = width / image.shape[1]
    small = cv2.resize(image, (width, max(1, round(image.shape[0] * scale))), interpolation=cv2.INTER_AREA)
    if hits is not None and len(hits):
        small = np.ascontiguousarray(small)
        for row, col in zip(hits[:, 0] * scale, hits[:, 1] * scale):
            cv2.circle(small, (int(col), int(row)), 2, (0, 0, 255), -1, lineType=cv2.LINE_AA)
    ok, buf = cv2.imencode(".jpg", small, [cv2.IMWRITE_JPEG_QUALITY, quality])
    if not ok:
        raise ValueError("JPEG encoding failed")
    return buf.tobytes()


class Thumbnailer:
    def __init__(self, watcher: MonitorWatcher, width: int = 320, max_rate_hz: float = 5.0) -> None:
        self.watcher = watcher
        self.width = width
        self.period_s = 1.0 / max_rate_hz
        self.latest: Thumbnail | None = None
        self.errors = 0
        self._seen: tuple[int, int, int] = (-1, -1, -1)
        self._ident = 0

    def start(self, stop: threading.Event) -> threading.Thread:
        thread = threading.Thread(target=self._run, args=(stop,), name="monitor-thumbnail", daemon=True)
        thread.start()
        return thread

    def _run(self, stop: threading.Event) -> None:
        while not stop.wait(self.period_s):
            try:
                self.update()
            except Exception:  # a bad image must not end the thumbnails
                self.errors += 1
                log.exception("thumbnail failed")

    def update(self) -> Thumbnail | None:
        self.watcher.want_frames(not self._preview_fresh())
        rings = self.watcher.rings
        seen = tuple(rings[p].received for p in ("camera/frame", "preprocess/edges", "preprocess/preview"))
        if seen == self._seen:
            return None
        self._seen = seen  # type: ignore[assignment]
        made = self._from_preview() or self._from_frame_and_edges()
        if made is not None:
            self.latest = made
        return made

    def _next(self, jpeg: bytes, seq: int, source: str, n_hits: int) -> Thumbnail:
        self._ident += 1
        return Thumbnail(jpeg, seq, source, n_hits, time.monotonic(), self._ident)

    def _preview_fresh(self) -> bool:
        newest = self.watcher.rings["preprocess/preview"].newest_first()
        return bool(newest) and time.monotonic() - newest[0][0] <= PREVIEW_FRESH_S

    def _from_preview(self) -> Thumbnail | None:
        newest = self.watcher.rings["preprocess/preview"].newest_first()
        if not newest or time.monotonic() - newest[0][0] > PREVIEW_FRESH_S:
            return None
        try:
            preview = codec.decode(bytes(newest[0][1]), Frame)
        except codec.DecodeError:
            return None
        image = frame_image(preview)
        if image is None:
            return None
        return self._next(render(image, None, self.width), preview.header.seq, "preview", 0)

    def _from_frame_and_edges(self) -> Thumbnail | None:
        frames: dict[int, Frame] = {}  # newest first (insertion order)
        for _, payload in self.watcher.rings["camera/frame"].newest_first():
            try:
                frame = codec.decode(bytes(payload), Frame)
            except codec.DecodeError:
                continue
            frames.setdefault(frame.header.seq, frame)
        if not frames:
            return None
        for edges in self._edges_newest_first():
            frame = frames.get(edges.header.seq)
            image = frame_image(frame) if frame is not None else None
            if image is not None:
                hits = edge_hits(edges)
                return self._next(render(image, hits, self.width), edges.header.seq, "frame+edges", len(hits))
        for frame in frames.values():  # no edges for any kept frame (no preprocess running): bare frame
            image = frame_image(frame)
            if image is not None:
                return self._next(render(image, None, self.width), frame.header.seq, "frame", 0)
        return None

    def _edges_newest_first(self) -> list[Edges]:
        found = []
        for _, payload in self.watcher.rings["preprocess/edges"].newest_first():
            try:
                found.append(codec.decode(bytes(payload), Edges))
            except codec.DecodeError:
                continue
        return found
