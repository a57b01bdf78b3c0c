"""The monitor's web server: standard library only (http.server), Server-Sent Events for live state.

One ticker thread builds the state `rate_hz` times a second and wakes every open event stream; each
browser connection has its own server thread that only waits and writes. Static files ship in the
package (no CDN: the pit has no internet).
"""
from __future__ import annotations

import json
import logging
import sys
import threading
from http import HTTPStatus
from http.server import BaseHTTPRequestHandler, ThreadingHTTPServer
from importlib import resources
from typing import Any, Callable
from urllib.parse import urlsplit

log = logging.getLogger("courtloc.monitor")

STATIC_TYPES = {".html": "text/html; charset=utf-8", ".js": "text/javascript; charset=utf-8",
                ".css": "text/css; charset=utf-8"}
STATIC_FILES = ("index.html", "app.js", "style.css")


class Broadcast:
    """The newest state as JSON, with a version number that streams wait on."""

    def __init__(self) -> None:
        self._cond = threading.Condition()
        self.version = 0
        self.body = b"{}"

    def publish(self, state: dict[str, Any]) -> None:
        body = json.dumps(state, separators=(",", ":"), allow_nan=False).encode()
        with self._cond:
            self.version += 1
            self.body = body
            self._cond.notify_all()

    def wait_newer(self, version: int, timeout: float) -> tuple[int, bytes]:
        with self._cond:
            self._cond.wait_for(lambda: self.version != version, timeout)
            return self.version, self.body

    def wake_all(self) -> None:
        with self._cond:
            self._cond.notify_all()


class MonitorServer(ThreadingHTTPServer):
    daemon_threads = True
    allow_reuse_address = True

    def __init__(self, address: tuple[str, int], broadcast: Broadcast, court_json: bytes,
                 thumbnail: Callable[[], bytes | None], stop: threading.Event) -> None:
        super().__init__(address, MonitorHandler)
        self.broadcast = broadcast
        self.court_json = court_json
        self.thumbnail = thumbnail
        self.stop = stop
        self.static = {name: resources.files("courtloc.monitor").joinpath("static", name).read_bytes()
                       for name in STATIC_FILES}

    def handle_error(self, request: Any, client_address: Any) -> None:
        """A browser that goes away mid-response is normal (a closed tab), not a traceback."""
        if isinstance(sys.exc_info()[1], (BrokenPipeError, ConnectionResetError, TimeoutError)):
            log.debug("client %s went away", client_address)
            return
        super().handle_error(request, client_address)


class MonitorHandler(BaseHTTPRequestHandler):
    server: MonitorServer
    protocol_version = "HTTP/1.1"

    def log_message(self, format: str, *args: Any) -> None:  # noqa: A002 - signature of the base class
        log.debug("http %s: " + format, self.address_string(), *args)

    def do_GET(self) -> None:  # noqa: N802 - http.server's naming
        path = urlsplit(self.path).path
        if path in ("/", "/index.html"):
            self._send(HTTPStatus.OK, STATIC_TYPES[".html"], self.server.static["index.html"])
        elif path.startswith("/static/") and path[len("/static/"):] in self.server.static:
            name = path[len("/static/"):]
            self._send(HTTPStatus.OK, STATIC_TYPES["." + name.rsplit(".", 1)[1]], self.server.static[name])
        elif path == "/api/court":
            self._send(HTTPStatus.OK, "application/json", self.server.court_json)
        elif path == "/api/state":
            self._send(HTTPStatus.OK, "application/json", self.server.broadcast.body)
        elif path == "/thumb.jpg":
            jpeg = self.server.thumbnail()
            if jpeg is None:
                self._send(HTTPStatus.NOT_FOUND, "text/plain", b"no camera frame yet")
            else:
                self._send(HTTPStatus.OK, "image/jpeg", jpeg)
        elif path == "/events":
            self._stream()
        else:
            self._send(HTTPStatus.NOT_FOUND, "text/plain", b"not found")

    def _send(self, status: HTTPStatus, content_type: str, body: bytes) -> None:
        self.send_response(status)
        self.send_header("Content-Type", content_type)
        self.send_header("Content-Length", str(len(body)))
        self.send_header("Cache-Control", "no-store")
        self.end_headers()
        self.wfile.write(body)

    def _stream(self) -> None:
        """Server-Sent Events: one `data:` line per new state, until the browser or the monitor goes."""
        self.send_response(HTTPStatus.OK)
        self.send_header("Content-Type", "text/event-stream")
        self.send_header("Cache-Control", "no-store")
        self.send_header("Connection", "close")
        self.end_headers()
        self.close_connection = True
        broadcast, stop = self.server.broadcast, self.server.stop
        version = 0  # the first state is published by the ticker (version 1): nothing before it
        try:
            self.wfile.write(b"retry: 1000\n\n")  # the browser reconnects within 1 s if the monitor restarts
            while not stop.is_set():
                new_version, body = broadcast.wait_newer(version, timeout=1.0)
                if new_version == version:
                    self.wfile.write(b": keep-alive\n\n")
                else:
                    version = new_version
                    self.wfile.write(b"data: " + body + b"\n\n")
                self.wfile.flush()
        except (BrokenPipeError, ConnectionResetError, TimeoutError):
            log.debug("event stream to %s closed", self.address_string())
