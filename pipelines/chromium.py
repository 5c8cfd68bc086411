"""Screenshots of a web page in headless chromium, taken once the page is drawn.

Chromium runs headless with software WebGL (SwiftShader) in a fresh profile and is driven over the
DevTools protocol (CDP, a websocket; the port chromium picked is read from the profile's
DevToolsActivePort file). A shot is:

    open the page in a new tab (viewport exactly `size`)
    drawn(seconds left)                 the caller's own signal, e.g. the viser client applied every message
    capture every CAPTURE_GAP_S until STILL_CAPTURES captures in a row are identical
                                        (what the page decodes after its messages: image textures, fonts)
    write the last capture to PNG (atomically)

so what is shot is the page at rest, however long a busy machine takes to get there (at most
`timeout` seconds, then one SeeUError line). The page is not told the WebGL renderer's name (the
WEBGL_debug_renderer_info extension is hidden), so it shows no "software rendering" notice: SwiftShader
is our choice here, not the user's browser's.

Example:
    from pathlib import Path
    from pipelines.chromium import Chromium

    with Chromium((1000, 700)) as browser:
        browser.shoot("http://127.0.0.1:8080", Path("page.png"))
"""

from __future__ import annotations

import base64
import itertools
import json
import shutil
import subprocess
import tempfile
import time
from collections import deque
from collections.abc import Callable
from pathlib import Path
from typing import Any

from seeu_data.errors import SeeUError

CAPTURE_GAP_S = 0.3  # between two captures of the page
STILL_CAPTURES = 3  # identical captures in a row: the page is at rest
SHOT_TIMEOUT_S = 240.0  # a shot that takes longer fails (a busy 2-core machine needs ~40 s)
START_TIMEOUT_S = 60.0  # chromium's start, until its DevTools port is known
# the page sees no WebGL renderer name (the renderer is SwiftShader by our choice, nothing to warn of)
HIDE_RENDERER_NAME = """
for (const gl of [WebGLRenderingContext, WebGL2RenderingContext]) {
  const getExtension = gl.prototype.getExtension;
  gl.prototype.getExtension = function (name) {
    return name === "WEBGL_debug_renderer_info" ? null : getExtension.call(this, name);
  };
}
"""


def chromium_exe() -> str:
    """The chromium executable on PATH; SeeUError naming the install command when there is none."""
    exe = shutil.which("chromium") or shutil.which("chromium-browser")
    if exe is None:
        raise SeeUError("chromium not found: install it (apt-get install chromium) to take screenshots")
    return exe


