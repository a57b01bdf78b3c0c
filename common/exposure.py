"""What a process exposes beyond this machine, and the nagging that `insecure = true` buys.

Other teams share the arena network: a listener beyond loopback needs the security bundle, or the
deployment's explicit `insecure = true`, in which case the process says so in its log every minute.
"""
from __future__ import annotations

import logging
import threading

INSECURE_WARNING_PERIOD_S = 60.0
_LOOPBACK_HOSTS = {"localhost", "::1", "[::1]"}


def endpoint_host(endpoint: str) -> str:
    """The host of a zenoh endpoint `proto/host:port[?...][#...]`."""
    address = endpoint.split("/", 1)[-1].split("?", 1)[0].split("#", 1)[0]
    return address.rsplit(":", 1)[0] if ":" in address else address


def is_loopback(endpoint: str) -> bool:
    host = endpoint_host(endpoint)
    return host in _LOOPBACK_HOSTS or host.startswith("127.")


def exposed_endpoints(listening: list[str]) -> list[str]:
    """Those of `listening` reachable beyond this machine."""
    return [ep for ep in listening if not is_loopback(ep)]


def insecure_exposure(listening: list[str], secured: bool) -> list[str]:
    """Of the endpoints this process listens on, those beyond loopback left open (only `insecure = true`
    lets a process get this far with any)."""
    return [] if secured else exposed_endpoints(listening)


def warn_while_insecure(exposed: list[str], stop: threading.Event, logger: logging.Logger,
                        period_s: float = INSECURE_WARNING_PERIOD_S) -> threading.Thread | None:
    """A warning now and every `period_s` until `stop`, while `exposed` endpoints are open to anyone."""
    if not exposed:
        return None

    def nag() -> None:
        while True:
            logger.warning("INSECURE: listening on %s without authentication or encryption (insecure = true): "
                           "anyone on this network can read and drive the robot", ", ".join(exposed))
            if stop.wait(period_s):
                return

    thread = threading.Thread(target=nag, name="insecure-warning", daemon=True)
    thread.start()
    return thread
