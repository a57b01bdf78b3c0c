"""Writes test_vectors.json from the Python implementation (services/shooter_bridge/protocol.py).

    python deploy/firmware/make_vectors.py [OUT.json]

`encode`: a frame's fields and its bytes. `decode`: a byte stream (noise, cut frames, bad CRCs, a frame
inside a corrupt one) and what a receiver must get out of it: the frames in order and the decoder's
counters. tests/test_firmware.py checks that this file is what the Python code produces today and that
the C code in this folder agrees with every entry.
"""
from __future__ import annotations

import json
import random
import sys
from dataclasses import asdict
from pathlib import Path
from typing import Any

from courtloc.services.shooter_bridge.protocol import (
    Command, HoldReason, McuFrame, OdometrySample, OdomFlag, StreamDecoder, crc16_ccitt_false, encode,
    encode_odometry)

HERE = Path(__file__).resolve().parent
DEFAULT_OUT = HERE / "test_vectors.json"


def frame_dict(frame: McuFrame) -> dict[str, int | str]:
    return {"seq": frame.seq, "command": int(frame.command), "rpm": frame.rpm, "flags": frame.flags,
            "reason": frame.reason, "extra": bytes(frame.extra).hex()}


# ODOMETRY in the MCU's fixed-point units (what the C struct holds): seq, t_us, vx mm/s, vy mm/s,
# wz mrad/s, gz urad/s, flags
ODOMETRY_CASES: list[tuple[int, int, int, int, int, int, int]] = [
    (1, 1_000_000, 1234, -250, 500, 512_000, int(OdomFlag.WHEELS_VALID | OdomFlag.GYRO_VALID)),
    (0xFFFF, 0xFFFFFFFF, -32768, 32767, -32768, -2_147_483_648, int(OdomFlag.FAULT)),
    (7, 0, 0, 0, 0, 2_147_483_647, int(OdomFlag.GYRO_VALID | OdomFlag.GYRO_SATURATED | OdomFlag.WHEEL_SLIP)),
]


def odometry_sample(case: tuple[int, int, int, int, int, int, int]) -> OdometrySample:
    seq, t_us, vx, vy, wz, gz, flags = case
    return OdometrySample(seq=seq, mcu_time_us=t_us, vx_m_s=vx / 1e3, vy_m_s=vy / 1e3, wz_wheels_rad_s=wz / 1e3,
                          wz_gyro_rad_s=gz / 1e6, flags=OdomFlag(flags))


def _encode_cases() -> list[McuFrame]:
    return [
        McuFrame(seq=0x1234, command=Command.SET_RPM, rpm=2500, flags=0x03),
        McuFrame(seq=0x0001, command=Command.HOLD, reason=int(HoldReason.STALE)),
        McuFrame(seq=0x0002, command=Command.HEARTBEAT),
        McuFrame(seq=0x0010, command=Command.STATUS, rpm=2480, flags=0x01),
        McuFrame(seq=0xFFFF, command=Command.SET_RPM, rpm=0xFFFF, flags=0xFF, reason=0xFF),
        McuFrame(seq=0, command=Command.HOLD, reason=int(HoldReason.STOPPED)),
        McuFrame(seq=0xA55A, command=Command.SET_RPM, rpm=0x5AA5, flags=0x0F),  # sync bytes inside the body
    ]


def _decode_streams() -> list[tuple[str, bytes]]:
    ok = [encode(f) for f in _encode_cases()]
    odometry = [encode_odometry(odometry_sample(c)) for c in ODOMETRY_CASES]
    bad_odometry = bytearray(odometry[0])
    bad_odometry[15] ^= 0x01  # inside VX
    bad_crc = bytearray(ok[0])
    bad_crc[7] ^= 0x10
    long_body = bytearray(b"\xa5\x5a\x0a" + ok[1][3:10] + b"\x01\x02\x03")  # LEN 10: extra body bytes ignored
    long_body += crc16_ccitt_false(bytes(long_body[2:])).to_bytes(2, "little")
    unknown = bytearray(b"\xa5\x5a\x07\x05\x00\x7f\x00\x00\x00\x00")
    unknown += crc16_ccitt_false(bytes(unknown[2:])).to_bytes(2, "little")
    # a corrupt frame claiming LEN 32 whose body holds a real frame: the receiver must find the inner one
    inner = bytearray(b"\xa5\x5a\x20") + ok[2] + bytes(range(20)) + b"\x00\x00"
    rng = random.Random(17)
    noisy = bytearray()
    for frame in ok:
        noisy += bytes(rng.randrange(256) for _ in range(rng.randrange(0, 12)))
        noisy += b"\xa5\x5a\xff" + b"\xa5\x5a\x07\x01" + frame
    return [
        ("all encode cases back to back", b"".join(ok)),
        ("starts mid-frame", ok[0][5:] + ok[1]),
        ("bit error in RPM, then a good frame", bytes(bad_crc) + ok[3]),
        ("LEN 10: extra body bytes ignored", bytes(long_body)),
        ("unknown command skipped", bytes(unknown) + ok[2]),
        ("impossible LENs", b"\xa5\x5a\x00\xa5\x5a\x06\xa5\x5a\x21" + ok[4]),
        ("real frame inside a corrupt one", bytes(inner)),
        ("noise, bad lengths and truncated frames between frames", bytes(noisy)),
        ("trailing SYNC0 kept for the next chunk", ok[5] + b"\x00\xa5"),
        ("ODOMETRY and STATUS interleaved", odometry[0] + ok[3] + odometry[1] + odometry[2]),
        ("corrupt ODOMETRY, then a good one", bytes(bad_odometry) + odometry[1]),
        ("ODOMETRY cut short, then STATUS", odometry[2][:17] + ok[3]),
    ]


