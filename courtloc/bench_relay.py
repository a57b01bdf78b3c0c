"""The transport baseline: one 640x480 BGR frame handed along RELAY_HOPS processes doing trivial work.

Each hop uses the same parts as a stage (session helper, table QoS, an inbox as deep as the chain's, a worker thread,
header stamps) and moves the frame the way the chain does: the source writes it once into its shared-memory
pool like the camera, every hop copies the pixels out once like preprocess and writes them into its own
pool to pass them on. So the difference to the real chain is the real work.
Run as `python -m courtloc.bench_relay --hop I --port P --seconds S`; `courtloc bench pipeline --relay`
starts a router and the hops and compares them with the real chain in the same run. With `--realtime JSON` (the
deployment's `[realtime]`) hop I runs with the settings of the I-th stage (camera, preprocess, infer,
shooter_bridge), as the chain's stages do, so the two stay comparable.
"""
from __future__ import annotations

import argparse
import json
import sys
import threading
import time

import numpy as np
import zenoh

from courtloc.common.bus import ZenohConfig, declare_publisher, open_session
from courtloc.common.inbox import Inbox
from courtloc.common.messages import Frame, Header
from courtloc.common.realtime import RealtimeConfig, apply_realtime
from courtloc.common.services_table import RELAY_HOPS, RELAY_TOPICS, SERVICES
from courtloc.common.shm_frames import PixelStaging, ShmFramePublisher, decode_frame_payload

ROBOT = "bench"
WIDTH, HEIGHT = 640, 480
POOL_BYTES = 16 * 2**20  # the camera's default pool


def _source(session: zenoh.Session, seconds: float, fps: float) -> None:
    publisher = ShmFramePublisher(declare_publisher(session, RELAY_TOPICS[0], ROBOT), POOL_BYTES)
    image = np.random.default_rng(0).integers(0, 255, (HEIGHT, WIDTH, 3), np.uint8)
    staging = PixelStaging()
    period, deadline, seq = 1.0 / fps, time.monotonic(), 0
    end = deadline + seconds
    stop = threading.Event()
    while deadline < end:
        header = Header.now(ROBOT, seq, "relay0")
        header.valid = True
        image[0, 0, 0] = seq % 256  # frames differ, as a camera's do
        publisher.put(Frame(header=header, width=WIDTH, height=HEIGHT, encoding="bgr8", data=b""), staging.fill(image))
        seq += 1
        deadline += period
        stop.wait(max(0.0, deadline - time.monotonic()))


def _hop(session: zenoh.Session, hop: int, seconds: float) -> list[float]:
    """Forward (or, on the last hop, measure) every frame of the previous hop until `seconds` pass."""
    last = hop == RELAY_HOPS - 1
    inbox = Inbox({"frame": RELAY_TOPICS[hop - 1].inbox_depth})  # kept as deep as the chain keeps its frames
    subscriber = session.declare_subscriber(RELAY_TOPICS[hop - 1].key(ROBOT),
                                            lambda sample: inbox.put("frame", sample.payload))
    publisher = None if last else ShmFramePublisher(declare_publisher(session, RELAY_TOPICS[hop], ROBOT), POOL_BYTES)
    spans_ms: list[float] = []
    end = time.monotonic() + seconds
    while time.monotonic() < end:
        delivery = inbox.take(timeout=0.5)
        if delivery is None:
            continue
        received = decode_frame_payload(delivery.payload)
        delivery.payload = None  # copied out: the buffer goes back to its pool
        header = received.header.forwarded(f"relay{hop}", valid=True)
        if last:
            spans_ms.append(header.span_ns() / 1e6)
        else:
            # zenoh-python writes provider buffers from bytes only: the pass-on costs one more copy
            publisher.put(received.message.model_copy(update={"header": header}), bytes(received.pixels))
    subscriber.undeclare()
    return spans_ms


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument("--hop", type=int, required=True)
    parser.add_argument("--port", type=int, required=True)
    parser.add_argument("--seconds", type=float, default=10.0)
    parser.add_argument("--fps", type=float, default=30.0)
    parser.add_argument("--mode", choices=["stage", "client", "peer"], default="stage",
                        help="stage: the session a pipeline stage opens (ZenohConfig.stage_links)")
    parser.add_argument("--realtime", type=RealtimeConfig.model_validate_json, default=RealtimeConfig(),
                        help="the deployment's [realtime] as JSON: this hop takes its stage's settings")
    args = parser.parse_args(argv)
    apply_realtime(list(SERVICES)[args.hop], args.realtime)  # before the session: zenoh's threads inherit it
    config = ZenohConfig(connect=[f"tcp/127.0.0.1:{args.port}"])
    config = config.stage_links() if args.mode == "stage" else config.model_copy(update={"mode": args.mode})
    session = open_session(config, threading.Event())
    assert session is not None
    try:
        print("ready", flush=True)
        sys.stdin.readline()  # the bench starts every hop at once, when all are connected
        if args.hop == 0:
            _source(session, args.seconds, args.fps)
        else:
            spans = _hop(session, args.hop, args.seconds + 2.0)
            if args.hop == RELAY_HOPS - 1:
                print(json.dumps(spans), flush=True)
    finally:
        session.close()
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