class Chromium:
    """Headless chromium, one tab per `shoot`; a context manager (the browser ends on exit)."""

    def __init__(self, size: tuple[int, int]):
        self.size = size  # (width, height) px of every page
        self.ids = itertools.count(1)
        self.events: list[dict] = []  # CDP events received while waiting for something else

    def __enter__(self) -> Chromium:
        from websockets.sync.client import connect

        exe = chromium_exe()
        self.profile = Path(tempfile.mkdtemp(prefix="seeu-chromium-"))
        log = (self.profile / "stderr.log").open("w")
        argv = [
            exe,
            "--headless",
            "--no-sandbox",  # as root (CI containers) chromium refuses to start with its sandbox
            "--use-angle=swiftshader",
            "--enable-unsafe-swiftshader",
            "--hide-scrollbars",
            "--remote-debugging-port=0",
            f"--user-data-dir={self.profile}",
            "about:blank",
        ]
        self.proc = subprocess.Popen(argv, stdin=subprocess.DEVNULL, stdout=subprocess.DEVNULL, stderr=log)
        log.close()
        try:
            self.ws = connect(self.devtools_url(), max_size=None, open_timeout=START_TIMEOUT_S)
        except BaseException:
            self.close()
            raise
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    def devtools_url(self) -> str:
        """ws://... of the browser, from DevToolsActivePort (port, then path) once chromium wrote it."""
        port_file = self.profile / "DevToolsActivePort"
        end = time.monotonic() + START_TIMEOUT_S
        while time.monotonic() < end:
            lines = port_file.read_text().split() if port_file.is_file() else []
            if len(lines) == 2:
                return f"ws://127.0.0.1:{lines[0]}{lines[1]}"
            if self.proc.poll() is not None:
                break
            time.sleep(0.05)
        tail = (self.profile / "stderr.log").read_text(errors="replace").strip()[-300:]
        raise SeeUError(f"chromium did not start (exit {self.proc.poll()}): {tail}")

    def close(self) -> None:
        from seeu_data.interrupts import end_process

        if hasattr(self, "ws"):
            self.ws.close()
        end_process(self.proc)
        shutil.rmtree(self.profile, ignore_errors=True)

    def call(self, method: str, session: str | None = None, timeout: float = SHOT_TIMEOUT_S, **params: Any) -> dict:
        """Send one CDP command (to the browser, or to a tab's `session`) and return its result."""
        ident = next(self.ids)
        message: dict[str, Any] = {"id": ident, "method": method, "params": params}
        if session is not None:
            message["sessionId"] = session
        self.ws.send(json.dumps(message))
        reply = self.receive(lambda m: m.get("id") == ident, method, timeout)
        if "error" in reply:
            raise SeeUError(f"chromium: {method}: {reply['error'].get('message')}")
        return reply.get("result", {})

    def receive(self, wanted: Callable[[dict], bool], what: str, timeout: float) -> dict:
        """The first message `wanted` accepts: an event kept from before, or the next one to come
        (events on the way are kept, replies to others dropped)."""
        for i, event in enumerate(self.events):
            if wanted(event):
                return self.events.pop(i)
        end = time.monotonic() + timeout
        while True:
            try:
                message = json.loads(self.ws.recv(timeout=max(end - time.monotonic(), 0.0)))
            except TimeoutError:
                raise SeeUError(f"chromium: no {what} within {timeout:.0f} s") from None
            if wanted(message):
                return message
            if "method" in message:
                self.events.append(message)

    def shoot(
        self, url: str, png: Path, drawn: Callable[[float], None] | None = None, timeout: float = SHOT_TIMEOUT_S
    ) -> None:
        """Open `url` in a new tab, wait until it is drawn (`drawn(seconds left)` returns, then
        STILL_CAPTURES identical captures in a row) and write the last capture to `png`."""
        from seeu_data.store.arrow_io import atomic_write_bytes

        end = time.monotonic() + timeout
        self.events.clear()
        target = self.call("Target.createTarget", url="about:blank")["targetId"]
        try:
            tab = self.call("Target.attachToTarget", targetId=target, flatten=True)["sessionId"]
            width, height = self.size
            self.call(
                "Emulation.setDeviceMetricsOverride", tab, width=width, height=height, deviceScaleFactor=1, mobile=False
            )
            self.call("Page.enable", tab)  # without it the script below is not run
            self.call("Page.addScriptToEvaluateOnNewDocument", tab, source=HIDE_RENDERER_NAME)
            self.call("Page.navigate", tab, url=url)
            loaded = lambda m: m.get("method") == "Page.loadEventFired" and m.get("sessionId") == tab  # noqa: E731
            self.receive(loaded, "page load", max(end - time.monotonic(), 0.0))
            if drawn is not None:
                drawn(max(end - time.monotonic(), 0.0))
            captures: deque[bytes] = deque(maxlen=STILL_CAPTURES)
            while len(captures) < STILL_CAPTURES or len(set(captures)) > 1:
                if time.monotonic() > end:
                    raise SeeUError(f"the page did not come to rest within {timeout:.0f} s", url)
                if captures:
                    time.sleep(CAPTURE_GAP_S)
                shot = self.call("Page.captureScreenshot", tab, timeout=max(end - time.monotonic(), 1.0), format="png")
                captures.append(base64.b64decode(shot["data"]))
        finally:
            self.call("Target.closeTarget", targetId=target)
        png.parent.mkdir(parents=True, exist_ok=True)
        atomic_write_bytes(png, captures[-1])
