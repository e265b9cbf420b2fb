"""The dashboard in a real browser: headless Debian chromium (software WebGL) loads the viser
page served on 127.0.0.1, connects, and renders the scene; screenshots over the DevTools
protocol show the occupancy in the verdict colour, and a new verdict changes it."""

from __future__ import annotations

import io
import json
import os
import shutil
import signal
import socket
import subprocess
import tempfile
import time
import urllib.request
from collections.abc import Callable, Iterator

import numpy as np
import pytest

from sara_app.bench_live import CHROMIUM_FLAGS
from sara_app.dashboard.frame import CONTACT_ENV, MODEL_NAMES
from sara_app.dashboard.scene import demo_frame
from sara_app.dashboard.viewer import Dashboard

CHROMIUM = "/usr/bin/chromium"
pytestmark = pytest.mark.skipif(
    not os.path.exists(CHROMIUM), reason=f"{CHROMIUM} is absent (apt-get install chromium)"
)
FLAGS = CHROMIUM_FLAGS


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


def _wait(cond: Callable[[], object], timeout_s: float, what: str) -> object:
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

        url = _wait(page_ws, 30.0, "the DevTools page target")
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

    def screenshot(self) -> np.ndarray:
        import base64

        from PIL import Image

        png = base64.b64decode(self.call("Page.captureScreenshot", format="png")["data"])
        return np.asarray(Image.open(io.BytesIO(png)).convert("RGB")).astype(int)

    def close(self) -> None:
        self.ws.close()


@pytest.fixture()
def browser_on_dashboard() -> Iterator[tuple[Dashboard, DevTools]]:
    dash = Dashboard()
    url = dash.start(port=8720)
    for i in range(3):
        dash.update(demo_frame(0.1 * i, verified=True))
    profile = tempfile.mkdtemp(prefix="sara-chromium-")
    port = _free_port()
    proc = subprocess.Popen(
        [CHROMIUM, *FLAGS, f"--user-data-dir={profile}", f"--remote-debugging-port={port}", url],
        stdout=subprocess.DEVNULL,
        stderr=subprocess.DEVNULL,
        start_new_session=True,
    )
    devtools = None
    try:
        devtools = DevTools(port)
        yield dash, devtools
    finally:
        if devtools is not None:
            devtools.close()
        os.killpg(proc.pid, signal.SIGTERM)  # the session this test started (chromium's children)
        try:
            proc.wait(timeout=10)
        except subprocess.TimeoutExpired:
            os.killpg(proc.pid, signal.SIGKILL)
            proc.wait(timeout=10)
        dash.stop()
        shutil.rmtree(profile, ignore_errors=True)


def _dominant(img: np.ndarray, channel: int, margin: int = 40) -> int:
    """Pixels whose ``channel`` exceeds both other channels by ``margin``."""
    others = [c for c in range(3) if c != channel]
    c = img[..., channel]
    return int(np.sum((c - img[..., others[0]] > margin) & (c - img[..., others[1]] > margin)))


def _magenta(img: np.ndarray, margin: int = 60) -> int:
    """Pixels whose red and blue both exceed green by ``margin``."""
    r, g, b = img[..., 0], img[..., 1], img[..., 2]
    return int(np.sum((r - g > margin) & (b - g > margin)))


def test_page_connects_and_renders_the_verdict(
    browser_on_dashboard: tuple[Dashboard, DevTools],
) -> None:
    dash, devtools = browser_on_dashboard
    _wait(lambda: dash.client_count() > 0, 60.0, "the browser to connect to viser")

    def shot_with(pred: Callable[[np.ndarray], bool]) -> np.ndarray | None:
        img = devtools.screenshot()
        return img if pred(img) else None

    # Verified: green occupancy (and no red, the critical-pair line is hidden).
    frame = demo_frame(1.0, verified=True)
    frame.critical_pair = None
    dash.update(frame)
    green = _wait(lambda: shot_with(lambda im: _dominant(im, 1) > 500), 60.0, "green occupancy")
    assert isinstance(green, np.ndarray)
    assert green.reshape(-1, 3).std(axis=0).max() > 10.0  # not blank / uniform
    assert len(np.unique(green.reshape(-1, 3), axis=0)) > 100
    # Failsafe: the same capsules turn red.
    frame = demo_frame(1.0, verified=False)
    frame.critical_pair = None
    dash.update(frame)
    red = _wait(
        lambda: shot_with(lambda im: _dominant(im, 0) > max(500, 2 * _dominant(green, 0))),
        60.0,
        "red occupancy",
    )
    assert isinstance(red, np.ndarray)
    assert _dominant(red, 1) < _dominant(green, 1)
    # PFL: every occupancy capsule clamped against the environment turns magenta.
    frame = demo_frame(1.0, verified=True)
    frame.critical_pair = None
    frame.contact_class = np.full(frame.robot_radius.shape, CONTACT_ENV, dtype=np.int8)
    dash.update(frame)
    pfl = _wait(
        lambda: shot_with(lambda im: _magenta(im) > max(500, 2 * _magenta(green))),
        60.0,
        "magenta (env-constrained) occupancy",
    )
    assert isinstance(pfl, np.ndarray) and _dominant(pfl, 1) < _dominant(green, 1)
    # The legend's colour swatches are rendered HTML, not escaped text.
    swatches = devtools.call(
        "Runtime.evaluate",
        expression="[[...document.querySelectorAll('span')].filter("
        "e => e.style.color === 'rgb(220, 0, 220)').length,"
        " document.body.innerText.includes('<span'), document.body.innerText.includes('■')]",
        returnByValue=True,
    )["result"]["value"]
    assert swatches == [1, False, True], swatches
    # The URDF robot alone: everything else hidden, then the robot too; the images differ.
    scene = dash.scene
    assert scene is not None
    for name in (*MODEL_NAMES, "occupancy", "skeletons", "contacts", "boxes", "critical_pair"):
        scene.set_visible(name, False)
    dash.update(frame)
    red_elsewhere = _dominant(green, 0) + 50  # e.g. the axes gizmo
    robot = _wait(
        lambda: shot_with(lambda im: _dominant(im, 0) < red_elsewhere), 60.0, "capsules hidden"
    )
    scene.set_visible("robot", False)
    empty = _wait(
        lambda: shot_with(lambda im: np.sum(np.abs(im - robot).sum(-1) > 60) > 1000),
        60.0,
        "the robot to disappear",
    )
    assert isinstance(robot, np.ndarray) and isinstance(empty, np.ndarray)
    if os.environ.get("SARA_SCREENSHOT_DIR"):  # for looking at them by hand
        from PIL import Image

        for name, img in (("verified", green), ("failsafe", red), ("pfl", pfl), ("robot", robot)):
            path = os.path.join(os.environ["SARA_SCREENSHOT_DIR"], f"dashboard_{name}.png")
            Image.fromarray(img.astype(np.uint8)).save(path)
