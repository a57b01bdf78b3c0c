"""The transport baseline: one 640x480 BGR frame handed along RELAY_HOPS processes doing trivial work.

Each hop uses the same parts as a stage (session helper, table QoS, latest-only inbox, a worker thread,
the msgpack codec, header stamps), so the difference to the real chain is the real work.
Run as `python -m courtloc.bench_relay --hop I --port P --seconds S`; `courtloc bench pipeline --relay`
starts a router and the hops and compares them with the real chain in the same run.
"""
from __future__ import annotations

import argparse
import json
import sys
import threading
import time

import numpy as np
import zenoh

from courtloc.common import codec
from courtloc.common.bus import ZenohConfig, declare_publisher, open_session
from courtloc.common.inbox import LatestInbox
from courtloc.common.messages import Frame, Header
from courtloc.common.services_table import RELAY_HOPS, RELAY_TOPICS

ROBOT = "bench"
WIDTH, HEIGHT = 640, 480


def _source(session: zenoh.Session, seconds: float, fps: float) -> None:
    publisher = declare_publisher(session, RELAY_TOPICS[0], ROBOT)
    pixels = np.random.default_rng(0).integers(0, 255, (HEIGHT, WIDTH, 3), np.uint8).tobytes()
    period, deadline, seq = 1.0 / fps, time.monotonic(), 0
    end = deadline + seconds
    stop = threading.Event()
    while deadline < end:
        header = Header.now(ROBOT, seq, "relay0")
        header.valid = True
        publisher.put(codec.encode(Frame(header=header, width=WIDTH, height=HEIGHT, encoding="bgr8", data=pixels)))
        seq += 1
        deadline += period
        stop.wait(max(0.0, deadline - time.monotonic()))


def _hop(session: zenoh.Session, hop: int, seconds: float) -> list[float]:
    """Forward (or, on the last hop, measure) every frame of the previous hop until `seconds` pass."""
    last = hop == RELAY_HOPS - 1
    inbox = LatestInbox()
    subscriber = session.declare_subscriber(RELAY_TOPICS[hop - 1].key(ROBOT),
                                            lambda sample: inbox.put("frame", sample.payload))
    publisher = None if last else declare_publisher(session, RELAY_TOPICS[hop], ROBOT)
    spans_ms: list[float] = []
    end = time.monotonic() + seconds
    while time.monotonic() < end:
        delivery = inbox.take(timeout=0.5)
        if delivery is None:
            continue
        frame = codec.decode(bytes(delivery.payload), Frame)
        header = frame.header.forwarded(f"relay{hop}", valid=True)
        if last:
            spans_ms.append(header.span_ns() / 1e6)
        else:
            publisher.put(codec.encode(frame.model_copy(update={"header": header})))
    subscriber.undeclare()
    return spans_ms


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument("--hop", type=int, required=True)
    parser.add_argument("--port", type=int, required=True)
    parser.add_argument("--seconds", type=float, default=10.0)
    parser.add_argument("--fps", type=float, default=30.0)
    parser.add_argument("--mode", choices=["client", "peer"], default="client")
    args = parser.parse_args(argv)
    session = open_session(ZenohConfig(mode=args.mode, connect=[f"tcp/127.0.0.1:{args.port}"]), threading.Event())
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
