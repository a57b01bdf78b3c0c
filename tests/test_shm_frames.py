"""Frames in zenoh shared memory: same bytes as the codec, one copy out, bounded pool, bytes to other hosts."""
from __future__ import annotations

import threading
from pathlib import Path

import numpy as np
import pytest
import zenoh
from buskit import (
    BusClient,
    endpoint,
    folder_camera_toml,
    free_port,
    start_router,
    start_stage,
    write_config,
    write_line_frames,
)

from courtloc.common import codec
from courtloc.common.bus import ZenohConfig, open_session
from courtloc.common.messages import Frame, Header
from courtloc.common.services_table import TOPICS
from courtloc.common.shm_frames import PixelStaging, decode_frame_payload, frame_prefix


def _meta(encoding: str = "bgr8") -> Frame:
    header = Header.now("robot1", 7, "camera")
    header.valid = True
    return Frame(header=header, width=64, height=48, encoding=encoding, data=b"")


@pytest.mark.parametrize("size", [0, 1, 255, 256, 65535, 65536, 921600])
def test_prefix_plus_data_is_the_codecs_encoding(size: int) -> None:
    data = bytes(range(256)) * (size // 256) + bytes(size % 256)
    meta = _meta()
    assert frame_prefix(meta, size) + data == codec.encode(meta.model_copy(update={"data": data}))


def test_decoding_gives_the_pixels_of_the_encoded_frame() -> None:
    image = np.random.default_rng(1).integers(0, 255, (48, 64, 3), np.uint8)
    meta = _meta()
    data = PixelStaging().fill(image)
    received = decode_frame_payload(frame_prefix(meta, len(data)) + bytes(data))
    assert received.header == meta.header and (received.message.width, received.message.height) == (64, 48)
    assert np.array_equal(np.frombuffer(received.pixels, np.uint8).reshape(48, 64, 3), image)
    assert not received.via_shm


def test_a_frame_encoded_in_another_field_order_still_decodes() -> None:
    meta = _meta()
    import msgpack

    body = {"data": b"\x01\x02\x03", **meta.model_dump(exclude={"data"})}  # data first: the codec's path
    received = decode_frame_payload(msgpack.packb(body, use_bin_type=True))
    assert bytes(received.pixels) == b"\x01\x02\x03" and received.header.seq == 7


@pytest.mark.parametrize("payload, reason", [
    (b"\x92\x01\x02", "not_a_map"),
    (codec.encode(_meta())[:40], "truncated"),
    (codec.encode(_meta().model_copy(update={"header": _meta().header.model_copy(update={"schema_version": 99})})),
     "schema_version"),
])
def test_malformed_frames_raise_the_codecs_reasons(payload: bytes, reason: str) -> None:
    with pytest.raises(codec.DecodeError) as info:
        decode_frame_payload(payload)
    assert info.value.reason == reason


def _camera(tmp_path: Path, port: int, extra: str = "") -> Path:
    folder = write_line_frames(tmp_path / "frames", n=3)  # 640x480: a real frame's size
    return write_config(tmp_path / "cam.toml", port, folder_camera_toml(folder, fps=30, extra=extra),
                        health_period_s=0.2)  # the tests wait for counts in health


@pytest.mark.integration
def test_local_preprocess_reads_shared_memory_while_a_no_shm_session_gets_bytes(tmp_path: Path) -> None:
    port = free_port()
    router = start_router(port)
    config = _camera(tmp_path, port)
    client = BusClient(port)
    client.subscribe("preprocess/health")
    client.subscribe("preprocess/edges")
    # A session that cannot share memory stands for a subscriber on another host.
    remote = open_session(ZenohConfig(connect=[endpoint(port)], shared_memory=False))
    remote_frames: list[tuple[bool, Frame]] = []
    got_remote = threading.Event()

    def on_remote(sample: zenoh.Sample) -> None:
        remote_frames.append((sample.payload.as_shm() is not None, codec.decode(bytes(sample.payload), Frame)))
        got_remote.set()

    remote_sub = remote.declare_subscriber(TOPICS["camera/frame"].key("robot1"), on_remote)
    camera, preprocess = start_stage("camera", config), start_stage("preprocess", config)
    try:
        edges = client.wait_for("preprocess/edges", lambda m: m.header.valid and m.n_hits > 0, timeout=30)
        assert [s.stage for s in edges.header.stamps] == ["camera", "preprocess"]
        health = client.wait_for("preprocess/health", lambda h: h.detail.get("frames_via_shm", 0) >= 5, timeout=30)
        assert health.detail["frames_via_bytes"] == 0 and health.rejected == 0
        # Both stages run beside their router without the security bundle: linked directly (the camera a peer).
        linked = client.wait_for("preprocess/health", lambda h: h.detail.get("zenoh_peers", 0) >= 1, timeout=30)
        assert linked.detail["links"] == "direct"
        assert got_remote.wait(20), "the no-shm session got no frame"
        via_shm, frame = remote_frames[-1]
        assert not via_shm, "a link without shared memory carries bytes"
        assert frame.encoding == "bgr8" and len(frame.data) == 640 * 480 * 3 and frame.header.valid
    finally:
        remote_sub.undeclare()
        remote.close()
        client.close()
        for proc in (preprocess, camera):
            assert proc.stop() == 0, proc.output()
        router.stop()


@pytest.mark.integration
def test_a_consumer_holding_frames_cannot_stall_the_camera(tmp_path: Path) -> None:
    """A 2 MB pool holds two frames: a subscriber keeping every frame alive exhausts it; the camera goes on
    in bytes (counted) and returns to shared memory once the frames are let go."""
    port = free_port()
    router = start_router(port)
    client = BusClient(port)
    client.subscribe("camera/health")
    kept: list[zenoh.ZBytes] = []
    holding = threading.Event()
    holding.set()
    lock = threading.Lock()

    def keep(sample: zenoh.Sample) -> None:
        if holding.is_set():
            with lock:
                kept.append(sample.payload)

    hoarder = client.session.declare_subscriber(TOPICS["camera/frame"].key("robot1"), keep)
    camera = start_stage("camera", _camera(tmp_path, port, extra="shm_pool_mb = 2"))
    try:
        exhausted = client.wait_for("camera/health", lambda h: h.detail.get("frames_as_bytes", 0) >= 5, timeout=30)
        later = client.wait_for("camera/health", lambda h: h.frames_out > exhausted.frames_out + 5, timeout=30)
        assert later.detail["frames_as_bytes"] > exhausted.detail["frames_as_bytes"], "still publishing, as bytes"
        assert "shared-memory pool" in later.last_error
        in_shm_while_held = later.detail["frames_in_shm"]
        holding.clear()
        with lock:
            kept.clear()  # the buffers go back to the camera's pool
        resumed = client.wait_for("camera/health", lambda h: h.detail["frames_in_shm"] > in_shm_while_held + 5,
                                  timeout=30)
        assert resumed.detail["frames_in_shm"] > in_shm_while_held
    finally:
        hoarder.undeclare()
        kept.clear()
        client.close()
        assert camera.stop() == 0, camera.output()
        router.stop()


def _video(path: Path, n: int = 5) -> Path:
    import cv2

    writer = cv2.VideoWriter(str(path), cv2.VideoWriter_fourcc(*"MJPG"), 10, (64, 48))
    for i in range(n):
        writer.write(np.full((48, 64, 3), 40 * i, np.uint8))
    writer.release()
    return path


def test_a_video_source_decodes_straight_into_the_staging_buffer(tmp_path: Path) -> None:
    from courtloc.services.camera.config import FileSourceConfig
    from courtloc.services.camera.sources import FileSource

    source = FileSource(FileSourceConfig(path=_video(tmp_path / "v.avi")))
    source.open()
    try:
        staging = PixelStaging()
        buffer = staging.fill(source.read().frame)
        second = source.read(staging.view)
        assert second.frame is staging.view, "decoded in place"
        assert staging.fill(second.frame) is buffer
        assert abs(int(np.frombuffer(buffer, np.uint8).mean()) - 40) <= 3, "the buffer holds the second frame"
    finally:
        source.close()


@pytest.mark.integration
def test_video_frames_published_from_the_staging_buffer_are_each_their_own(tmp_path: Path) -> None:
    port = free_port()
    router = start_router(port)
    video = _video(tmp_path / "v.avi")
    config = write_config(tmp_path / "cam.toml", port, f'[camera]\nsource = "file"\nfps = 30\n'
                                                       f'[camera.file]\npath = "{video}"\n')
    client = BusClient(port)
    client.subscribe("camera/frame")
    camera = start_stage("camera", config)
    try:
        first = client.wait_for("camera/frame")
        for message in client.messages("camera/frame"):
            if message.header.seq >= first.header.seq + 12:
                break
            level = int(np.frombuffer(message.data, np.uint8).mean())
            assert abs(level - 40 * (message.header.seq % 5)) <= 3, "each frame shows its own picture"
    finally:
        client.close()
        assert camera.stop() == 0, camera.output()
        router.stop()
