"""The preprocess stage's functions: frame checks, decoding, the paper crop, the config, the wire format."""
from __future__ import annotations

import cv2
import numpy as np
import pytest
from pydantic import ValidationError

from courtloc.common.jpeg_header import jpeg_size
from courtloc.common.payloads import FrameError, decode_frame, hits_from_bytes, hits_to_bytes
from courtloc.scan.config import PreprocessConfig
from courtloc.scan.preprocessor import Preprocessor
from courtloc.scan.reference_scan import reference_preprocess
from courtloc.scan.synthetic import line_frame


@pytest.fixture(scope="module")
def frame() -> np.ndarray:
    return line_frame(np.random.default_rng(21))


@pytest.mark.parametrize("bad,reason", [
    (np.zeros((480, 640, 3), np.float32), "dtype"),
    (np.zeros((480, 640), np.uint8), "shape"),
    (np.zeros((480, 640, 4), np.uint8), "channels"),
    (np.zeros((479, 640, 3), np.uint8), "size"),
    (np.zeros((480, 641, 3), np.uint8), "size"),
    (np.zeros((0, 640, 3), np.uint8), "empty"),
    ([[1, 2, 3]], "type"),
])
def test_bad_frames_are_refused_with_the_reason_and_the_next_frame_still_works(bad, reason: str,  # noqa: ANN001
                                                                                 frame: np.ndarray) -> None:
    preprocessor = Preprocessor(PreprocessConfig())
    with pytest.raises(FrameError) as caught:
        preprocessor.process(bad)
    assert caught.value.reason == reason
    assert isinstance(caught.value, ValueError)
    np.testing.assert_array_equal(preprocessor.process(frame), reference_preprocess(frame, PreprocessConfig()))


def test_decode_frame_jpeg_and_bgr8(frame: np.ndarray) -> None:
    ok, jpeg = cv2.imencode(".jpg", frame)
    assert ok
    decoded = decode_frame("jpeg", jpeg.tobytes(), 640, 480)
    assert decoded.shape == (480, 640, 3) and decoded.dtype == np.uint8
    raw = decode_frame("bgr8", frame.tobytes(), 640, 480)
    np.testing.assert_array_equal(raw, frame)


@pytest.mark.parametrize("encoding,data,reason", [
    ("jpeg", b"", "empty"),
    ("jpeg", b"\xff\xd8 definitely not a jpeg", "not_jpeg"),
    ("bgr8", b"\x00" * 100, "size"),
    ("png24", b"\x00" * 10, "encoding"),
])
def test_decode_frame_refuses_bad_payloads(encoding: str, data: bytes, reason: str) -> None:
    with pytest.raises(FrameError) as caught:
        decode_frame(encoding, data, 640, 480)
    assert caught.value.reason == reason


def test_decode_frame_refuses_a_jpeg_of_another_size_than_declared() -> None:
    ok, jpeg = cv2.imencode(".jpg", np.zeros((240, 320, 3), np.uint8))
    with pytest.raises(FrameError, match="320x240") as caught:
        decode_frame("jpeg", jpeg.tobytes(), 640, 480)
    assert caught.value.reason == "size"


def _with_declared_size(jpeg: bytes, width: int, height: int) -> bytes:
    """`jpeg` with its frame header (SOF0) rewritten to declare another size: a decode bomb."""
    sof = jpeg.index(b"\xff\xc0")
    return jpeg[:sof + 5] + height.to_bytes(2, "big") + width.to_bytes(2, "big") + jpeg[sof + 9:]


def test_jpeg_size_is_read_from_the_header() -> None:
    ok, jpeg = cv2.imencode(".jpg", np.zeros((48, 64, 3), np.uint8))
    assert jpeg_size(jpeg.tobytes()) == (64, 48)
    assert jpeg_size(_with_declared_size(jpeg.tobytes(), 16000, 16000)) == (16000, 16000)


def test_decode_bomb_is_refused_from_its_header() -> None:
    """631 bytes declaring 16000x16000: refused by the declared size, never decoded."""
    ok, jpeg = cv2.imencode(".jpg", np.zeros((8, 8, 3), np.uint8))
    bomb = _with_declared_size(jpeg.tobytes(), 16000, 16000)
    with pytest.raises(FrameError, match="declares 16000x16000") as caught:
        decode_frame("jpeg", bomb, 640, 480)
    assert caught.value.reason == "size"


