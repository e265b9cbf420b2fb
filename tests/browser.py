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
