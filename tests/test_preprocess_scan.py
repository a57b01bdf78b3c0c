"""The fast radial scan against the pseudo-code reference, and the scan rules checked by hand."""
from __future__ import annotations

import math
import shutil

import cv2
import numpy as np
import pytest

from courtloc.scan.config import HsvRange, PreprocessConfig, ScanConfig
from courtloc.scan.hsv_mask import WhiteMask, white_mask
from courtloc.scan.preprocessor import Preprocessor
from courtloc.scan.radial_scan import RadialScanner
from courtloc.scan.reference_scan import reference_preprocess, reference_scan
from courtloc.scan.synthetic import line_frame, noise_frame


@pytest.fixture(params=["native", "numpy"])
def native(request: pytest.FixtureRequest) -> bool:
    """Both scan implementations; the compiled one must be built wherever a C compiler is (see below)."""
    if request.param == "native" and not RadialScanner(ScanConfig()).native:
        pytest.skip("compiled radial scan not built")
    return request.param == "native"


def test_compiled_scan_is_built_where_a_compiler_is() -> None:
    if shutil.which("cc") is None and shutil.which("gcc") is None:
        pytest.skip("no C compiler on this machine: the numpy scan is the one in use")
    assert RadialScanner(ScanConfig()).native, "pip install -e . should have compiled scan/scan_kernel.c"


def any_size(config: PreprocessConfig) -> PreprocessConfig:
    return config.model_copy(update={"frame_width": None, "frame_height": None})


def assert_same_hits(fast: np.ndarray, reference: np.ndarray) -> None:
    assert fast.dtype == np.int16 and fast.shape[1:] == (4,)
    assert fast.shape == reference.shape, f"{len(fast)} fast hits vs {len(reference)} reference hits"
    np.testing.assert_array_equal(fast, reference)


@pytest.mark.parametrize("seed", range(6))
def test_fast_equals_reference_on_drawn_line_frames(seed: int, native: bool) -> None:
    config = PreprocessConfig()
    frame = line_frame(np.random.default_rng(seed))
    reference = reference_preprocess(frame, config)
    assert len(reference) > 20  # the frame really has lines to find
    assert_same_hits(Preprocessor(config, native=native).process(frame), reference)


@pytest.mark.parametrize("seed", range(3))
def test_fast_equals_reference_on_noise_frames(seed: int, native: bool) -> None:
    config = PreprocessConfig()
    frame = noise_frame(np.random.default_rng(100 + seed))
    reference = reference_preprocess(frame, config)
    assert len(reference) > 1000
    assert_same_hits(Preprocessor(config, native=native).process(frame), reference)


@pytest.mark.parametrize("height,width", [(1, 1), (2, 7), (37, 53), (241, 319), (480, 360), (123, 640), (500, 99)])
def test_fast_equals_reference_on_odd_frame_sizes(height: int, width: int, native: bool) -> None:
    config = any_size(PreprocessConfig(crop_top=0))
    rng = np.random.default_rng(height * 1000 + width)
    preprocessor = Preprocessor(config, native=native)
    for frame in (line_frame(rng, height, width), noise_frame(rng, height, width)):
        assert_same_hits(preprocessor.process(frame), reference_preprocess(frame, config))


@pytest.mark.parametrize("scan", [
    ScanConfig(rounding="half_up"),
    ScanConfig(origin=(320.0, 480.0)),  # the paper's written (W/2, H): its bottom row lies outside the frame
    ScanConfig(origin=(-0.6, 240.3), angle_start_deg=-90, angle_stop_deg=90, angle_step_deg=3.5),
    ScanConfig(origin=(320.0, 240.0), angle_start_deg=0, angle_stop_deg=358, angle_step_deg=1.0, max_d=150),
    ScanConfig(origin=(100.5, 479.5), rounding="half_up", angle_step_deg=0.7),
])
def test_fast_equals_reference_for_other_scan_settings(scan: ScanConfig, native: bool) -> None:
    config = PreprocessConfig(scan=scan)
    rng = np.random.default_rng(7)
    preprocessor = Preprocessor(config, native=native)
    for frame in (line_frame(rng), noise_frame(rng)):
        assert_same_hits(preprocessor.process(frame), reference_preprocess(frame, config))


