"""The C frame code in deploy/firmware/ against the Python implementation, byte for byte, both directions.

The C source is compiled with the system C compiler into a shared library and driven through ctypes; the
test skips when there is no compiler. It checks the checked-in test vectors (and that they are what the
Python code produces today), then random streams of frames, noise and corruption fed in random chunks:
the C decoder must deliver the same frames and the same counters as the Python one.
"""
from __future__ import annotations

import ctypes
import json
import random
import runpy
import shutil
import subprocess
from pathlib import Path
from typing import Any

import pytest

from courtloc.services.shooter_bridge.protocol import (
    Command,
    McuFrame,
    OdometrySample,
    OdomFlag,
    StreamDecoder,
    crc16_ccitt_false,
    decode,
    encode,
    encode_odometry,
    parse_odometry,
)

FIRMWARE = Path(__file__).resolve().parents[1] / "deploy" / "firmware"
STATS = ("frames", "crc_errors", "bad_length", "unknown_command", "discarded_bytes")


MAX_EXTRA = 25


class CFrame(ctypes.Structure):
    _fields_ = [("seq", ctypes.c_uint16), ("command", ctypes.c_uint8), ("rpm", ctypes.c_uint16),
                ("flags", ctypes.c_uint8), ("reason", ctypes.c_uint8), ("extra_len", ctypes.c_uint8),
                ("extra", ctypes.c_uint8 * MAX_EXTRA)]


ODOMETRY_FIELDS = ("seq", "t_us", "vx_mm_s", "vy_mm_s", "wz_mrad_s", "gz_urad_s", "flags")


class COdometry(ctypes.Structure):
    _fields_ = [("seq", ctypes.c_uint16), ("t_us", ctypes.c_uint32), ("vx_mm_s", ctypes.c_int16),
                ("vy_mm_s", ctypes.c_int16), ("wz_mrad_s", ctypes.c_int16), ("gz_urad_s", ctypes.c_int32),
                ("flags", ctypes.c_uint8)]


class CStats(ctypes.Structure):
    _fields_ = [(name, ctypes.c_uint32) for name in STATS]


class CDecoder(ctypes.Structure):
    _fields_ = [("buf", ctypes.c_uint8 * 37), ("len", ctypes.c_uint8), ("stats", CStats)]


FRAME_CB = ctypes.CFUNCTYPE(None, ctypes.POINTER(CFrame), ctypes.c_void_p)


def c_compiler() -> str:
    compiler = shutil.which("cc") or shutil.which("gcc") or shutil.which("clang")
    if compiler is None:
        pytest.skip("no C compiler on this machine")
    return compiler


@pytest.fixture(scope="module")
def lib(tmp_path_factory: pytest.TempPathFactory) -> ctypes.CDLL:
    compiler = c_compiler()
    out = tmp_path_factory.mktemp("firmware") / "libcourtloc_mcu.so"
    # -Werror -pedantic: the file must build warning-free on a strict C99 toolchain, as on an MCU
    subprocess.run([compiler, "-std=c99", "-Wall", "-Wextra", "-Wconversion", "-pedantic", "-Werror", "-O2",
                    "-shared", "-fPIC", str(FIRMWARE / "courtloc_mcu.c"), "-o", str(out)],
                   check=True, capture_output=True, text=True)
    library = ctypes.CDLL(str(out))
    library.clm_crc16.restype = ctypes.c_uint16
    library.clm_crc16.argtypes = [ctypes.c_char_p, ctypes.c_size_t, ctypes.c_uint16]
    library.clm_encode.restype = ctypes.c_size_t
    library.clm_encode.argtypes = [ctypes.POINTER(CFrame), ctypes.c_char_p]
    library.clm_decoder_init.argtypes = [ctypes.POINTER(CDecoder)]
    library.clm_decoder_feed.restype = ctypes.c_size_t
    library.clm_decoder_feed.argtypes = [ctypes.POINTER(CDecoder), ctypes.c_char_p, ctypes.c_size_t, FRAME_CB,
                                         ctypes.c_void_p]
    library.clm_decoder_buffered.restype = ctypes.c_size_t
    library.clm_decoder_buffered.argtypes = [ctypes.POINTER(CDecoder)]
    library.clm_encode_odometry.restype = ctypes.c_size_t
    library.clm_encode_odometry.argtypes = [ctypes.POINTER(COdometry), ctypes.c_char_p]
    library.clm_parse_odometry.restype = ctypes.c_int
    library.clm_parse_odometry.argtypes = [ctypes.POINTER(CFrame), ctypes.POINTER(COdometry)]
    return library


def c_frame(frame: McuFrame) -> CFrame:
    extra = bytes(frame.extra)
    return CFrame(frame.seq, int(frame.command), frame.rpm, frame.flags, frame.reason, len(extra),
                  (ctypes.c_uint8 * MAX_EXTRA)(*extra))


