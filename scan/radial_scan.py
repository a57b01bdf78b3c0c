"""The fast radial scan: Algorithm 1 as a table lookup, identical hit for hit to `reference_scan`.

Everything that depends only on the frame size is computed once per size (`RayTable`): which pixel each
ray visits at each d, with the reference's own float64 arithmetic and rounding. A frame then costs one
gather of the ~36k distinct pixels the rays visit (640x480), in raster order, the white mask of those
pixels only, one gather of the mask values into ray order, and one comparison of neighbours.
Raster order matters: a new frame is not in the CPU cache, and reading it front to back lets the
hardware prefetch; gathering straight in ray order was 2-3x slower on cold frames (measured).

Two exact simplifications of the reference walk, both decided at table time:
- Samples outside the image are dropped, so each ray's remaining samples are its in-image samples in
  order of d; neighbours in the table are then "previous in-image sample" and "this sample".
- A sample rounding to the same pixel as the sample before it is dropped: its value equals its
  predecessor's, so it can neither be a hit nor change the next comparison, and a hit is always reported
  at the first sample of a new pixel, which is kept.
All rays' samples are laid end to end in one array; `pair_on_ray` masks the pairs that straddle two rays.

Two implementations of the per-frame work share the tables: the compiled kernel (`scan_kernel.c`: white
test by a lookup in `WhiteMask.bit_table`, then the neighbour comparison, in two C loops), used when it was
built, and the numpy path below (OpenCV's HSV conversion and `inRange` on the gathered pixels). Both equal
the reference; `RadialScanner(native=False)` forces numpy (the benchmark runs both).
"""
from __future__ import annotations

import math
from collections import OrderedDict
from dataclasses import dataclass

import cv2
import numpy as np

from courtloc.common.payloads import HIT_DTYPE
from courtloc.scan.config import ScanConfig
from courtloc.scan.hsv_mask import WhiteMask
from courtloc.scan.native_scan import kernel_hit_samples, load_kernel

HIT_COLUMNS = ("row", "col", "ray", "d")
# cv2.remap wants maps narrower than SHRT_MAX, so the gathered pixels are laid out in rows of this width.
_GATHER_ROW = 256


def empty_hits() -> np.ndarray:
    return np.zeros((0, 4), HIT_DTYPE)


@dataclass(frozen=True)
class RayTable:
    """The kept samples of every ray for one frame size, rays laid end to end (S samples in all).

    pixels: (P,) sorted flat indices (row * W + col) of the distinct pixels the rays visit.
    gather_x, gather_y: float32 maps for cv2.remap that copy those P pixels, padded to whole rows.
    sample_pixel: (S,) index into `pixels` of each sample.
    sample_flat: (S,) flat frame index of each sample (= pixels[sample_pixel]).
    pair_on_ray: (S-1,) True where samples i and i+1 belong to the same ray.
    sample_hit: (S, 4) int16 (row, col, ray, d) to report when that sample is a hit.
    ray_start: (n_rays + 1,) offset of each ray's first sample.
    For the compiled kernel: pixel_offsets (P,) int32 byte offsets of the pixels in a BGR frame,
    sample_pixel32 (S,) int32, has_predecessor (S,) uint8 (1: sample i-1 is on the same ray).
    """

    height: int
    width: int
    angles_deg: tuple[float, ...]
    pixels: np.ndarray
    gather_x: np.ndarray
    gather_y: np.ndarray
    sample_pixel: np.ndarray
    sample_flat: np.ndarray
    pair_on_ray: np.ndarray
    sample_hit: np.ndarray
    ray_start: np.ndarray
    pixel_offsets: np.ndarray
    sample_pixel32: np.ndarray
    has_predecessor: np.ndarray

    @property
    def n_rays(self) -> int:
        return len(self.angles_deg)


