"""Stopping a process cleanly on Ctrl-C or `kill`: both signals set one event the process waits on, or (a
command without such a loop) `kill` raises in the main thread as Ctrl-C does."""
from __future__ import annotations

import logging
import signal
import threading

log = logging.getLogger(__name__)
_STOP_SIGNALS = (signal.SIGINT, signal.SIGTERM)


def stop_on_signals(stop: threading.Event | None = None) -> threading.Event:
    """Set `stop` (a new event when None) on SIGINT or SIGTERM, and return it.

    Python delivers signals to the main thread only, so elsewhere (a stage run inside a test's thread)
    nothing is installed and the caller's own stop path is the only one.
    """
    event = stop if stop is not None else threading.Event()
    if threading.current_thread() is not threading.main_thread():
        return event

    def request_stop(signum: int, _frame: object) -> None:
        log.info("signal %d: stopping", signum)
        event.set()

    for signum in _STOP_SIGNALS:
        signal.signal(signum, request_stop)
    return event


def terminate_as_interrupt() -> None:
    """`kill` (SIGTERM) ends the process as Ctrl-C does: KeyboardInterrupt in the main thread, so `finally`
    blocks run (a bench stops the router and stages it started instead of leaving them running). A later
    `stop_on_signals` replaces it; off the main thread nothing is installed."""
    if threading.current_thread() is not threading.main_thread():
        return

    def interrupt(signum: int, _frame: object) -> None:
        log.info("signal %d: interrupting", signum)
        raise KeyboardInterrupt

    signal.signal(signal.SIGTERM, interrupt)