def decode_expectation(stream: bytes) -> dict[str, Any]:
    decoder = StreamDecoder()
    frames = decoder.feed(stream)
    return {"frames": [frame_dict(f) for f in frames], "stats": asdict(decoder.stats), "buffered": decoder.buffered}


def build() -> dict[str, Any]:
    return {
        "protocol": "courtloc shooter bridge serial frame, version 1 (docs/shooter.md)",
        "generated_by": "deploy/firmware/make_vectors.py",
        "crc": [{"ascii": "123456789", "crc": 0x29B1}, {"ascii": "", "crc": 0xFFFF}],
        "encode": [{"frame": frame_dict(f), "hex": encode(f).hex()} for f in _encode_cases()],
        "odometry": [{"fixed": dict(zip(("seq", "t_us", "vx_mm_s", "vy_mm_s", "wz_mrad_s", "gz_urad_s", "flags"), c)),
                      "hex": encode_odometry(odometry_sample(c)).hex()} for c in ODOMETRY_CASES],
        "decode": [{"name": name, "hex": stream.hex(), **decode_expectation(stream)}
                   for name, stream in _decode_streams()],
    }


def render() -> str:
    return json.dumps(build(), indent=1) + "\n"


def _bytes(data: bytes) -> str:
    return "{" + ", ".join(f"0x{b:02x}" for b in data) + "}" if data else "{0}"


def render_header() -> str:
    """The same vectors as C arrays (test_vectors.h), for selftest.c on the host or on the MCU itself."""
    data = build()
    out = ["/* Generated by deploy/firmware/make_vectors.py from the Python implementation: do not edit. */",
           "#ifndef COURTLOC_MCU_TEST_VECTORS_H", "#define COURTLOC_MCU_TEST_VECTORS_H", "",
           '#include "courtloc_mcu.h"', ""]
    out.append("static const struct { clm_frame_t frame; uint8_t bytes[CLM_MAX_FRAME]; uint8_t size; } "
               "CLM_ENCODE_VECTORS[] = {")
    for case in data["encode"]:
        f, raw = case["frame"], bytes.fromhex(case["hex"])
        out.append(f"    {{{{0x{f['seq']:04x}, 0x{f['command']:02x}, {f['rpm']}, 0x{f['flags']:02x}, {f['reason']}, 0, {{0}}}}, "
                   f"{_bytes(raw)}, {len(raw)}}},")
    out.append("};")
    out.append("static const struct { clm_odometry_t odometry; uint8_t bytes[CLM_ODOMETRY_FRAME_SIZE]; } "
               "CLM_ODOMETRY_VECTORS[] = {")
    for case in data["odometry"]:
        o = case["fixed"]
        gz = f"{o['gz_urad_s']}" if o["gz_urad_s"] > -2147483648 else "(-2147483647 - 1)"
        out.append(f"    {{{{{o['seq']}u, {o['t_us']}u, {o['vx_mm_s']}, {o['vy_mm_s']}, {o['wz_mrad_s']}, {gz}, "
                   f"0x{o['flags']:02x}}}, {_bytes(bytes.fromhex(case['hex']))}}},")
    out.append("};")
    for i, case in enumerate(data["decode"]):
        stream = bytes.fromhex(case["hex"])
        out.append(f"static const uint8_t CLM_DECODE_STREAM_{i}[] = {_bytes(stream)};")
        out.append(f"static const clm_frame_t CLM_DECODE_FRAMES_{i}[] = {{")
        for f in case["frames"] or [None]:
            if f is None:
                out.append("    {0, 0, 0, 0, 0, 0, {0}},")
                continue
            extra = bytes.fromhex(f["extra"])
            out.append(f"    {{0x{f['seq']:04x}, 0x{f['command']:02x}, {f['rpm']}, 0x{f['flags']:02x}, {f['reason']}, "
                       f"{len(extra)}, {_bytes(extra)}}},")
        out.append("};")
    out.append("static const struct { const char *name; const uint8_t *stream; size_t size; const clm_frame_t *frames; "
               "size_t n_frames; clm_stats_t stats; size_t buffered; } CLM_DECODE_VECTORS[] = {")
    for i, case in enumerate(data["decode"]):
        st = case["stats"]
        out.append(f'    {{"{case["name"]}", CLM_DECODE_STREAM_{i}, sizeof CLM_DECODE_STREAM_{i}, CLM_DECODE_FRAMES_{i}, '
                   f'{len(case["frames"])}, {{{st["frames"]}, {st["crc_errors"]}, {st["bad_length"]}, '
                   f'{st["unknown_command"]}, {st["discarded_bytes"]}}}, {case["buffered"]}}},')
    out += ["};", "", "#endif", ""]
    return "\n".join(out)


if __name__ == "__main__":
    out = Path(sys.argv[1]) if len(sys.argv) > 1 else DEFAULT_OUT
    out.write_text(render())
    header = out.with_suffix(".h")
    header.write_text(render_header())
    print(f"wrote {out} and {header}")
