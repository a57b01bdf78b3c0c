"""Real routers, real stage processes and a real bus client for integration tests.

Everything waits on events (a line printed, a message received, a liveliness change) with a
deadline; nothing sleeps to synchronise.
"""
from __future__ import annotations

import queue
import socket
import subprocess
import sys
import threading
import time
from contextlib import closing
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Callable, Iterator

import zenoh

from courtloc.common import codec
from courtloc.common.bus import ZenohConfig, open_session
from courtloc.common.services_table import TOPICS, all_liveliness_key, service_of_liveliness_key
from courtloc.router_process import RouterSettings, router_argv
from courtloc.services.deployment import load_deployment
from courtloc.stage_cli import stage_argv

PYTHON = [sys.executable, "-m", "courtloc"]


def free_port() -> int:
    with closing(socket.socket(socket.AF_INET, socket.SOCK_STREAM)) as sock:
        sock.bind(("127.0.0.1", 0))
        return int(sock.getsockname()[1])


def endpoint(port: int) -> str:
    return f"tcp/127.0.0.1:{port}"


@dataclass
class Proc:
    """A child process whose output lines are collected and can be awaited."""

    argv: list[str]
    env: dict[str, str] | None = None
    lines: list[str] = field(default_factory=list)
    process: subprocess.Popen | None = None
    _new_line: threading.Condition = field(default_factory=threading.Condition)

    def start(self) -> "Proc":
        self.process = subprocess.Popen(self.argv, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True,
                                        stdin=subprocess.DEVNULL, env=self.env)
        threading.Thread(target=self._pump, daemon=True).start()
        return self

    def _pump(self) -> None:
        assert self.process is not None and self.process.stdout is not None
        for line in self.process.stdout:
            with self._new_line:
                self.lines.append(line.rstrip("\n"))
                self._new_line.notify_all()
        with self._new_line:
            self._new_line.notify_all()

    def wait_line(self, needle: str, timeout: float = 20.0) -> str:
        deadline = time.monotonic() + timeout
        with self._new_line:
            while True:
                for line in self.lines:
                    if needle in line:
                        return line
                remaining = deadline - time.monotonic()
                if remaining <= 0 or (self.process is not None and self.process.poll() is not None
                                      and not self._pending()):
                    raise AssertionError(f"no line with {needle!r} in {self.argv}:\n" + "\n".join(self.lines[-30:]))
                self._new_line.wait(remaining)

    def _pending(self) -> bool:
        return bool(self.process and self.process.stdout and not self.process.stdout.closed)

    @property
    def pid(self) -> int:
        assert self.process is not None
        return self.process.pid

    def alive(self) -> bool:
        return self.process is not None and self.process.poll() is None

    def stop(self, timeout: float = 10.0) -> int | None:
        if self.process is None:
            return None
        if self.process.poll() is None:
            self.process.terminate()
            try:
                self.process.wait(timeout)
            except subprocess.TimeoutExpired:
                self.process.kill()
                self.process.wait()
        return self.process.returncode

    def kill(self) -> None:
        if self.process is not None and self.process.poll() is None:
            self.process.kill()
            self.process.wait()

    def output(self) -> str:
        return "\n".join(self.lines)


def start_router(port: int) -> Proc:
    """A router on loopback as the launcher starts it (the lean router process, without the CLI's imports);
    the `courtloc router` command itself: test_placement_two_hosts, test_security_*, test_router_process."""
    router = Proc(router_argv(RouterSettings(robot_id="robot1", listen=[endpoint(port)]))).start()
    router.wait_line("router listening")
    return router


def start_stage(name: str, config_path: Path, verbose: bool = True) -> Proc:
    """The stage's own process, started as the launcher starts it: `courtloc run` checks the config and then
    becomes this same command line (stage_argv: a simulated camera is the twin's camera stage), so going
    straight to it skips only the CLI's imports (~1.5 s a stage). `courtloc run` itself is tested in test_config,
    test_realtime, test_security_own_credentials and test_cli_mistakes."""
    return Proc(stage_argv(name, config_path, load_deployment(config_path), verbose=1 if verbose else 0)).start()