@pytest.mark.parametrize("ext", [".png", ".bmp"])
def test_encoding_jpeg_accepts_only_jpeg(frame: np.ndarray, ext: str) -> None:
    ok, other = cv2.imencode(ext, frame)
    assert ok and cv2.imdecode(other, cv2.IMREAD_COLOR) is not None  # OpenCV itself would decode it
    with pytest.raises(FrameError) as caught:
        decode_frame("jpeg", other.tobytes(), 640, 480)
    assert caught.value.reason == "not_jpeg"


def test_paper_image_is_the_cropped_dot_image(frame: np.ndarray) -> None:
    preprocessor = Preprocessor(PreprocessConfig())
    hits = preprocessor.process(frame)
    paper = preprocessor.paper_image(hits, 480, 640)
    assert paper.shape == (280, 640) and paper.dtype == np.float32
    assert set(np.unique(paper).tolist()) == {0.0, 1.0}
    dots = np.zeros((480, 640), np.uint8)
    for row, col in hits[:, :2].tolist():
        cv2.circle(dots, (col, row), 2, 255, thickness=-1)
    np.testing.assert_array_equal(paper, dots[200:] / np.float32(255))


def test_process_with_paper_gives_both(frame: np.ndarray) -> None:
    preprocessor = Preprocessor(PreprocessConfig())
    hits, paper = preprocessor.process_with_paper(frame)
    np.testing.assert_array_equal(hits, preprocessor.process(frame))
    np.testing.assert_array_equal(paper, preprocessor.paper_image(hits, 480, 640))


def test_paper_image_crop_edge() -> None:
    preprocessor = Preprocessor(PreprocessConfig())
    hits = np.array([[199, 10, 0, 0], [100, 50, 0, 0]], np.int16)
    paper = preprocessor.paper_image(hits, 480, 640)
    # Only the lower rows of the dot at row 199 survive the crop; the one at row 100 is gone.
    assert paper[0, 10] == 1.0 and paper[1, 10] == 1.0 and paper[2, 10] == 0.0
    assert paper.sum() == 4  # rows 200 and 201 of that dot: 3 + 1 pixels
    with pytest.raises(FrameError):
        preprocessor.paper_image(hits, 150, 640)


def test_debug_preview_marks_hits(frame: np.ndarray) -> None:
    preprocessor = Preprocessor(PreprocessConfig())
    hits = preprocessor.process(frame)
    preview = preprocessor.debug_preview(frame, hits)
    assert preview.shape == (480, 640, 3)
    row, col = hits[len(hits) // 2, :2]
    assert preview[row, col].tolist() == [0, 0, 255]
    jpeg = preprocessor.debug_preview_jpeg(frame, hits)
    assert cv2.imdecode(np.frombuffer(jpeg, np.uint8), cv2.IMREAD_COLOR).shape == (480, 640, 3)


def test_hits_wire_format_round_trip(frame: np.ndarray) -> None:
    hits = Preprocessor(PreprocessConfig()).process(frame)
    data = hits_to_bytes(hits)
    assert len(data) == 8 * len(hits)
    np.testing.assert_array_equal(hits_from_bytes(data), hits)
    with pytest.raises(ValueError):
        hits_from_bytes(data[:-1])


@pytest.mark.parametrize("fields,name", [
    ({"crop_topp": 10}, "crop_topp"),
    ({"hsv_ranges": [{"lower": [0, 0, 200], "upper": [180, 40, 255]}]}, "hsv_ranges"),
    ({"hsv_ranges": [{"lower": [0, 50, 200], "upper": [179, 40, 255]}]}, "hsv_ranges"),
    ({"scan": {"angle_step_deg": 0}}, "angle_step_deg"),
    ({"scan": {"rounding": "banker"}}, "rounding"),
    ({"crop_top": 480}, "crop_top"),
])
def test_bad_config_names_the_field(fields: dict, name: str) -> None:
    with pytest.raises(ValidationError, match=name):
        PreprocessConfig.model_validate(fields)


def test_config_from_mapping_keeps_values() -> None:
    config = PreprocessConfig.model_validate({
        "hsv_ranges": [{"lower": [0, 0, 220], "upper": [179, 30, 255]}],
        "scan": {"angle_step_deg": 1.0, "rounding": "half_up"},
        "crop_top": 100,
        "debug_preview": {"enabled": True, "max_rate_hz": 0.5},
    })
    assert config.scan.n_rays == 181 and config.hsv_ranges[0].lower == (0, 0, 220)
    assert config.debug_preview.enabled and config.crop_top == 100
