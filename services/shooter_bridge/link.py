"""The serial link to the shooter MCU: latest command wins, heartbeat when idle, reconnect with back-off.

One writer thread owns the port. `send()` only replaces the pending command and wakes the thread, so
the caller never blocks and never sees a serial error; a command replaced before it was written is
counted, not queued (an old RPM is worth nothing). When nothing was written for `heartbeat_s`, a
HEARTBEAT goes out. A write or open failure closes the port and retries after 0.1 s, 0.2 s, 0.4 s ...
up to `reconnect_max_s`; a command queued while the port was away is dropped on reconnect.

The thread sleeps in one select() on the port and a wake-up pipe, so frames from the MCU are read as
soon as they arrive (their receive time is what maps the MCU's clock onto ours): STATUS frames go to
`on_status`, ODOMETRY frames with their receive time to `on_odometry`.
"""
from __future__ import annotations

import logging
import os
import select
import threading
import time
from dataclasses import dataclass
from typing import Callable, Iterator, Optional

import serial

from courtloc.services.shooter_bridge.config import LinkConfig
from courtloc.services.shooter_bridge.protocol import (
    Command,
    FrameError,
    HoldReason,
    McuFrame,
    OdometrySample,
    StreamDecoder,
    encode,
    parse_odometry,
)

log = logging.getLogger(__name__)


@dataclass
class LinkStats:
    frames_sent: int = 0
    heartbeats_sent: int = 0
    commands_replaced: int = 0
    write_errors: int = 0
    read_errors: int = 0
    open_failures: int = 0
    connects: int = 0
    status_frames: int = 0
    odometry_frames: int = 0
    bad_odometry: int = 0
    last_error: str = ""