def test_scan_of_a_mask_equals_reference_for_any_nonzero_values() -> None:
    rng = np.random.default_rng(3)
    mask = (rng.random((97, 131)) < 0.4).astype(np.uint8) * rng.integers(1, 256, (97, 131), dtype=np.uint8)
    scan = ScanConfig()
    assert_same_hits(RadialScanner(scan).scan_mask(mask), reference_scan(mask, scan))


def test_hits_follow_the_far_edge_of_a_horizontal_band() -> None:
    """Worked by hand: a white band on rows 100..109; every ray crossing it upwards leaves it on row 99."""
    height, width = 480, 640
    mask = np.zeros((height, width), np.uint8)
    mask[100:110] = 255
    scan = ScanConfig()
    hits = RadialScanner(scan).scan_mask(mask)
    assert len(hits) > 0
    assert set(hits[:, 0].tolist()) == {99}
    # Ray 45 is 90 degrees: straight up column 320 from row 479, so row 99 is d = 380.
    assert [320, 45, 380] in hits[:, 1:].tolist()
    # Rays that leave through the sides before reaching row 99 have no hit: a ray reaches row 99 inside
    # the frame only if it climbs 380 rows before moving 320 columns sideways.
    for ray, angle in enumerate(scan.angles_deg()):
        a = math.radians(angle)
        if math.sin(a) < 1e-9:
            reaches_row_99 = False  # 0 and 180 degrees run along the bottom row
        else:
            sideways = 380 * math.cos(a) / math.sin(a)  # columns moved while climbing 380 rows
            reaches_row_99 = abs(sideways) < 319
        assert (ray in hits[:, 2]) == reaches_row_99, f"ray {ray} at {angle} degrees"
    assert_same_hits(hits, reference_scan(mask, scan))


def test_no_hits_on_uniform_frames_and_edges_need_white_before_dark() -> None:
    scanner = RadialScanner(ScanConfig())
    assert len(scanner.scan_mask(np.zeros((48, 64), np.uint8))) == 0
    assert len(scanner.scan_mask(np.full((48, 64), 255, np.uint8))) == 0
    # Dark inside, white outside: walking outwards goes dark -> white, never white -> dark.
    mask = np.full((48, 64), 255, np.uint8)
    mask[30:, 20:44] = 0
    assert len(scanner.scan_mask(mask)) == 0


def _lit_floor_frame(height: int = 480, width: int = 640) -> np.ndarray:
    """A light grey floor (V 185) that a lamp lifts smoothly past the white threshold (V 200) in a patch,
    with one white line across the frame below the patch."""
    rows, cols = np.mgrid[0:height, 0:width]
    lamp = 30.0 * np.exp(-((rows - 150.0) ** 2 + (cols - 320.0) ** 2) / (2 * 90.0 ** 2))
    frame = np.repeat((185.0 + lamp)[..., None], 3, axis=2).astype(np.uint8)
    cv2.line(frame, (0, 330), (width - 1, 300), (250, 250, 250), 5)
    return frame