class BusClient:
    """A test's own Zenoh client on the router: await messages and liveliness, inject payloads."""

    def __init__(self, port: int, robot_id: str = "robot1", reconnect_max_s: float | None = None,
                 wait_for_router_s: float = 0.0) -> None:
        self.robot_id = robot_id
        # reconnect_max_s: a short back-off so the client itself is not the slow part after a router restart
        retry = {} if reconnect_max_s is None else {"open_retry_s": reconnect_max_s / 2,
                                                    "open_retry_max_s": reconnect_max_s}
        give_up = threading.Event()  # with wait_for_router_s, keep trying until the router listens
        timer = threading.Timer(wait_for_router_s, give_up.set)
        timer.start()
        try:
            session = open_session(ZenohConfig(mode="client", connect=[endpoint(port)], **retry),
                                   give_up if wait_for_router_s > 0 else None)
        finally:
            timer.cancel()
        if session is None:
            raise AssertionError(f"no router on port {port} within {wait_for_router_s} s")
        self.session = session
        self._queues: dict[str, queue.Queue] = {}
        self._subs: list[Any] = []
        self._alive: set[str] = set()
        self._alive_cond = threading.Condition()
        self._subs.append(self.session.liveliness().declare_subscriber(
            all_liveliness_key(robot_id), self._on_liveliness, history=True))

    def _on_liveliness(self, sample: zenoh.Sample) -> None:
        with self._alive_cond:
            service = service_of_liveliness_key(str(sample.key_expr))
            if sample.kind == zenoh.SampleKind.PUT:
                self._alive.add(service)
            else:
                self._alive.discard(service)
            self._alive_cond.notify_all()

    def wait_alive(self, service: str, alive: bool = True, timeout: float = 30.0) -> None:
        with self._alive_cond:
            if not self._alive_cond.wait_for(lambda: (service in self._alive) == alive, timeout):
                raise AssertionError(f"{service} liveliness never became {alive}")

    def subscribe(self, path: str) -> None:
        q: queue.Queue = queue.Queue()
        self._queues[path] = q
        self._subs.append(self.session.declare_subscriber(
            TOPICS[path].key(self.robot_id), lambda sample: q.put(bytes(sample.payload))))

    def messages(self, path: str, timeout: float = 20.0) -> Iterator[Any]:
        """Decoded messages of `path` as they arrive, until `timeout` seconds pass without the caller stopping."""
        q = self._queues[path]
        deadline = time.monotonic() + timeout
        while True:
            remaining = deadline - time.monotonic()
            if remaining <= 0:
                raise AssertionError(f"timed out waiting on {path}")
            try:
                payload = q.get(timeout=remaining)
            except queue.Empty:
                raise AssertionError(f"timed out waiting on {path}") from None
            yield codec.decode(payload, TOPICS[path].message)

    def wait_for(self, path: str, predicate: Callable[[Any], bool] = lambda m: True, timeout: float = 20.0) -> Any:
        for message in self.messages(path, timeout):
            if predicate(message):
                return message
        raise AssertionError("unreachable")

    def drain(self, path: str) -> None:
        q = self._queues[path]
        while not q.empty():
            q.get_nowait()

    def put_raw(self, path: str, payload: bytes) -> None:
        # Blocking, not zenoh's default (drop): a test that puts hundreds of messages in a loop counts on the
        # stage receiving each one, and a full transmit queue must not drop some on a busy machine.
        self.session.put(TOPICS[path].key(self.robot_id), payload, congestion_control=zenoh.CongestionControl.BLOCK)

    def wait_subscribed(self, path: str, timeout: float = 20.0) -> None:
        """Until some subscriber of `path` is known to the router: a put before that reaches nobody."""
        matched = threading.Event()
        publisher = self.session.declare_publisher(TOPICS[path].key(self.robot_id))
        listener = publisher.declare_matching_listener(lambda status: matched.set() if status.matching else None)
        try:
            if not (publisher.matching_status.matching or matched.wait(timeout)):
                raise AssertionError(f"no subscriber of {path} appeared within {timeout} s")
        finally:
            listener.undeclare()
            publisher.undeclare()

    def close(self) -> None:
        for sub in self._subs:
            sub.undeclare()
        self.session.close()


def write_config(path: Path, port: int, body: str = "", robot_id: str = "robot1", zenoh_extra: str = "",
                 health_period_s: float | None = None) -> Path:
    """A deployment file whose stages connect to the test router on `port`; quick reconnects. health_period_s:
    for a test that waits on health reports, a short period makes each wait short (counts are what it checks)."""
    health = "" if health_period_s is None else f"health_period_s = {health_period_s:g}\n"
    path.write_text(f'robot_id = "{robot_id}"\n{health}[zenoh]\nconnect = ["{endpoint(port)}"]\n'
                    f'open_retry_s = 0.1\nopen_retry_max_s = 0.3\n{zenoh_extra}\n{body}\n')
    return path




def write_line_frames(folder: Path, n: int = 3, size: tuple[int, int] = (480, 640)) -> Path:
    """`n` PNG frames of a grey floor with one white line each (so preprocess finds hits)."""
    import cv2
    import numpy as np

    folder.mkdir(parents=True, exist_ok=True)
    height, width = size
    for i in range(n):
        image = np.full((height, width, 3), 60, np.uint8)
        cv2.line(image, (0, height * 5 // 8 + 20 * i), (width - 1, height * 11 // 16), (255, 255, 255), 4)
        cv2.imwrite(str(folder / f"{i}.png"), image)
    return folder


def folder_camera_toml(folder: Path, fps: float = 20, extra: str = "") -> str:
    """The [camera] tables of a deployment whose camera replays PNGs from `folder`."""
    return (f'[camera]\nsource = "folder"\nfps = {fps}\n{extra}\n'
            f'[camera.folder]\npath = "{folder}"\npattern = "*.png"\n')
