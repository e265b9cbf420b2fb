"""View settings per browser, in two real headless chromium instances on one dashboard: the
default view shows the robot (its pixels change when this browser hides it), and unticking a
set in one browser changes that browser's picture and settings only."""

from __future__ import annotations

import os
from collections.abc import Iterator

import numpy as np
import pytest
from browser import CHROMIUM, DevTools, blocks_apart, chromium_on, wait_for

from sara_app.bus.session import free_port
from sara_app.dashboard.frame import EFFECTIVE
from sara_app.dashboard.scene import DEFAULT_VISIBLE, demo_frame
from sara_app.dashboard.view import CHECKBOXES
from sara_app.dashboard.viewer import Dashboard

pytestmark = pytest.mark.skipif(
    not os.path.exists(CHROMIUM), reason=f"{CHROMIUM} is absent (apt-get install chromium)"
)
LABEL = dict(CHECKBOXES)
_CHECKBOX = (
    "document.getElementById([...document.querySelectorAll('label')]"
    ".find(l => l.textContent === {!r})?.htmlFor)"
)


# half the default camera's distance to what it looks at: the robot large in the picture
LOOK_AT = (0.4, 0.0, 0.6)
CAMERA = (1.15, -0.95, 1.1)


@pytest.fixture()
def dash() -> Iterator[Dashboard]:
    d = Dashboard(camera_position=CAMERA, camera_look_at=LOOK_AT)
    d.start(port=free_port())
    frame = demo_frame(1.0)
    frame.critical_pair = None
    d.update(frame)
    yield d
    d.stop()


def _untick(page: DevTools, name: str) -> None:
    """Click the checkbox of ``name`` (untick or tick it) until the browser's own box shows it
    flipped: a click while the panel still lays itself out (a loaded machine) can land beside
    the box, and is then tried again; a click that did flip it is never repeated."""
    box = _CHECKBOX.format(LABEL[name])
    was = bool(page.eval(f"{box}.checked"))
    for _ in range(5):
        page.click(box)
        try:
            wait_for(lambda: bool(page.eval(f"{box}.checked")) is not was, 3.0, f"{name} flipped")
            return
        except AssertionError:
            continue
    raise AssertionError(f"five clicks on {name!r} left its box as it was")


ROBOT_BLOCKS = 8  # what hiding the robot changes at least, seen from CAMERA


def test_two_browsers_keep_their_own_view_settings(dash: Dashboard) -> None:
    views = dash.views
    assert views is not None
    with chromium_on(str(dash.url)) as one, chromium_on(str(dash.url)) as two:
        wait_for(lambda: dash.client_count() == 2, 60.0, "both browsers to connect")
        # each browser's view settings are made in viser's connect callback, after it counts
        wait_for(lambda: len(views._browsers) == 2, 60.0, "both browsers' view settings")  # noqa: SLF001
        browsers = views._browsers  # noqa: SLF001 - which settings belong to whom is tested
        ids = sorted(browsers)
        wait_for(lambda: one.eval(_CHECKBOX.format(LABEL["robot"]) + " !== null"), 60.0,
                 "the view folder in browser one")  # fmt: skip
        for i in ids:
            assert views.shows(i) == DEFAULT_VISIBLE

        def sent(i: int, name: str, shown: bool) -> None:
            wait_for(lambda: browsers[i].frames[name].visible is shown, 30.0,
                     f"{name} {'shown' if shown else 'hidden'} sent to browser {i}")  # fmt: skip

        # Hiding the robot in browser one: exactly that browser's settings change.
        _untick(one, "robot")
        wait_for(lambda: any(not views.shows(i)["robot"] for i in ids), 30.0,
                 "browser one's untick to arrive")  # fmt: skip
        mine = [i for i in ids if not views.shows(i)["robot"]]
        assert len(mine) == 1, "exactly the clicking browser hid the robot"
        other = next(i for i in ids if i != mine[0])
        assert views.shows(other) == DEFAULT_VISIBLE
        assert dash.scene is not None and dash.scene.layers["robot"]  # still shown in two
        sent(mine[0], "robot", False)
        # The robot is visible in the default view: two's picture differs from one's by the
        # robot. This is also the evidence that two has drawn the robot's meshes (viser loads
        # them asynchronously, after the rest of the scene): its picture is final.
        hidden_one = one.settled_screenshot()
        default_two = two.screenshot_until(
            lambda im: blocks_apart(im, hidden_one) >= ROBOT_BLOCKS, 60.0,
            "the robot drawn in browser two", settled=True,
        )  # fmt: skip
        # Shown again in one: one's picture is two's (its meshes drawn too).
        _untick(one, "robot")
        sent(mine[0], "robot", True)
        default_one = one.screenshot_until(
            lambda im: blocks_apart(im, default_two) == 0, 60.0,
            "browser one's picture to be two's again", settled=True,
        )  # fmt: skip
        # Hidden in one again: one's picture changes by the robot; two's does not change.
        _untick(one, "robot")
        sent(mine[0], "robot", False)
        no_robot = one.screenshot_until(
            lambda im: blocks_apart(im, default_one) >= ROBOT_BLOCKS, 60.0,
            "the robot to vanish in browser one", settled=True,
        )  # fmt: skip
        assert blocks_apart(two.settled_screenshot(), default_two) == 0
        # One's effective set goes on its own too (the person stands outside this close view).
        _untick(one, EFFECTIVE)
        wait_for(lambda: not views.shows(mine[0])[EFFECTIVE], 30.0, "the untick to arrive")
        assert views.shows(other)[EFFECTIVE] and dash.scene.models[EFFECTIVE].visible
        sent(mine[0], EFFECTIVE, False)
        assert blocks_apart(two.settled_screenshot(), default_two) == 0
        # Hidden in both browsers: the set is no longer sent at all.
        _untick(two, EFFECTIVE)
        wait_for(lambda: not dash.scene.models[EFFECTIVE].visible, 30.0,  # type: ignore[union-attr]
                 "the effective set to be hidden for everybody")  # fmt: skip
        if os.environ.get("SARA_SCREENSHOT_DIR"):  # for looking at them by hand
            from PIL import Image

            for name, img in (("default", default_one), ("no_robot", no_robot)):
                path = os.path.join(os.environ["SARA_SCREENSHOT_DIR"], f"view_{name}.png")
                Image.fromarray(img.astype(np.uint8)).save(path)