class McuLink:
    def __init__(self, config: LinkConfig, on_status: Optional[Callable[[McuFrame], None]] = None,
                 on_odometry: Optional[Callable[[OdometrySample, int], None]] = None) -> None:
        self.config = config
        self.on_status = on_status
        self.on_odometry = on_odometry  # called on the link thread with (sample, receive monotonic ns)
        self.stats = LinkStats()
        self.last_status: Optional[McuFrame] = None
        self._decoder = StreamDecoder()
        self._lock = threading.Lock()
        self._pending: Optional[tuple[Command, int, int, int]] = None
        self._wake_r, self._wake_w = os.pipe()  # select()-able wake-up: send() and stop() write a byte
        os.set_blocking(self._wake_r, False)
        os.set_blocking(self._wake_w, False)
        self._pipe_closed = False
        self._stop = threading.Event()
        self._connected = threading.Event()
        self._port = None  # serial.Serial while open; touched by the writer thread only
        self._seq = 0
        self._last_write = 0.0
        self._thread: Optional[threading.Thread] = None
        self._changed = threading.Condition()  # notified whenever stats or the connection change

    # ---- caller side ----------------------------------------------------------------------------
    def start(self) -> None:
        if self._thread is not None:
            return
        self._thread = threading.Thread(target=self._run, name="mcu-link", daemon=True)
        self._thread.start()

    def send(self, command: Command, rpm: float = 0.0, flags: int = 0, reason: int = 0) -> None:
        """Queue `command` for the MCU, replacing any not yet written. Never blocks, never raises."""
        value = int(round(min(max(rpm, 0.0), 65535.0))) if command is Command.SET_RPM else 0
        with self._lock:
            if self._pending is not None:
                self.stats.commands_replaced += 1
            self._pending = (command, value, int(flags) & 0xFF, int(reason) & 0xFF)
        self._poke()

    @property
    def connected(self) -> bool:
        return self._connected.is_set()

    def wait_connected(self, timeout: float) -> bool:
        return self._connected.wait(timeout)

    def wait_until(self, predicate: Callable[["McuLink"], bool], timeout: float) -> bool:
        """Block until `predicate(self)` holds (re-checked on every state change) or `timeout` passes."""
        with self._changed:
            return self._changed.wait_for(lambda: predicate(self), timeout)

    def _notify(self) -> None:
        with self._changed:
            self._changed.notify_all()

    def stop(self, timeout: float = 2.0) -> None:
        """Send a last HOLD (best effort), close the port and end the thread."""
        self._stop.set()
        self._poke()
        if self._thread is not None:
            self._thread.join(timeout)
            if self._thread.is_alive():
                return  # still using the wake-up pipe; it goes with the process
            self._thread = None
        if not self._pipe_closed:
            self._pipe_closed = True
            os.close(self._wake_r)
            os.close(self._wake_w)

    def _poke(self) -> None:
        if self._pipe_closed:  # stopped: the descriptor number may belong to another file by now
            return
        try:
            os.write(self._wake_w, b"\0")
        except BlockingIOError:  # the pipe is full: a wake-up is pending already
            pass

    def _wait(self, timeout: float) -> tuple[bool, int]:
        """Sleep until poked, the port is readable or `timeout`; (port readable, monotonic ns on waking)."""
        port_fd = self._port.fileno() if self._port is not None else None
        fds = [self._wake_r] if port_fd is None else [self._wake_r, port_fd]
        try:
            ready, _, _ = select.select(fds, [], [], timeout)
        except (OSError, ValueError):  # the port's descriptor went away under us: the read reports it
            ready = [port_fd]
        woke_ns = time.monotonic_ns()
        if self._wake_r in ready:
            try:
                while os.read(self._wake_r, 64):
                    pass
            except BlockingIOError:
                pass
        return port_fd is not None and port_fd in ready, woke_ns

    # ---- writer thread --------------------------------------------------------------------------
    def _run(self) -> None:
        delays = backoff_delays(self.config.reconnect_initial_s, self.config.reconnect_max_s)
        while not self._stop.is_set():
            if self._port is None:
                if not self._open():
                    self._stop.wait(next(delays))
                    continue
                delays = backoff_delays(self.config.reconnect_initial_s, self.config.reconnect_max_s)
            due = self._last_write + self.config.heartbeat_s - time.monotonic()
            readable, woke_ns = self._wait(max(0.0, due))
            if self._stop.is_set():
                break
            with self._lock:
                pending, self._pending = self._pending, None
            if pending is not None:
                self._write(*pending)
            elif time.monotonic() - self._last_write >= self.config.heartbeat_s:
                self._write(Command.HEARTBEAT, 0, 0, 0)
            # The wake-up time is the bytes' arrival only when they woke us: after a poke or a timeout any
            # bytes found came later, and are stamped when read.
            self._read_status(readable, woke_ns if readable else 0)
        if self._port is not None:
            self._write(Command.HOLD, 0, 0, int(HoldReason.STOPPED))
            self._close()

    def _open(self) -> bool:
        try:
            # exclusive: a second bridge on the same MCU must fail to open, not interleave frames
            self._port = serial.Serial(self.config.port, self.config.baud, timeout=0,
                                       write_timeout=self.config.write_timeout_s, exclusive=True)
        except (serial.SerialException, OSError, ValueError) as exc:
            self.stats.open_failures += 1
            self._note_error(f"open {self.config.port}: {exc}")
            return False
        self.stats.connects += 1
        self.stats.last_error = ""
        self._decoder = StreamDecoder()
        with self._lock:
            # A command queued while the port was away is old by now: the next decision replaces it.
            if self._pending is not None:
                self._pending = None
                self.stats.commands_replaced += 1
        self._last_write = 0.0  # heartbeat at once: the MCU learns the link is back
        self._connected.set()
        log.info("MCU link open on %s at %d baud", self.config.port, self.config.baud)
        self._notify()
        return True

    def _close(self) -> None:
        port, self._port = self._port, None
        self._connected.clear()
        if port is not None:
            try:
                port.close()
            except Exception:  # closing a vanished device may fail; it is gone either way
                pass
        self._notify()

    def _write(self, command: Command, rpm: int, flags: int, reason: int) -> None:
        if self._port is None:
            return
        data = encode(McuFrame(seq=self._seq, command=command, rpm=rpm, flags=flags, reason=reason))
        try:
            self._port.write(data)
        except (serial.SerialException, OSError) as exc:  # includes SerialTimeoutException
            self.stats.write_errors += 1
            self._note_error(f"write to {self.config.port}: {exc}")
            self._close()
            return
        self._seq = (self._seq + 1) & 0xFFFF
        self._last_write = time.monotonic()
        self.stats.frames_sent += 1
        if command is Command.HEARTBEAT:
            self.stats.heartbeats_sent += 1
        self._notify()

    def _read_status(self, readable: bool = False, received_ns: int = 0) -> None:
        if self._port is None:
            return
        received_ns = received_ns or time.monotonic_ns()
        try:
            waiting = self._port.in_waiting
            if readable and not waiting:
                # readable with nothing to read: the device hung up (pyserial raises on this read)
                data = self._port.read(1)
                if not data:
                    raise serial.SerialException("device reports readiness to read but returned no data")
            else:
                data = self._port.read(waiting) if waiting else b""
        except (serial.SerialException, OSError) as exc:
            self.stats.read_errors += 1
            self._note_error(f"read from {self.config.port}: {exc}")
            self._close()
            return
        for frame in self._decoder.feed(data):
            if frame.command is Command.ODOMETRY:
                self._hand_odometry(frame, received_ns)
                continue
            if frame.command is not Command.STATUS:
                continue
            self.stats.status_frames += 1
            self.last_status = frame
            self._notify()
            if self.on_status is not None:
                try:
                    self.on_status(frame)
                except Exception:  # the caller's bug must not end the link
                    log.exception("on_status handler failed")

    def _hand_odometry(self, frame: McuFrame, received_ns: int) -> None:
        try:
            sample = parse_odometry(frame)
        except FrameError as exc:
            self.stats.bad_odometry += 1
            self._note_error(f"odometry frame: {exc}")
            return
        self.stats.odometry_frames += 1
        if self.on_odometry is not None:
            try:
                self.on_odometry(sample, received_ns)
            except Exception:  # the caller's bug must not end the link
                log.exception("on_odometry handler failed")
        self._notify()

    def _note_error(self, message: str) -> None:
        # Logged once per distinct error: a missing port during back-off would otherwise flood the log.
        if message != self.stats.last_error:
            log.warning("MCU link: %s", message)
        self.stats.last_error = message
        self._notify()


def backoff_delays(initial_s: float, max_s: float) -> Iterator[float]:
    """initial, 2 x initial, 4 x initial ... capped at max_s, forever."""
    delay = initial_s
    while True:
        yield delay
        delay = min(delay * 2.0, max_s)
