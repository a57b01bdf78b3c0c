"""Zenoh sessions and publishers built from our config and the services table.

Multicast scouting is off unless asked for: on an arena network other teams' robots must not be
discovered or joined by accident.
"""
from __future__ import annotations

import json
import logging
import os
import re
import secrets
import sys
import threading
import time
from pathlib import Path
from typing import Callable, Literal

import zenoh
from pydantic import BaseModel, ConfigDict, Field

from courtloc.common.exposure import is_loopback
from courtloc.common.security import SecurityConfig, client_settings
from courtloc.common.services_table import MAX_BUS_MESSAGE_BYTES, Topic

log = logging.getLogger(__name__)

_PRIORITY = {
    "real_time": zenoh.Priority.REAL_TIME,
    "interactive_high": zenoh.Priority.INTERACTIVE_HIGH,
    "data_high": zenoh.Priority.DATA_HIGH,
    "data": zenoh.Priority.DATA,
    "data_low": zenoh.Priority.DATA_LOW,
    "background": zenoh.Priority.BACKGROUND,
}
_CONGESTION = {"drop": zenoh.CongestionControl.DROP, "block": zenoh.CongestionControl.BLOCK}


class ZenohConfig(BaseModel):
    model_config = ConfigDict(extra="forbid")

    mode: Literal["client", "peer", "router"] = "client"
    connect: list[str] = Field(default_factory=lambda: ["tcp/127.0.0.1:7447"])
    listen: list[str] = Field(default_factory=list)
    config_file: Path | None = Field(
        default=None, description="a standard zenoh JSON5 config; $ZENOH_CONFIG is used when unset")
    multicast_scouting: bool = False
    open_retry_s: float = Field(default=0.5, gt=0, description="first back-off while no router answers")
    open_retry_max_s: float = Field(default=2.0, gt=0)
    shared_memory: bool = Field(
        default=True, description="zenoh shared memory on this session: large payloads between processes of "
        "one host travel as a descriptor; a link that cannot share memory (another host) carries bytes")
    security: SecurityConfig | None = Field(
        default=None, description="mTLS + password from a `courtloc secure init` bundle (tls/ endpoints)")
    direct_links: bool = Field(
        default=True, description="stages on the router's own host (every connect endpoint on loopback) join as "
        "zenoh peers listening on loopback and exchange data over direct links: one socket hop instead of two "
        "through the router. The router still carries everything to and from other hosts and tools. Not with "
        "[zenoh.security]: a peer's listener would be a way in that skips the router's mTLS and password")

    def stage_links(self) -> "ZenohConfig":
        """The config a pipeline stage opens its session with: a loopback peer when `direct_links` allows it
        (a client of a router on this host, no security), else this one unchanged."""
        if (self.mode != "client" or not self.direct_links or self.security is not None or not self.connect
                or not all(is_loopback(endpoint) for endpoint in self.connect)):
            return self
        # Port 0: the OS picks a free one; the router tells the other peers where (gossip).
        return self.model_copy(update={"mode": "peer", "listen": ["tcp/127.0.0.1:0"]})


def build_zenoh_config(cfg: ZenohConfig) -> zenoh.Config:
    """Start from the standard config file when given; our explicit fields win over it."""
    file = cfg.config_file or (Path(os.environ["ZENOH_CONFIG"]) if os.environ.get("ZENOH_CONFIG") else None)
    zcfg = zenoh.Config.from_file(str(file)) if file else zenoh.Config()
    zcfg.insert_json5("mode", json.dumps(cfg.mode))
    zcfg.insert_json5("scouting/multicast/enabled", json.dumps(cfg.multicast_scouting))
    if cfg.connect:
        zcfg.insert_json5("connect/endpoints", json.dumps(cfg.connect))
    if cfg.listen:
        zcfg.insert_json5("listen/endpoints", json.dumps(cfg.listen))
    if cfg.mode == "peer":
        # Peers learn each other from the router they connect to (gossip) and link up directly; multicast
        # scouting stays as configured (off: no other team's robot is found).
        zcfg.insert_json5("scouting/gossip/enabled", "true")
        zcfg.insert_json5("scouting/gossip/autoconnect", json.dumps({"peer": ["peer"]}))
    # After a router restart zenoh reconnects on its own schedule (1 s doubling to 4 s by default);
    # the same back-off as our first open keeps the resume time bounded by open_retry_max_s.
    zcfg.insert_json5("connect/retry", json.dumps({
        "period_init_ms": int(cfg.open_retry_s * 1000), "period_max_ms": int(cfg.open_retry_max_s * 1000),
        "period_increase_factor": 2.0}))
    # Every session on the path must agree, the router included, or the link falls back to bytes.
    zcfg.insert_json5("transport/shared_memory/enabled", json.dumps(cfg.shared_memory))
    # zenoh reassembles a fragmented message whole (1 GiB allowed by default) before a subscriber sees it:
    # bounded by the services table, a bigger one is dropped on receipt (the link stays up) instead of being
    # held in memory until our own size check refuses it. Payloads in shared memory are not reassembled
    # (a descriptor travels); the runtime's size check refuses those before copying them.
    zcfg.insert_json5("transport/link/rx/max_message_size", json.dumps(MAX_BUS_MESSAGE_BYTES))
    if cfg.security is not None and cfg.mode != "router":
        for path, value in client_settings(cfg.security).items():
            zcfg.insert_json5(path, json.dumps(value))
    return zcfg


