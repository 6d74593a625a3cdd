"""A headless Chromium driven over the DevTools protocol on a pipe (no Python dependency, no
port): load a page, collect its console errors and uncaught exceptions, take screenshots.

The flags keep it off the network (a closed network makes Chromium wait on connections) and
let WebGL draw without a GPU (SwiftShader, a CPU renderer)."""

from __future__ import annotations

import base64
import contextlib
import fcntl
import json
import os
import shutil
import subprocess
import tempfile
import threading
import time
from pathlib import Path

import numpy as np

CHROMIUM_NAMES = ("chromium", "chromium-browser", "google-chrome")
FLAGS = (
    "--headless",
    "--no-sandbox",  # tests run as root in CI, where the sandbox refuses to start
    "--disable-gpu",
    "--enable-unsafe-swiftshader",
    "--use-angle=swiftshader",
    "--disable-quic",
    "--no-first-run",
    "--disable-background-networking",
    "--disable-component-update",
    "--disable-sync",
    "--remote-debugging-pipe",
)


def find_chromium() -> str | None:
    for name in CHROMIUM_NAMES:
        path = shutil.which(name)
        if path:
            return path
    return None


class BrowserError(RuntimeError):
    pass


class HeadlessChromium:
    """One browser with one page of `width` x `height` CSS pixels (device scale 1). The
    DevTools pipe is Chromium's fds 3 (commands in) and 4 (replies and events out)."""

    def __init__(self, executable: str, width: int = 800, height: int = 600) -> None:
        self.profile = tempfile.mkdtemp(prefix="chromium-profile-")
        to_browser_r, self._to_browser = os.pipe()
        self._from_browser, from_browser_w = os.pipe()

        def child_fds() -> None:
            # Through fds above 4 first: a pipe end that already is fd 3 or 4 would keep its
            # close-on-exec flag (dup2 onto itself changes nothing).
            high = [fcntl.fcntl(fd, fcntl.F_DUPFD, 10) for fd in (to_browser_r, from_browser_w)]
            os.dup2(high[0], 3)
            os.dup2(high[1], 4)

        self.process = subprocess.Popen(
            [
                executable,
                *FLAGS,
                f"--user-data-dir={self.profile}",
                f"--window-size={width},{height}",
            ],
            stdin=subprocess.DEVNULL,
            stdout=subprocess.DEVNULL,
            stderr=None if os.environ.get("CHROMIUM_STDERR") else subprocess.DEVNULL,
            close_fds=False,
            preexec_fn=child_fds,
        )
        os.close(to_browser_r)
        os.close(from_browser_w)
        self._next_id = 0
        self._replies: dict[int, dict] = {}
        self._changed = threading.Condition()
        self.events: list[dict] = []
        self._reader = threading.Thread(target=self._read, daemon=True)
        self._reader.start()
        target = self.call("Target.createTarget", url="about:blank")["targetId"]
        self.session = self.call("Target.attachToTarget", targetId=target, flatten=True)[
            "sessionId"
        ]
        for domain in ("Page", "Runtime", "Log"):
            self.call(f"{domain}.enable", session=self.session)
        self.call(
            "Emulation.setDeviceMetricsOverride",
            session=self.session,
            width=width,
            height=height,
            deviceScaleFactor=1,
            mobile=False,
        )

    def _read(self) -> None:
        buffer = b""
        while True:
            try:
                chunk = os.read(self._from_browser, 1 << 16)
            except OSError:
                chunk = b""
            if not chunk:
                with self._changed:
                    self._replies[-1] = {"error": {"message": "the browser closed"}}
                    self._changed.notify_all()
                return
            buffer += chunk
            *messages, buffer = buffer.split(b"\0")
            with self._changed:
                for raw in messages:
                    message = json.loads(raw)
                    if "id" in message:
                        self._replies[message["id"]] = message
                    else:
                        self.events.append(message)
                self._changed.notify_all()

    def call(self, method: str, session: str | None = None, timeout_s: float = 30.0, **params):
        self._next_id += 1
        key = self._next_id
        message = {"id": key, "method": method, "params": params}
        if session:
            message["sessionId"] = session
        os.write(self._to_browser, json.dumps(message).encode() + b"\0")
        deadline = time.monotonic() + timeout_s
        with self._changed:
            while key not in self._replies and -1 not in self._replies:
                if not self._changed.wait(deadline - time.monotonic()):
                    raise BrowserError(f"{method}: no reply in {timeout_s} s")
            reply = self._replies.pop(key, None) or self._replies[-1]
        if "error" in reply:
            raise BrowserError(f"{method}: {reply['error']}")
        return reply["result"]

    def open(self, url: str, timeout_s: float = 60.0) -> None:
        """Navigate and wait for the page's load event (its scripts have run)."""
        with self._changed:
            start = len(self.events)
        self.call("Page.navigate", session=self.session, url=url)
        deadline = time.monotonic() + timeout_s
        with self._changed:
            while not any(e.get("method") == "Page.loadEventFired" for e in self.events[start:]):
                if not self._changed.wait(max(0.0, deadline - time.monotonic())):
                    raise BrowserError(f"{url}: not loaded in {timeout_s} s")

    def screenshot(self) -> np.ndarray:
        """The page as an (H, W, 3) uint8 RGB image."""
        import cv2

        data = self.call("Page.captureScreenshot", session=self.session, format="png")["data"]
        bgr = cv2.imdecode(np.frombuffer(base64.b64decode(data), np.uint8), cv2.IMREAD_COLOR)
        return bgr[:, :, ::-1].copy()

    def wait_for(self, accept, timeout_s: float, period_s: float = 0.5) -> np.ndarray:
        """Screenshots until `accept(image)` holds (the last one is returned either way)."""
        deadline = time.monotonic() + timeout_s
        while True:
            image = self.screenshot()
            if accept(image) or time.monotonic() > deadline:
                return image
            time.sleep(period_s)

    def errors(self) -> list[str]:
        """Console errors, uncaught exceptions and error log entries so far."""
        out = []
        with self._changed:
            events = list(self.events)
        for e in events:
            method, p = e.get("method"), e.get("params", {})
            if method == "Runtime.consoleAPICalled" and p.get("type") in ("error", "assert"):
                out.append(" ".join(str(a.get("value", a.get("description"))) for a in p["args"]))
            elif method == "Runtime.exceptionThrown":
                details = p["exceptionDetails"]
                out.append(details.get("exception", {}).get("description", details["text"]))
            elif method == "Log.entryAdded" and p["entry"]["level"] == "error":
                out.append(p["entry"]["text"])
        return out

    def close(self) -> None:
        with contextlib.suppress(BrowserError):
            self.call("Browser.close", timeout_s=5.0)
        try:
            self.process.wait(timeout=10)
        except subprocess.TimeoutExpired:
            self.process.kill()
            self.process.wait()
        for fd in (self._to_browser, self._from_browser):
            with contextlib.suppress(OSError):
                os.close(fd)
        shutil.rmtree(self.profile, ignore_errors=True)

    def __enter__(self) -> HeadlessChromium:
        return self

    def __exit__(self, *exc) -> None:
        self.close()


def file_url(path: Path) -> str:
    return Path(path).resolve().as_uri()