def c_encode(lib: ctypes.CDLL, frame: McuFrame) -> bytes:
    out = ctypes.create_string_buffer(37)
    size = lib.clm_encode(ctypes.byref(c_frame(frame)), out)
    return out.raw[:size]


class CStream:
    """The C decoder fed chunk by chunk, collecting frames as plain dicts."""

    def __init__(self, lib: ctypes.CDLL) -> None:
        self.lib = lib
        self.decoder = CDecoder()
        lib.clm_decoder_init(ctypes.byref(self.decoder))
        self.frames: list[dict[str, int]] = []
        self._cb = FRAME_CB(self._on_frame)  # held: the C side calls it during feed

    def _on_frame(self, frame: Any, _ctx: Any) -> None:
        f = frame.contents
        self.frames.append({"seq": f.seq, "command": f.command, "rpm": f.rpm, "flags": f.flags,
                            "reason": f.reason, "extra": bytes(f.extra[:f.extra_len]).hex()})

    def feed(self, data: bytes) -> int:
        return self.lib.clm_decoder_feed(ctypes.byref(self.decoder), data, len(data), self._cb, None)

    def stats(self) -> dict[str, int]:
        return {name: getattr(self.decoder.stats, name) for name in STATS}

    @property
    def buffered(self) -> int:
        return self.lib.clm_decoder_buffered(ctypes.byref(self.decoder))


def as_dict(frame: McuFrame) -> dict[str, int | str]:
    return {"seq": frame.seq, "command": int(frame.command), "rpm": frame.rpm, "flags": frame.flags,
            "reason": frame.reason, "extra": bytes(frame.extra).hex()}


def frame_of(fields: dict[str, Any]) -> McuFrame:
    return McuFrame(**{**fields, "command": Command(fields["command"]), "extra": bytes.fromhex(fields["extra"])})


def vectors() -> dict[str, Any]:
    return json.loads((FIRMWARE / "test_vectors.json").read_text())


def test_vectors_are_what_the_python_implementation_produces() -> None:
    generator = runpy.run_path(str(FIRMWARE / "make_vectors.py"))
    assert (FIRMWARE / "test_vectors.json").read_text() == generator["render"](), \
        "protocol.py changed: regenerate with python deploy/firmware/make_vectors.py"
    assert (FIRMWARE / "test_vectors.h").read_text() == generator["render_header"](), \
        "protocol.py changed: regenerate with python deploy/firmware/make_vectors.py"
    data = vectors()
    for case in data["encode"]:
        assert decode(bytes.fromhex(case["hex"])) == frame_of(case["frame"])
    assert len(data["decode"]) >= 8 and any(c["stats"]["crc_errors"] for c in data["decode"])
    assert any(f["command"] == Command.ODOMETRY for c in data["decode"] for f in c["frames"])