def open_session(cfg: ZenohConfig, stop: threading.Event | None = None) -> zenoh.Session | None:
    """Open a session, waiting with back-off while no router answers (a client cannot open without one).

    Returns None only when `stop` is set before a session could be opened.
    """
    delay = cfg.open_retry_s
    while True:
        try:
            return zenoh.open(build_zenoh_config(cfg))
        except zenoh.ZError as exc:
            if stop is None:
                raise
            log.warning("zenoh: cannot open session (%s); retrying in %.1f s", str(exc).split(" at ")[0], delay)
            if stop.wait(delay):
                return None
            delay = min(delay * 2, cfg.open_retry_max_s)


def declare_publisher(zsession: zenoh.Session, topic: Topic, robot_id: str) -> zenoh.Publisher:
    return zsession.declare_publisher(
        topic.key(robot_id),
        priority=_PRIORITY[topic.priority],
        congestion_control=_CONGESTION[topic.congestion],
        express=topic.express,
    )


class RouterUnreachable(ConnectionError):
    """No router answered at the configured endpoints in the time given."""


def wait_for_router(zenoh_config: ZenohConfig, timeout_s: float | None) -> None:
    """Return once a session to the configured endpoints opens (then closed again: the caller opens its
    own); raise RouterUnreachable naming the endpoints when none answers within `timeout_s` (None: wait on).

    While it waits it says once on stderr what it waits for, on a terminal or when it may wait forever
    (a pipe with a timeout gets only the verdict: one line).
    """
    endpoints = ", ".join(zenoh_config.connect) or "any router (scouting)"
    deadline = None if timeout_s is None else time.monotonic() + timeout_s
    delay, said = zenoh_config.open_retry_s, False
    while True:
        try:
            zenoh.open(build_zenoh_config(zenoh_config)).close()
            return
        except zenoh.ZError as exc:
            reason = str(exc).split(" at ")[0]
        left = None if deadline is None else deadline - time.monotonic()
        if left is not None and left <= 0:
            raise RouterUnreachable(f"no router answered at {endpoints} within {timeout_s:g} s ({reason}); "
                                    "is it running, and is --connect / the config's [zenoh] connect right?")
        if not said and (deadline is None or sys.stderr.isatty()):
            limit = "until it answers (Ctrl-C stops; --timeout S gives up)" if deadline is None else \
                f"up to {timeout_s:g} s"
            log.warning("waiting for a router at %s %s", endpoints, limit)
            said = True
        time.sleep(delay if left is None else min(delay, left))
        delay = min(delay * 2, zenoh_config.open_retry_max_s)


# zenoh ids: up to 16 bytes in lower-case hex, without leading zeros (zenoh refuses "0a...").
ZENOH_ID_PATTERN = re.compile(r"^[1-9a-f][0-9a-f]{0,31}$")


def check_zenoh_id(value: str) -> str:
    if not ZENOH_ID_PATTERN.match(value):
        raise ValueError(f"zenoh id {value!r} must match {ZENOH_ID_PATTERN.pattern} (hex, no leading zero)")
    return value


def new_router_id() -> str:
    """A fresh zenoh id for a router one run starts: 128 random bits with the top one set (no leading zero),
    so no other pipeline's router has it by chance."""
    return f"{secrets.randbits(127) | 1 << 127:032x}"


def watch_router_identity(zsession: zenoh.Session, expected_id: str,
                          on_foreign: Callable[[str], None]) -> zenoh.TransportEventsListener:
    """Call `on_foreign(router_id)` whenever `zsession` is connected to a router whose id is not
    `expected_id`: the routers connected now (checked before this returns) and any it connects to later.
    A client reconnects to whatever listens at its endpoint: after its router died, another pipeline's router
    that took the port would be joined silently. A transport event, not a poll: it fires as the link opens,
    before much data can cross it. Peers (another stage in peer mode) are not routers and are not checked.
    `on_foreign` may be called more than once for one router. Undeclare the listener when done."""
    check_zenoh_id(expected_id)

    def on_event(event: zenoh.TransportEvent) -> None:
        transport = event.transport
        if (event.kind == zenoh.SampleKind.PUT and transport.whatami == zenoh.WhatAmI.ROUTER
                and str(transport.zid) != expected_id):
            on_foreign(str(transport.zid))

    # Declared first, then the current routers read: a transport opening in between is seen by one of the
    # two (the listener's own history arrives later, on zenoh's thread, after the caller has gone on).
    listener = zsession.info.declare_transport_events_listener(on_event, history=False)
    for router_id in (str(zid) for zid in zsession.info.routers_zid()):
        if router_id != expected_id:
            on_foreign(router_id)
    return listener