def ray_samples(height: int, width: int, scan: ScanConfig) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Rounded (row, col) of every (ray, d) before any filtering, and whether each lies in the image.

    The arithmetic mirrors `reference_scan` operation for operation (d * cos, then cx +; math.cos of
    math.radians) so the float64 results, and therefore the rounded pixels, are bit-identical.
    """
    cx, cy = scan.origin_for(height, width)
    d = np.arange(scan.max_d_for(height, width) + 1, dtype=np.float64)
    radians = [math.radians(a) for a in scan.angles_deg()]
    cos_a = np.array([math.cos(a) for a in radians], np.float64)[:, None]
    sin_a = np.array([math.sin(a) for a in radians], np.float64)[:, None]
    x = cx + d * cos_a
    y = cy - d * sin_a
    if scan.rounding == "trunc":
        cols, rows = np.trunc(x), np.trunc(y)
    else:
        cols, rows = np.floor(x + 0.5), np.floor(y + 0.5)
    inside = (rows >= 0) & (rows < height) & (cols >= 0) & (cols < width)
    return rows, cols, inside


def build_ray_table(height: int, width: int, scan: ScanConfig) -> RayTable:
    if height <= 0 or width <= 0:
        raise ValueError(f"frame size must be positive, got {height}x{width}")
    if max(height, width) >= np.iinfo(HIT_DTYPE).max:
        raise ValueError(f"frame size {height}x{width} does not fit the int16 hit format")
    rows, cols, inside = ray_samples(height, width, scan)
    flats, ds, rays = [], [], []
    for k in range(rows.shape[0]):
        d = np.flatnonzero(inside[k])
        flat = rows[k, d].astype(np.int64) * width + cols[k, d].astype(np.int64)
        new_pixel = np.ones(flat.shape, bool)
        new_pixel[1:] = flat[1:] != flat[:-1]
        flats.append(flat[new_pixel])
        ds.append(d[new_pixel])
        rays.append(np.full(int(new_pixel.sum()), k, np.int64))
    lengths = np.array([len(f) for f in flats], np.int64)
    ray_start = np.concatenate([[0], np.cumsum(lengths)])
    sample_flat = np.concatenate(flats) if flats else np.zeros(0, np.int64)
    sample_d = np.concatenate(ds) if ds else np.zeros(0, np.int64)
    sample_ray = np.concatenate(rays) if rays else np.zeros(0, np.int64)
    pair_on_ray = sample_ray[1:] == sample_ray[:-1]
    pixels, sample_pixel = np.unique(sample_flat, return_inverse=True)
    padded = np.full(-(-len(pixels) // _GATHER_ROW) * _GATHER_ROW, pixels[-1] if len(pixels) else 0, np.int64)
    padded[: len(pixels)] = pixels
    sample_hit = np.stack([sample_flat // width, sample_flat % width, sample_ray, sample_d], axis=-1)
    has_predecessor = np.zeros(len(sample_flat), np.uint8)
    has_predecessor[1:] = pair_on_ray
    table = RayTable(
        height=height,
        width=width,
        angles_deg=tuple(scan.angles_deg()),
        pixels=pixels.astype(np.intp),
        gather_x=(padded % width).astype(np.float32).reshape(-1, _GATHER_ROW),
        gather_y=(padded // width).astype(np.float32).reshape(-1, _GATHER_ROW),
        sample_pixel=sample_pixel.reshape(-1).astype(np.intp),
        sample_flat=sample_flat.astype(np.intp),
        pair_on_ray=pair_on_ray,
        sample_hit=sample_hit.astype(HIT_DTYPE).reshape(-1, 4),
        ray_start=ray_start,
        # int32 offsets bound the frame to 2^31 bytes; larger frames use the numpy path (see scan_bgr).
        pixel_offsets=(pixels * 3).astype(np.int32) if height * width * 3 < 2**31 else np.zeros(0, np.int32),
        sample_pixel32=sample_pixel.reshape(-1).astype(np.int32),
        has_predecessor=has_predecessor,
    )
    for value in vars(table).values():  # shared by every frame of this size: nobody may write to it
        if isinstance(value, np.ndarray):
            value.flags.writeable = False
    return table


def edge_drops(brightness: np.ndarray, hit: np.ndarray, table: RayTable, span: int) -> np.ndarray:
    """For each hit sample: the brightness of the sample before it less the darkest of it and the span - 1
    samples after it on the same ray (what `ScanConfig.min_edge_drop` is compared with)."""
    bright = brightness.astype(np.int16)
    lowest = bright[hit]
    on_ray = np.ones(hit.shape[0], bool)
    last = bright.shape[0] - 1
    for k in range(1, span):
        nxt = np.minimum(hit + k, last)
        on_ray &= (hit + k <= last) & table.pair_on_ray[nxt - 1]
        lowest = np.where(on_ray, np.minimum(lowest, bright[nxt]), lowest)
    return bright[hit - 1] - lowest


def hits_of_values(values: np.ndarray, table: RayTable, brightness: np.ndarray | None = None,
                   min_edge_drop: int = 0, edge_drop_samples: int = 1) -> np.ndarray:
    """Hits from the (S,) mask values of the table's samples, two-valued: 0/255 or bool; with `brightness`
    (S,) and `min_edge_drop` > 0, only where the brightness also drops that much (ScanConfig)."""
    if values.shape[0] < 2:
        return empty_hits()
    # A hit: previous sample white, this one not. With two-valued samples that is previous > current;
    # samples are in ray-then-d order, so the hits come out ordered by ray, then by d.
    # Pairs straddling two rays are dropped after the search: there are few candidates, many pairs.
    pair = np.flatnonzero(values[:-1] > values[1:])
    pair = pair[table.pair_on_ray[pair]]
    if brightness is not None and min_edge_drop > 0:
        pair = pair[edge_drops(brightness, pair + 1, table, edge_drop_samples) >= min_edge_drop]
    return table.sample_hit[pair + 1]


class RadialScanner:
    """Algorithm 1 for one scan configuration; ray tables are built once per frame size and kept."""

    def __init__(self, scan: ScanConfig, max_cached_sizes: int = 4, native: bool | None = None) -> None:
        """native: None uses the compiled kernel when it was built, False always numpy, True requires it."""
        self.scan = scan
        self._max_cached = max_cached_sizes
        self._kernel = None if native is False else load_kernel()
        if native and self._kernel is None:
            raise RuntimeError("the compiled radial scan is not built (pip install -e . with a C compiler)")
        self._tables: OrderedDict[tuple[int, int], RayTable] = OrderedDict()

    def table(self, height: int, width: int) -> RayTable:
        key = (height, width)
        table = self._tables.get(key)
        if table is None:
            table = build_ray_table(height, width, self.scan)
            self._tables[key] = table
            if len(self._tables) > self._max_cached:
                self._tables.popitem(last=False)
        else:
            self._tables.move_to_end(key)
        return table

    def scan_mask(self, mask: np.ndarray) -> np.ndarray:
        """Hits of a full-frame (H, W) mask (non-zero = white)."""
        table = self.table(*mask.shape)
        values = np.ascontiguousarray(mask).reshape(-1)[table.sample_flat] != 0
        return hits_of_values(values, table)

    @property
    def native(self) -> bool:
        return self._kernel is not None

    def scan_bgr(self, bgr: np.ndarray, white: WhiteMask) -> np.ndarray:
        """Hits of a (H, W, 3) uint8 BGR frame, masking only the pixels the rays visit."""
        table = self.table(bgr.shape[0], bgr.shape[1])
        if table.sample_pixel.shape[0] < 2:
            return empty_hits()
        if self._kernel is not None and table.pixel_offsets.shape[0] == table.pixels.shape[0]:
            hit_samples = kernel_hit_samples(self._kernel, np.ascontiguousarray(bgr), table.pixel_offsets,
                                             table.sample_pixel32, table.has_predecessor, white.bit_table(),
                                             self.scan.min_edge_drop, self.scan.edge_drop_samples)
            return table.sample_hit[hit_samples]
        # cv2.remap with nearest-neighbour and integral maps is an exact, fast gather of pixels.
        pixels = cv2.remap(np.ascontiguousarray(bgr), table.gather_x, table.gather_y, cv2.INTER_NEAREST)
        values = white.frame(pixels).reshape(-1)[table.sample_pixel]
        brightness = pixels.max(axis=2).reshape(-1)[table.sample_pixel] if self.scan.min_edge_drop else None
        return hits_of_values(values, table, brightness, self.scan.min_edge_drop, self.scan.edge_drop_samples)
