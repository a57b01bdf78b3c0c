"""Zenoh sessions and publishers built from our config and the services table.

Multicast scouting is off unless asked for: on an arena network other teams' robots must not be
discovered or joined by accident.
"""
from __future__ import annotations

import json
import logging
import os
import threading
from contextlib import contextmanager
from pathlib import Path
from typing import Iterator, Literal

import zenoh
from pydantic import BaseModel, ConfigDict, Field

from courtloc.common.security import SecurityConfig, client_settings
from courtloc.common.services_table import Topic

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
    # After a router restart zenoh reconnects on its own schedule (1 s doubling to 4 s by default);
    # the same back-off as our first open keeps the resume time bounded by open_retry_max_s.
    zcfg.insert_json5("connect/retry", json.dumps({
        "period_init_ms": int(cfg.open_retry_s * 1000), "period_max_ms": int(cfg.open_retry_max_s * 1000),
        "period_increase_factor": 2.0}))
    # Every session on the path must agree, the router included, or the link falls back to bytes.
    zcfg.insert_json5("transport/shared_memory/enabled", json.dumps(cfg.shared_memory))
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


@contextmanager
def session(cfg: ZenohConfig) -> Iterator[zenoh.Session]:
    """A session that is always closed, however the block ends."""
    zsession = open_session(cfg)
    assert zsession is not None
    try:
        yield zsession
    finally:
        zsession.close()


def declare_publisher(zsession: zenoh.Session, topic: Topic, robot_id: str) -> zenoh.Publisher:
    return zsession.declare_publisher(
        topic.key(robot_id),
        priority=_PRIORITY[topic.priority],
        congestion_control=_CONGESTION[topic.congestion],
        express=topic.express,
    )
