"""A headless Chromium driven over the DevTools protocol on a pipe (no network port, no extra package).

Chromium started with ``--remote-debugging-pipe`` reads JSON commands from its fd 3 and writes
replies and events to its fd 4, each message ended by a NUL byte.  That is all the replay tests
need: open a file:// page, evaluate JavaScript (awaiting promises), send real mouse input and take
a screenshot.
"""

from __future__ import annotations

import base64
import fcntl
import json
import os
import shutil
import subprocess
import tempfile
import time
from pathlib import Path
from typing import Any

CHROMIUM = Path(os.environ.get("FISHFMU_CHROMIUM") or shutil.which("chromium") or "/usr/bin/chromium")
"""Debian's package installs /usr/bin/chromium; FISHFMU_CHROMIUM names another build."""
FLAGS = ["--headless", "--no-sandbox", "--disable-gpu", "--disable-quic", "--no-first-run",
         "--disable-background-networking", "--disable-component-update", "--disable-sync",
         "--enable-unsafe-swiftshader", "--use-angle=swiftshader",   # WebGL2 in software
         "--hide-scrollbars", "--mute-audio", "--remote-debugging-pipe"]


class CdpError(RuntimeError):
    pass


def _pipe_to_fds_3_4(read_fd: int, write_fd: int) -> None:
    """In the child: the pipe ends on fds 3 and 4 (via high copies, in case they are 3 or 4 already).
    Python's own fds are close-on-exec, so only these and stdio reach Chromium."""
    r, w = fcntl.fcntl(read_fd, fcntl.F_DUPFD, 10), fcntl.fcntl(write_fd, fcntl.F_DUPFD, 10)
    os.dup2(r, 3)
    os.dup2(w, 4)
    os.close(r)
    os.close(w)


class Browser:
    """One headless Chromium with one page of ``width`` x ``height`` CSS pixels (device scale 1)."""

    def __init__(self, width: int = 1000, height: int = 600, executable: Path = CHROMIUM) -> None:
        self.profile = tempfile.mkdtemp(prefix="fishfmu-chromium-")
        to_browser_r, self._to_browser = os.pipe()
        self._from_browser, from_browser_w = os.pipe()
        self.proc = subprocess.Popen(
            [str(executable), *FLAGS, f"--user-data-dir={self.profile}", f"--window-size={width},{height}",
             "about:blank"],
            stdin=subprocess.DEVNULL, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL,
            close_fds=False, preexec_fn=lambda: _pipe_to_fds_3_4(to_browser_r, from_browser_w))
        os.close(to_browser_r)
        os.close(from_browser_w)
        self._buffer = b""
        self._next_id = 0
        self.session: str | None = None
        try:
            target = self.call("Target.createTarget", url="about:blank")["targetId"]
            self.session = self.call("Target.attachToTarget", targetId=target, flatten=True)["sessionId"]
            self.call("Page.enable")
            self.call("Emulation.setDeviceMetricsOverride", width=width, height=height, deviceScaleFactor=1,
                      mobile=False)
        except BaseException:
            self.close()
            raise

    # -- protocol -------------------------------------------------------------------------------
    def _read_message(self, deadline: float) -> dict[str, Any]:
        while b"\0" not in self._buffer:
            if time.monotonic() > deadline:
                raise CdpError("no answer from Chromium in time")
            chunk = os.read(self._from_browser, 1 << 20)
            if not chunk:
                raise CdpError("Chromium closed the pipe")
            self._buffer += chunk
        message, _, self._buffer = self._buffer.partition(b"\0")
        return json.loads(message)

    def call(self, method: str, timeout_s: float = 30.0, **params: Any) -> dict[str, Any]:
        """Send one command (to the page once attached) and wait for its reply; events are dropped."""
        self._next_id += 1
        msg: dict[str, Any] = {"id": self._next_id, "method": method, "params": params}
        if self.session is not None and not method.startswith("Target."):
            msg["sessionId"] = self.session
        os.write(self._to_browser, json.dumps(msg).encode() + b"\0")
        deadline = time.monotonic() + timeout_s
        while True:
            reply = self._read_message(deadline)
            if reply.get("id") == self._next_id:
                if "error" in reply:
                    raise CdpError(f"{method}: {reply['error']}")
                return reply.get("result", {})

    # -- what a test does -----------------------------------------------------------------------
    def open(self, url: str, ready_js: str | None = None, timeout_s: float = 30.0) -> None:
        """Load ``url``; then wait for the promise ``ready_js`` evaluates to (if given)."""
        self.call("Page.navigate", url=url)
        deadline = time.monotonic() + timeout_s
        while self.eval("document.readyState") != "complete":
            if time.monotonic() > deadline:
                raise CdpError(f"{url} did not load")
            time.sleep(0.05)
        if ready_js:
            self.eval(ready_js, timeout_s=timeout_s)

    def eval(self, expression: str, timeout_s: float = 30.0) -> Any:
        """The value of a JavaScript expression (awaited if it is a promise), as JSON."""
        r = self.call("Runtime.evaluate", timeout_s=timeout_s, expression=expression, awaitPromise=True,
                      returnByValue=True)
        if "exceptionDetails" in r:
            d = r["exceptionDetails"]
            raise CdpError(f"{expression[:80]}: {d.get('exception', {}).get('description', d.get('text'))}")
        return r["result"].get("value")

    def click(self, x: float, y: float) -> None:
        self.mouse_drag([(x, y)])

    def mouse_drag(self, points: list[tuple[float, float]], button: str = "left") -> None:
        """Press at the first point, move through the others, release at the last (a click if one)."""
        x, y = points[0]
        self.call("Input.dispatchMouseEvent", type="mouseMoved", x=x, y=y)
        self.call("Input.dispatchMouseEvent", type="mousePressed", x=x, y=y, button=button, clickCount=1)
        for x, y in points[1:]:
            self.call("Input.dispatchMouseEvent", type="mouseMoved", x=x, y=y, button=button)
        self.call("Input.dispatchMouseEvent", type="mouseReleased", x=x, y=y, button=button, clickCount=1)

    def centre_of(self, selector: str) -> tuple[float, float]:
        r = self.eval(f"(() => {{ const r = document.querySelector({json.dumps(selector)}).getBoundingClientRect();"
                      " return [r.left + r.width / 2, r.top + r.height / 2]; })()")
        return float(r[0]), float(r[1])

    def screenshot(self) -> bytes:
        """The page as PNG bytes."""
        return base64.b64decode(self.call("Page.captureScreenshot", format="png")["data"])

    def close(self) -> None:
        try:
            self.call("Browser.close", timeout_s=5.0)
        except (CdpError, OSError):
            pass
        try:
            self.proc.wait(timeout=10)
        except subprocess.TimeoutExpired:
            self.proc.kill()
            self.proc.wait()
        for fd in (self._to_browser, self._from_browser):
            os.close(fd)
        shutil.rmtree(self.profile, ignore_errors=True)

    def __enter__(self) -> "Browser":
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()
