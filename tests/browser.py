"""Headless Debian chromium driven over the DevTools protocol, for the tests that check the
dashboard in a real browser (never a browser downloaded by a test tool)."""

from __future__ import annotations

import io
import json
import subprocess
import tempfile
import time
import urllib.request
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from typing import Any

import numpy as np

from sara_app.bus.session import free_port
from sara_app.ops.chromium import CHROMIUM_FLAGS, chromium_environment, stop_chromium

CHROMIUM = "/usr/bin/chromium"
FLAGS = CHROMIUM_FLAGS


def wait_for(cond: Callable[[], object], timeout_s: float, what: str) -> object:
    t_end = time.monotonic() + timeout_s
    while time.monotonic() < t_end:
        value = cond()
        if value is not None and value is not False:
            return value
        time.sleep(0.2)
    raise AssertionError(f"timed out after {timeout_s} s waiting for {what}")


BLOCK_PX = 16
BLOCK_APART = 45  # sum over R, G, B of the difference of two blocks' mean colours


def blocks_apart(a: np.ndarray, b: np.ndarray) -> int:
    """How many 16 x 16 pixel blocks of the scene region (below the WebGL notice, left of the
    panel) differ in mean colour. Not single pixels: viser lowers a page's resolution whenever
    its frame rate drops (software WebGL, more so under load), which moves lines and edges by a
    pixel or two all over an unchanged scene (a CI run saw 22 766 pixels apart in the browser
    whose picture must not change) but moves no block's mean colour by more than about 20."""

    def coarse(img: np.ndarray) -> np.ndarray:
        region = img[150:454, :528]
        h, w = region.shape[0] // BLOCK_PX, region.shape[1] // BLOCK_PX
        return region.reshape(h, BLOCK_PX, w, BLOCK_PX, 3).mean(axis=(1, 3))

    return int(np.sum(np.abs(coarse(a) - coarse(b)).sum(-1) > BLOCK_APART))


class DevTools:
    """Minimal Chrome DevTools protocol client on one page target."""

    def __init__(self, port: int) -> None:
        from websockets.sync.client import connect

        def page_ws() -> str | None:
            try:
                with urllib.request.urlopen(f"http://127.0.0.1:{port}/json/list", timeout=2) as r:
                    targets = json.load(r)
            except OSError:
                return None
            pages = [t for t in targets if t.get("type") == "page"]
            return pages[0]["webSocketDebuggerUrl"] if pages else None

        url = wait_for(page_ws, 30.0, "the DevTools page target")
        self.ws = connect(str(url), max_size=None, open_timeout=10)
        self._id = 0

    def call(self, method: str, **params: object) -> dict:
        self._id += 1
        self.ws.send(json.dumps({"id": self._id, "method": method, "params": params}))
        while True:
            msg = json.loads(self.ws.recv(timeout=30))
            if msg.get("id") == self._id:
                if "error" in msg:
                    raise AssertionError(f"{method}: {msg['error']}")
                return msg["result"]

    def eval(self, expression: str) -> Any:
        """The value of a JavaScript expression in the page."""
        result = self.call("Runtime.evaluate", expression=expression, returnByValue=True)
        return result["result"].get("value")

    def click(self, element_js: str) -> None:
        """A real mouse click at the centre of the element ``element_js`` evaluates to."""
        rect = self.eval(
            f"(() => {{ const e = ({element_js}); e.scrollIntoView({{block: 'center'}});"
            " const r = e.getBoundingClientRect();"
            " return [r.x + r.width / 2, r.y + r.height / 2]; })()"
        )
        for kind in ("mousePressed", "mouseReleased"):
            self.call(
                "Input.dispatchMouseEvent",
                type=kind,
                x=rect[0],
                y=rect[1],
                button="left",
                clickCount=1,
            )

    def type_text(self, element_js: str, text: str) -> None:
        """Click into the input ``element_js`` evaluates to and type ``text``."""
        self.click(element_js)
        self.call("Input.insertText", text=text)

    def screenshot(self) -> np.ndarray:
        import base64

        from PIL import Image

        png = base64.b64decode(self.call("Page.captureScreenshot", format="png")["data"])
        return np.asarray(Image.open(io.BytesIO(png)).convert("RGB")).astype(int)

    def settled_screenshot(self, timeout_s: float = 30.0) -> np.ndarray:
        """A screenshot once two in a row agree in every 16 px block (the scene has caught up
        with what it was sent)."""
        last = [self.screenshot()]

        def same() -> np.ndarray | None:
            img = self.screenshot()
            ok = blocks_apart(img, last[0]) == 0
            last[0] = img
            return img if ok else None

        return wait_for(same, timeout_s, "the picture to settle")  # type: ignore[return-value]

    def screenshot_until(
        self, ok: Callable[[np.ndarray], bool], timeout_s: float, what: str, settled: bool = False
    ) -> np.ndarray:
        """The first screenshot (``settled``: the first settled one) for which ``ok`` holds,
        taken again until ``timeout_s``; an AssertionError naming ``what`` after that."""

        def check() -> np.ndarray | None:
            img = self.settled_screenshot() if settled else self.screenshot()
            return img if ok(img) else None

        return wait_for(check, timeout_s, what)  # type: ignore[return-value]

    def close(self) -> None:
        self.ws.close()


@contextmanager
def chromium_on(url: str) -> Iterator[DevTools]:
    """A headless chromium showing ``url`` (its own profile, stopped with its children)."""
    profile = tempfile.mkdtemp(prefix="sara-chromium-")
    port = free_port()
    proc = subprocess.Popen(
        [CHROMIUM, *FLAGS, f"--user-data-dir={profile}", f"--remote-debugging-port={port}", url],
        stdout=subprocess.DEVNULL,
        stderr=subprocess.DEVNULL,
        start_new_session=True,
        env=chromium_environment(profile),  # its temporary files go with the profile
    )
    devtools = None
    try:
        devtools = DevTools(port)
        yield devtools
    finally:
        if devtools is not None:
            devtools.close()
        stop_chromium(proc, profile)  # with its children, then its profile
