"""The dashboard in a real browser: headless Debian chromium (software WebGL) loads the viser
page served on 127.0.0.1, connects, and renders the scene; screenshots over the DevTools
protocol show the occupancy in the verdict colour, and a new verdict changes it."""

from __future__ import annotations

import os
from collections.abc import Iterator
from dataclasses import replace

import numpy as np
import pytest
from browser import CHROMIUM, DevTools, chromium_on, wait_for

from sara_app.bus.session import free_port
from sara_app.dashboard.frame import CONTACT_ENV, MODEL_NAMES
from sara_app.dashboard.scene import LAYERS, demo_frame
from sara_app.dashboard.viewer import Dashboard

pytestmark = pytest.mark.skipif(
    not os.path.exists(CHROMIUM), reason=f"{CHROMIUM} is absent (apt-get install chromium)"
)


@pytest.fixture()
def browser_on_dashboard() -> Iterator[tuple[Dashboard, DevTools]]:
    dash = Dashboard()
    url = dash.start(port=free_port())
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

    # Verified: green occupancy (and no red, the critical-pair line is hidden).
    frame = demo_frame(1.0, verified=True)
    frame.critical_pair = None
    dash.update(frame)
    green = devtools.screenshot_until(lambda im: _dominant(im, 1) > 500, 60.0, "green occupancy")
    assert green.reshape(-1, 3).std(axis=0).max() > 10.0  # not blank / uniform
    assert len(np.unique(green.reshape(-1, 3), axis=0)) > 100
    # Failsafe: the same capsules turn red.
    frame = demo_frame(1.0, verified=False)
    frame.critical_pair = None
    dash.update(frame)
    red = devtools.screenshot_until(
        lambda im: _dominant(im, 0) > max(500, 2 * _dominant(green, 0)),
        60.0,
        "red occupancy",
    )
    assert _dominant(red, 1) < _dominant(green, 1)
    # PFL: every occupancy capsule clamped against the environment turns magenta.
    frame = demo_frame(1.0, verified=True)
    frame.critical_pair = None
    frame.contact_class = np.full(frame.robot_radius.shape, CONTACT_ENV, dtype=np.int8)
    dash.update(frame)
    pfl = devtools.screenshot_until(
        lambda im: _magenta(im) > max(500, 2 * _magenta(green)),
        60.0,
        "magenta (env-constrained) occupancy",
    )
    assert _dominant(pfl, 1) < _dominant(green, 1)
    # The legend's colour swatches are rendered HTML, not escaped text.
    swatches = devtools.call(
        "Runtime.evaluate",
        expression="[[...document.querySelectorAll('span')].filter("
        "e => e.style.color === 'rgb(220, 0, 220)').length,"
        " document.body.innerText.includes('<span'), document.body.innerText.includes('■')]",
        returnByValue=True,
    )["result"]["value"]
    assert swatches == [1, False, True], swatches
    # Tracking as it stands and who breaks the bounds in the status; the totals folded away.
    now = {
        "p1": {
            "held": [{"joint": "l_wrist", "flag": "bone", "for_s": 0.25}],
            "last_flag": {"joint": "l_wrist", "flag": "bone", "ago_s": 0.0},
        }
    }
    frame.status = {**frame.status, "tracking": {"p1": {"bone": 3, "speed": 2}},
                    "tracking_now": now,
                    "violations": [{"human_id": "p1", "joint": "l_wrist", "quantity": "speed",
                                    "value": 3.25, "bound": 2.0}]}  # fmt: skip
    dash.update(frame)

    def tracking_text() -> str | None:
        text = str(devtools.call("Runtime.evaluate", expression="document.body.innerText",
                                 returnByValue=True)["result"]["value"])  # fmt: skip
        return text if "Beyond bounds" in text else None

    text = wait_for(tracking_text, 60.0, "the tracking rows in the status")
    assert "held: l_wrist (bone length off, 0.2 s)" in str(text), text
    assert "l_wrist speed 3.25 > 2.00 m/s" in str(text) and "bone 3" not in str(text)
    assert "Tracking flag totals" in str(text)
    # The URDF robot alone: everything else hidden, then the robot too; the images differ.
    scene = dash.scene
    assert scene is not None
    for name in (*MODEL_NAMES, *(n for n in LAYERS if n != "robot")):
        scene.set_visible(name, False)
    dash.update(frame)
    red_elsewhere = _dominant(green, 0) + 50  # e.g. the axes gizmo
    robot = devtools.screenshot_until(
        lambda im: _dominant(im, 0) < red_elsewhere, 60.0, "capsules hidden"
    )
    scene.set_visible("robot", False)
    empty = devtools.screenshot_until(
        lambda im: np.sum(np.abs(im - robot).sum(-1) > 60) > 1000,
        60.0,
        "the robot to disappear",
    )
    # A set cut at a height bound (legs an upper-body tracker does not measure) is drawn as a
    # mesh ending flat at the cut: the same capsule cut through its middle keeps its bottom
    # and loses its top part in the image.
    scene.set_visible("effective", True)
    h = frame.humans[0]
    one = {"effective": (np.array([[[0.3, -0.6, 0.3], [0.3, -0.6, 0.9]]]), np.array([0.35]))}

    def rows(im: np.ndarray) -> tuple[int, int] | None:
        """First and last image row with at least 8 pixels of the set's warm tint (red over
        blue; the grid is grey) in the 3D view, right of the axes gizmo and left of the
        panel; None: none."""
        view = im[:, 100:540]
        r = np.flatnonzero((view[..., 0] - view[..., 2] >= 4).sum(axis=1) >= 8)
        return (int(r[0]), int(r[-1])) if r.size else None

    last: list[np.ndarray] = [empty]

    def settled(im: np.ndarray) -> bool:
        """The same image twice in a row (the scene drawn, not on its way)."""
        same = bool(np.array_equal(im, last[-1]))
        last.append(im)
        return same and rows(im) is not None

    dash.update(replace(frame, humans=[replace(h, models=one, cuts={})]))
    whole = devtools.screenshot_until(settled, 60.0, "the capsule")
    top, bottom = rows(whole) or (0, 0)
    assert bottom - top > 40
    cuts = {"effective": np.array([0.6])}
    dash.update(replace(frame, humans=[replace(h, models=one, cuts=cuts)]))

    def cut_shown(im: np.ndarray) -> bool:
        r = rows(im)
        return r is not None and r[0] > top + 0.25 * (bottom - top) and abs(r[1] - bottom) <= 4

    cut = devtools.screenshot_until(cut_shown, 60.0, "the capsule cut at its middle")
    if os.environ.get("SARA_SCREENSHOT_DIR"):  # for looking at them by hand
        from PIL import Image

        for name, img in (("verified", green), ("failsafe", red), ("pfl", pfl), ("robot", robot),
                          ("whole", whole), ("cut", cut)):  # fmt: skip
            path = os.path.join(os.environ["SARA_SCREENSHOT_DIR"], f"dashboard_{name}.png")
            Image.fromarray(img.astype(np.uint8)).save(path)