def test_a_floor_lifted_past_the_white_threshold_gives_no_hits_but_paint_on_it_does(native: bool) -> None:
    """The edge drop (ScanConfig.min_edge_drop): paint ends within a pixel or two, a lit floor fades out
    over tens. Without it every ray through the lit patch reports a hit where the light fades (the
    robocon2025 twin's randomised frames had hundreds, and a wrong pose fitted them)."""
    frame = _lit_floor_frame()
    paper = PreprocessConfig(scan=ScanConfig(min_edge_drop=0))
    ours = PreprocessConfig()
    assert ours.scan.min_edge_drop > 0
    on_line = lambda hits: (hits[:, 0] >= 295) & (hits[:, 0] <= 340)  # noqa: E731
    paper_hits = Preprocessor(paper, native=native).process(frame)
    hits = Preprocessor(ours, native=native).process(frame)
    assert np.count_nonzero(~on_line(paper_hits)) >= 10, "the patch really crosses the white threshold"
    assert np.count_nonzero(~on_line(hits)) == 0
    # Every ray that leaves the line upwards still reports it.
    assert set(paper_hits[on_line(paper_hits), 2].tolist()) == set(hits[on_line(hits), 2].tolist())
    assert_same_hits(hits, reference_preprocess(frame, ours))


def test_the_edge_drop_looks_only_as_far_as_edge_drop_samples(native: bool) -> None:
    """A white band whose far side ramps down to the floor over 8 pixels: a hit with a 3-pixel look-ahead
    sees a 3-step slice of the ramp, with a 10-pixel look-ahead the whole drop."""
    height, width = 120, 160
    frame = np.full((height, width, 3), 120, np.uint8)
    frame[40:60] = 250
    for k in range(8):  # rows 39..32 ramp from 205 down to 135, just above the floor
        frame[39 - k] = 205 - 10 * k
    short = PreprocessConfig(scan=ScanConfig(min_edge_drop=40, edge_drop_samples=3), frame_width=None,
                             frame_height=None)
    long = PreprocessConfig(scan=ScanConfig(min_edge_drop=40, edge_drop_samples=10), frame_width=None,
                            frame_height=None)
    assert len(Preprocessor(short, native=native).process(frame)) == 0
    assert len(Preprocessor(long, native=native).process(frame)) > 0
    for config in (short, long):
        assert_same_hits(Preprocessor(config, native=native).process(frame), reference_preprocess(frame, config))


def test_hits_are_ordered_by_ray_then_distance() -> None:
    hits = Preprocessor(PreprocessConfig()).process(noise_frame(np.random.default_rng(11)))
    order = np.lexsort((hits[:, 3], hits[:, 2]))
    np.testing.assert_array_equal(order, np.arange(len(hits)))
    assert (hits[:, 2] >= 0).all() and (hits[:, 2] < ScanConfig().n_rays).all()


def test_default_rays_are_91_from_bottom_centre_pixel() -> None:
    scan = ScanConfig()
    assert scan.n_rays == 91 and scan.angles_deg()[-1] == 180.0
    assert scan.origin_for(480, 640) == (320.0, 479.0)
    assert scan.max_d_for(480, 640) == 640


def test_ray_tables_are_built_once_per_frame_size() -> None:
    scanner = RadialScanner(ScanConfig(), max_cached_sizes=2)
    first = scanner.table(48, 64)
    assert scanner.table(48, 64) is first
    other = scanner.table(40, 50)
    assert other is not first and other.width == 50
    scanner.table(30, 30)  # evicts the least recently used size
    assert scanner.table(48, 64) is not first
    with pytest.raises(ValueError):  # shared by every frame of that size, so read-only
        first.sample_hit[0, 0] = 1


def test_mask_of_gathered_pixels_equals_full_frame_mask() -> None:
    rng = np.random.default_rng(5)
    frame = rng.integers(0, 256, (120, 160, 3), dtype=np.uint8)
    white = WhiteMask(PreprocessConfig().hsv_ranges)
    full = white.frame(frame)
    assert 0 < (full > 0).sum()
    np.testing.assert_array_equal(white.pixels(frame.reshape(-1, 3)), full.reshape(-1))


def bgr_of_hsv(h: int, s: int, v: int) -> tuple[int, int, int]:
    return tuple(cv2.cvtColor(np.array([[[h, s, v]]], np.uint8), cv2.COLOR_HSV2BGR)[0, 0].tolist())


