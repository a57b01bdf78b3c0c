"""The monitor page in a real headless browser (Debian's chromium), driven over the DevTools pipe.

`--remote-debugging-pipe` speaks the Chrome DevTools Protocol on file descriptors 3 and 4
(NUL-separated JSON), so the test needs no websocket library: it waits in the page for the published
values to appear (a MutationObserver, not a sleep), then takes a screenshot.
"""
from __future__ import annotations

import base64
import json
import os
import shutil
import subprocess
import threading
from pathlib import Path
from typing import Any

import cv2
import numpy as np
import pytest
from buskit import BusClient, free_port, start_router
from test_monitor import RobotPublisher, start_monitor, wait_state

pytestmark = pytest.mark.integration

CHROMIUM = shutil.which("chromium") or shutil.which("chromium-browser")
WIDTH, HEIGHT = 1280, 900


class DevToolsPipe:
    """A headless chromium and the DevTools Protocol over its debugging pipe."""

    def __init__(self, binary: str, profile: Path) -> None:
        to_browser_r, self._to_browser = os.pipe()
        self._from_browser, from_browser_w = os.pipe()

        def wire_fds() -> None:  # in the child: the browser reads fd 3 and writes fd 4
            os.dup2(to_browser_r, 3)
            os.dup2(from_browser_w, 4)

        self.process = subprocess.Popen(
            [binary, "--headless", "--no-sandbox", "--disable-gpu", "--disable-quic", "--no-first-run",
             "--disable-background-networking", "--disable-component-update", "--disable-sync",
             "--disable-dev-shm-usage", f"--window-size={WIDTH},{HEIGHT}", f"--user-data-dir={profile}",
             "--remote-debugging-pipe", "about:blank"],
            pass_fds=(3, 4), preexec_fn=wire_fds, stdin=subprocess.DEVNULL,
            stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
        os.close(to_browser_r)
        os.close(from_browser_w)
        self._next_id = 0
        self._replies: dict[int, dict[str, Any]] = {}
        self._events: list[dict[str, Any]] = []
        self._cond = threading.Condition()
        threading.Thread(target=self._read, daemon=True).start()

    def _read(self) -> None:
        buffer = b""
        while True:
            chunk = os.read(self._from_browser, 1 << 16)
            if not chunk:
                break
            buffer += chunk
            *messages, buffer = buffer.split(b"\0")
            with self._cond:
                for raw in messages:
                    message = json.loads(raw)
                    if "id" in message:
                        self._replies[message["id"]] = message
                    else:
                        self._events.append(message)
                self._cond.notify_all()
        with self._cond:
            self._cond.notify_all()

    def call(self, method: str, params: dict[str, Any] | None = None, session: str | None = None,
             timeout: float = 30.0) -> dict[str, Any]:
        self._next_id += 1
        ident = self._next_id
        message: dict[str, Any] = {"id": ident, "method": method, "params": params or {}}
        if session:
            message["sessionId"] = session
        os.write(self._to_browser, json.dumps(message).encode() + b"\0")
        with self._cond:
            if not self._cond.wait_for(lambda: ident in self._replies, timeout):
                raise AssertionError(f"chromium did not answer {method} within {timeout} s")
            reply = self._replies.pop(ident)
        if "error" in reply:
            raise AssertionError(f"{method}: {reply['error']}")
        return reply["result"]

    def wait_event(self, method: str, session: str, timeout: float = 30.0) -> dict[str, Any]:
        def found() -> dict[str, Any] | None:
            return next((e for e in self._events if e["method"] == method and e.get("sessionId") == session), None)
        with self._cond:
            if not self._cond.wait_for(lambda: found() is not None, timeout):
                raise AssertionError(f"no {method} within {timeout} s")
            return found()  # type: ignore[return-value]

    def open_page(self, url: str) -> str:
        target = self.call("Target.createTarget", {"url": "about:blank"})["targetId"]
        session = self.call("Target.attachToTarget", {"targetId": target, "flatten": True})["sessionId"]
        self.call("Page.enable", session=session)
        self.call("Page.navigate", {"url": url}, session=session)
        self.wait_event("Page.loadEventFired", session)
        return session

    def close(self) -> None:
        try:
            self.call("Browser.close", timeout=5)
            self.process.wait(10)
        except (AssertionError, OSError, subprocess.TimeoutExpired):
            self.process.kill()
            self.process.wait()
        finally:
            os.close(self._to_browser)


# Resolves once every expected text is on the page and the camera thumbnail has loaded.
WAIT_FOR_VALUES = """
new Promise((resolve, reject) => {
  const expected = %s;
  const read = () => Object.fromEntries(Object.keys(expected).map(id => {
    const el = document.getElementById(id); return [id, el ? el.textContent : null]; }));
  const img = document.getElementById('thumb');
  const done = () => { const now = read();
    return Object.keys(expected).every(id => now[id] === expected[id]) && img.complete && img.naturalWidth > 0; };
  const finish = () => resolve({texts: read(), thumbWidth: img.naturalWidth, status: document.getElementById('status').textContent});
  if (done()) return finish();
  const observer = new MutationObserver(() => { if (done()) { observer.disconnect(); finish(); } });
  observer.observe(document.body, {subtree: true, childList: true, characterData: true, attributes: true});
  img.addEventListener('load', () => { if (done()) { observer.disconnect(); finish(); } });
  setTimeout(() => { observer.disconnect(); reject(new Error('page shows ' + JSON.stringify(read()))); }, 20000);
})
"""


@pytest.mark.skipif(CHROMIUM is None, reason="chromium is not installed: apt-get install chromium (README, Development; .ci/run installs it)")
def test_page_shows_the_published_pose_and_is_screenshotted(tmp_path: Path) -> None:
    port = free_port()
    router = start_router(port)
    monitor, url = start_monitor(port)
    client = BusClient(port)
    browser: DevToolsPipe | None = None
    try:
        with RobotPublisher(client, 1.234, -0.567, 0.5):
            wait_state(url, lambda s: s["status"] == "live" and s["thumb"] is not None)
            assert CHROMIUM is not None
            browser = DevToolsPipe(CHROMIUM, tmp_path / "profile")
            session = browser.open_page(url)
            expected = {"pose-x": "1.23", "pose-y": "-0.57", "heading": "28.6", "rpm": "4321", "distance": "3.21",
                        "model": "model mlp-test v7", "robot-id": "robot1"}
            result = browser.call("Runtime.evaluate", {"expression": WAIT_FOR_VALUES % json.dumps(expected),
                                                       "awaitPromise": True, "returnByValue": True},
                                  session=session)
            assert "exceptionDetails" not in result, result
            shown = result["result"]["value"]
            assert shown["texts"] == expected
            assert shown["status"] == "live" and shown["thumbWidth"] == 320
            cells = browser.call("Runtime.evaluate", {
                "expression": "[...document.querySelectorAll('#stage-infer td')].map(td => td.textContent)",
                "returnByValue": True}, session=session)["result"]["value"]
            # The test publishes infer's health but holds no liveliness token: alive is "no".
            assert cells == ["infer", "no", "19.5", "1.25", "2.50", "3", "0"]
            png = base64.b64decode(browser.call("Page.captureScreenshot", {"format": "png"}, session=session)["data"])
    finally:
        if browser is not None:
            browser.close()
        client.close()
        assert monitor.stop() == 0, monitor.output()
        router.stop()
    shot = tmp_path / "monitor.png"
    shot.write_bytes(png)
    assert png[:8] == b"\x89PNG\r\n\x1a\n"
    image = cv2.imread(str(shot), cv2.IMREAD_COLOR)
    assert image is not None and image.shape[1] == WIDTH and image.shape[0] >= 600
    assert len(np.unique(image.reshape(-1, 3), axis=0)) > 50, "a drawn page, not a blank one"
    red = (image[:, :, 2] > 200) & (image[:, :, 1] < 90) & (image[:, :, 0] < 90)
    assert red.sum() > 100, "the robot marker (red) is drawn on the court"