def test_crc_matches(lib: ctypes.CDLL) -> None:
    for case in vectors()["crc"]:
        data = case["ascii"].encode()
        assert lib.clm_crc16(data, len(data), 0xFFFF) == case["crc"] == crc16_ccitt_false(data)
    rng = random.Random(3)
    for n in range(0, 64):
        data = bytes(rng.randrange(256) for _ in range(n))
        assert lib.clm_crc16(data, n, 0xFFFF) == crc16_ccitt_false(data)
        # incremental use, as a UART handler would
        assert lib.clm_crc16(data[n // 2:], n - n // 2, lib.clm_crc16(data, n // 2, 0xFFFF)) == crc16_ccitt_false(data)


def test_encode_vectors(lib: ctypes.CDLL) -> None:
    for case in vectors()["encode"]:
        frame = frame_of(case["frame"])
        assert c_encode(lib, frame).hex() == case["hex"] == encode(frame).hex()


def odometry_sample(fixed: dict[str, int]) -> OdometrySample:
    return OdometrySample(seq=fixed["seq"], mcu_time_us=fixed["t_us"], vx_m_s=fixed["vx_mm_s"] / 1e3,
                          vy_m_s=fixed["vy_mm_s"] / 1e3, wz_wheels_rad_s=fixed["wz_mrad_s"] / 1e3,
                          wz_gyro_rad_s=fixed["gz_urad_s"] / 1e6, flags=OdomFlag(fixed["flags"]))


def test_odometry_vectors_both_ways(lib: ctypes.CDLL) -> None:
    cases = vectors()["odometry"]
    assert len(cases) >= 3
    for case in cases:
        fixed = case["fixed"]
        out = ctypes.create_string_buffer(26)
        size = lib.clm_encode_odometry(ctypes.byref(COdometry(*(fixed[k] for k in ODOMETRY_FIELDS))), out)
        assert out.raw[:size].hex() == case["hex"] == encode_odometry(odometry_sample(fixed)).hex()
        # what the MCU sends, the bridge parses to the same SI values
        assert parse_odometry(decode(out.raw[:size])) == odometry_sample(fixed)
        # and the C parser reads the bridge-side encoding back to the same fixed-point fields
        stream = CStream(lib)
        stream.feed(bytes.fromhex(case["hex"]))
        frame = frame_of(stream.frames[0])
        parsed = COdometry()
        assert lib.clm_parse_odometry(ctypes.byref(c_frame(frame)), ctypes.byref(parsed)) == 1
        assert {k: getattr(parsed, k) for k in ODOMETRY_FIELDS} == fixed
    status = c_frame(McuFrame(seq=1, command=Command.STATUS))
    assert lib.clm_parse_odometry(ctypes.byref(status), ctypes.byref(COdometry())) == 0


@pytest.mark.parametrize("chunk", [1, 5, 1000])
def test_decode_vectors(lib: ctypes.CDLL, chunk: int) -> None:
    for case in vectors()["decode"]:
        stream = bytes.fromhex(case["hex"])
        c = CStream(lib)
        for start in range(0, len(stream), chunk):
            c.feed(stream[start:start + chunk])
        assert (c.frames, c.stats(), c.buffered) == (case["frames"], case["stats"], case["buffered"]), case["name"]


def random_frame(rng: random.Random) -> McuFrame:
    command = rng.choice(list(Command))
    extra = bytes(rng.randrange(256) for _ in range(14 if command == Command.ODOMETRY else rng.choice([0, 0, 3])))
    return McuFrame(seq=rng.randrange(1 << 16), command=command, rpm=rng.randrange(1 << 16),
                    flags=rng.randrange(256), reason=rng.randrange(256), extra=extra)


def test_both_directions_on_random_frames(lib: ctypes.CDLL) -> None:
    rng = random.Random(11)
    frames = [random_frame(rng) for _ in range(300)]
    c_bytes = b"".join(c_encode(lib, f) for f in frames)
    assert c_bytes == b"".join(encode(f) for f in frames)  # MCU encoder == bridge encoder
    assert StreamDecoder().feed(c_bytes) == frames  # what the MCU sends, the bridge reads
    c = CStream(lib)
    assert c.feed(c_bytes) == len(frames)
    assert c.frames == [as_dict(f) for f in frames]  # what the bridge sends, the MCU reads


def corrupted_stream(rng: random.Random, n_frames: int) -> bytes:
    stream = bytearray()
    for _ in range(n_frames):
        data = bytearray(encode(random_frame(rng)))
        roll = rng.random()
        if roll < 0.15:
            data[rng.randrange(len(data))] ^= 1 << rng.randrange(8)  # bit error
        elif roll < 0.25:
            del data[rng.randrange(len(data)):]  # cut short
        elif roll < 0.30:
            data[2] = rng.choice([0, 6, 33, 255, 32])  # a LEN that lies
        elif roll < 0.35:
            data[5] = 0x7E  # an unknown command with a bad CRC
        stream += data
        if rng.random() < 0.3:
            stream += bytes(rng.choice([0xA5, 0x5A, rng.randrange(256)]) for _ in range(rng.randrange(1, 40)))
    return bytes(stream)


def test_corrupted_streams_decode_identically(lib: ctypes.CDLL) -> None:
    rng = random.Random(2026)
    for _ in range(40):
        stream = corrupted_stream(rng, 60)
        python = StreamDecoder()
        c = CStream(lib)
        position = 0
        py_frames: list[McuFrame] = []
        while position < len(stream):
            size = rng.choice([1, 2, 3, 7, 12, 13, 50, 400])
            chunk = stream[position:position + size]
            position += size
            py_frames += python.feed(chunk)
            c.feed(chunk)
        assert c.frames == [as_dict(f) for f in py_frames]
        assert c.stats() == {name: getattr(python.stats, name) for name in STATS}
        assert c.buffered == python.buffered
    assert python.stats.crc_errors and python.stats.bad_length and python.stats.discarded_bytes


def test_the_c_selftest_passes_on_the_generated_header(tmp_path: Path) -> None:
    """selftest.c + test_vectors.h: what a firmware team runs on the host or at the MCU's boot."""
    exe = tmp_path / "selftest"
    subprocess.run([c_compiler(), "-std=c99", "-Wall", "-Wextra", "-Wconversion", "-pedantic", "-Werror",
                    str(FIRMWARE / "selftest.c"), str(FIRMWARE / "courtloc_mcu.c"), "-o", str(exe)],
                   check=True, capture_output=True, text=True)
    run = subprocess.run([str(exe)], capture_output=True, text=True, timeout=30)
    assert run.returncode == 0 and run.stdout.startswith("ok: 0 of "), run.stdout
    total = int(run.stdout.split(" of ")[1].split()[0])
    data = vectors()
    assert total == 1 + len(data["encode"]) + len(data["odometry"]) + 2 * len(data["decode"])