def test_the_3d_view_says_the_verdict_in_words(
    browser_on_dashboard: tuple[Dashboard, DevTools],
) -> None:
    """The banner above the tabs: moving, slowed (by whom), braking (which person and body
    part, how close) and fault (which input, what to do), each in its colour, from the verdict
    message as the live bridge turns it into the frame's status."""
    from sara_app.bus.messages import VerdictMsg
    from sara_app.dashboard.from_messages import verdict_status

    dash, devtools = browser_on_dashboard
    wait_for(lambda: dash.client_count() > 0, 60.0, "the browser to connect to viser")
    banner = "document.querySelector('.sara-verdict')"
    base = {"seq": 1, "stamp_s": 1.0, "cell": "c", "safety_mode": "ssm", "cycle_time_us": 80.0,
            "min_distance_m": 0.42}  # fmt: skip
    states = [
        ({"mode": "intended"}, "moving", "Moving on its verified path (SSM), 0.42 m"),
        ({"mode": "intended", "intervened": True, "speed_scale": 0.3, "blocking": ["p1 l_hand"]},
         "slowed", "slowed to 30 % of its speed by SSM: p1's left hand, 0.42 m"),
        ({"mode": "failsafe", "blocking": ["p1 head"]}, "braking",
         "Braking along the verified stop (SSM): p1's head, 0.42 m"),
        ({"mode": "fault", "faults": ["p1: no skeleton for 0.2 s"]}, "fault",
         "Fault: p1: no skeleton for 0.2 s. The robot holds its verified stop; check that the "
         "tracker runs"),
    ]  # fmt: skip
    for fields, state, text in states:
        frame = demo_frame(1.0, verified=state != "braking")
        status = verdict_status(VerdictMsg(**{**base, **fields}), np.array([80.0]))
        frame.status = {**frame.status, **status}
        dash.update(frame)

        def shown(s: str = state) -> str | None:
            got = devtools.call(
                "Runtime.evaluate",
                returnByValue=True,
                expression=f"{banner} && [{banner}.dataset.state, "
                f"{banner}.textContent, getComputedStyle({banner}).backgroundColor]",
            )
            value = got["result"].get("value")  # fmt: skip
            return value if value and value[0] == s else None

        got = wait_for(shown, 60.0, f"the {state} banner")
        assert isinstance(got, list) and text in got[1], got
        if os.environ.get("SARA_SCREENSHOT_DIR"):  # docs/images
            from PIL import Image

            path = os.path.join(os.environ["SARA_SCREENSHOT_DIR"], f"banner_{state}.png")
            Image.fromarray(devtools.screenshot().astype(np.uint8)).save(path)
    assert got[2] == "rgb(185, 28, 28)"  # the fault's red