@pytest.mark.parametrize("bgr,expected", [
    ((255, 255, 255), True),    # the twin's white line
    ((230, 235, 240), True),    # slightly tinted bright white
    ((170, 200, 215), True),    # white tape under a warm lamp: dimmer, a little saturated, warm hue
    ((110, 110, 110), False),   # grey floor
    ((190, 190, 190), False),   # light grey floor
    (bgr_of_hsv(107, 10, 183), False),  # the Robocon 2025 twin's blue-grey floor
    (bgr_of_hsv(14, 149, 178), False),  # the seed twin's wooden floor
    ((0, 0, 255), False),       # saturated red
    ((60, 180, 240), False),    # orange
])
def test_default_hsv_ranges(bgr: tuple[int, int, int], expected: bool) -> None:
    frame = np.full((2, 2, 3), bgr, np.uint8)
    assert bool(white_mask(frame, PreprocessConfig().hsv_ranges).all()) is expected


def test_default_ranges_are_not_redundant() -> None:
    """Each default box admits colours the other refuses, so the union matters."""
    first, second = PreprocessConfig().hsv_ranges
    only_first = np.full((1, 1, 3), bgr_of_hsv(100, 20, 230), np.uint8)   # cool bright white
    only_second = np.full((1, 1, 3), (170, 200, 215), np.uint8)           # warm dim white
    for frame, inside in ((only_first, (True, False)), (only_second, (False, True))):
        assert (bool(white_mask(frame, [first]).all()), bool(white_mask(frame, [second]).all())) == inside


def test_the_mask_is_the_union_of_the_ranges() -> None:
    ranges = (HsvRange(lower=(0, 0, 200), upper=(179, 40, 255)), HsvRange(lower=(100, 100, 100), upper=(130, 255, 255)))
    frame = np.array([[[255, 255, 255], [255, 0, 0], [0, 0, 255]]], np.uint8)  # white, blue, red
    hsv = cv2.cvtColor(frame, cv2.COLOR_BGR2HSV)
    assert hsv[0, 1, 0] in range(100, 131)
    assert white_mask(frame, ranges).tolist() == [[255, 255, 0]]


def test_bit_table_is_the_mask_of_every_colour() -> None:
    white = WhiteMask(PreprocessConfig().hsv_ranges)
    table = white.bit_table()
    assert table.nbytes == 1 << 21 and not table.flags.writeable
    assert white.bit_table() is table  # built once per instance
    rng = np.random.default_rng(9)
    colours = rng.integers(0, 256, (200_000, 3), dtype=np.uint8)
    colours[:50] = [[255, 255, 255], [0, 0, 0], [170, 200, 215], [110, 110, 110]] * 12 + [[0, 0, 0]] * 2
    key = (colours[:, 0].astype(np.int64) << 16) | (colours[:, 1].astype(np.int64) << 8) | colours[:, 2]
    from_table = (table[key >> 3] >> (key & 7)) & 1
    np.testing.assert_array_equal(from_table.astype(bool), white.pixels(colours) != 0)
    assert 0 < from_table.sum() < len(from_table)


def test_compiled_scan_refuses_a_table_that_points_outside_the_frame() -> None:
    scanner = RadialScanner(ScanConfig())
    if not scanner.native:
        pytest.skip("compiled radial scan not built")
    from courtloc.scan.native_scan import kernel_hit_samples, load_kernel

    table = scanner.table(48, 64)
    white = WhiteMask(PreprocessConfig().hsv_ranges)
    frame = np.full((48, 64, 3), 255, np.uint8)
    bad_offsets = table.pixel_offsets.copy()
    bad_offsets[-1] = 48 * 64 * 3  # one past the last byte
    with pytest.raises(ValueError, match="outside the frame"):
        kernel_hit_samples(load_kernel(), frame, bad_offsets, table.sample_pixel32, table.has_predecessor,
                           white.bit_table())
    with pytest.raises(ValueError, match="white table"):
        kernel_hit_samples(load_kernel(), frame, table.pixel_offsets, table.sample_pixel32, table.has_predecessor,
                           np.zeros(10, np.uint8))
