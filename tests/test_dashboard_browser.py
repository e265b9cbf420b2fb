"""The dashboard in a real browser: headless Debian chromium (software WebGL) loads the viser
page served on 127.0.0.1, connects, and renders the scene; screenshots over the DevTools
protocol show the occupancy in the verdict colour, and a new verdict changes it."""

from __future__ import annotations

import os
from collections.abc import Callable, Iterator

import numpy as np
import pytest
from browser import CHROMIUM, DevTools, chromium_on, wait_for

from sara_app.dashboard.frame import CONTACT_ENV, MODEL_NAMES
from sara_app.dashboard.scene import LAYERS, demo_frame
from sara_app.dashboard.viewer import Dashboard

pytestmark = pytest.mark.skipif(
    not os.path.exists(CHROMIUM), reason=f"{CHROMIUM} is absent (apt-get install chromium)"
)


@pytest.fixture()
def browser_on_dashboard() -> Iterator[tuple[Dashboard, DevTools]]:
    dash = Dashboard()
    url = dash.start(port=8720)
    for i in range(3):
        dash.update(demo_frame(0.1 * i, verified=True))
    try:
        with chromium_on(url) as devtools:
            yield dash, devtools
    finally:
        dash.stop()


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
    wait_for(lambda: dash.client_count() > 0, 60.0, "the browser to connect to viser")

    def shot_with(pred: Callable[[np.ndarray], bool]) -> np.ndarray | None:
        img = devtools.screenshot()
        return img if pred(img) else None

    # Verified: green occupancy (and no red, the critical-pair line is hidden).
    frame = demo_frame(1.0, verified=True)
    frame.critical_pair = None
    dash.update(frame)
    green = wait_for(lambda: shot_with(lambda im: _dominant(im, 1) > 500), 60.0, "green occupancy")
    assert isinstance(green, np.ndarray)
    assert green.reshape(-1, 3).std(axis=0).max() > 10.0  # not blank / uniform
    assert len(np.unique(green.reshape(-1, 3), axis=0)) > 100
    # Failsafe: the same capsules turn red.
    frame = demo_frame(1.0, verified=False)
    frame.critical_pair = None
    dash.update(frame)
    red = wait_for(
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
    pfl = wait_for(
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
    # The tracking gate's and the monitor's flags, and who breaks the bounds, in the status.
    frame.status = {**frame.status, "tracking": {"p1": {"bone": 3, "speed": 2}},
                    "violations": [{"human_id": "p1", "joint": "l_wrist", "quantity": "speed",
                                    "value": 3.25, "bound": 2.0}]}  # fmt: skip
    dash.update(frame)

    def tracking_text() -> str | None:
        text = str(devtools.call("Runtime.evaluate", expression="document.body.innerText",
                                 returnByValue=True)["result"]["value"])  # fmt: skip
        return text if "Beyond bounds" in text else None

    text = wait_for(tracking_text, 60.0, "the tracking rows in the status")
    assert "p1: bone 3, speed 2" in str(text) and "l_wrist speed 3.25 > 2.00 m/s" in str(text)
    # The URDF robot alone: everything else hidden, then the robot too; the images differ.
    scene = dash.scene
    assert scene is not None
    for name in (*MODEL_NAMES, *(n for n in LAYERS if n != "robot")):
        scene.set_visible(name, False)
    dash.update(frame)
    red_elsewhere = _dominant(green, 0) + 50  # e.g. the axes gizmo
    robot = wait_for(
        lambda: shot_with(lambda im: _dominant(im, 0) < red_elsewhere), 60.0, "capsules hidden"
    )
    scene.set_visible("robot", False)
    empty = wait_for(
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
