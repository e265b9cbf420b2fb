"""``sara-app bench`` rows: the dashboard's scene update (Python side, no browser)."""

from __future__ import annotations

import itertools
from collections.abc import Iterator
from dataclasses import replace

from sara_app.dashboard.frame import DisplayFrame
from sara_app.dashboard.scene import VIEW_NAMES, demo_frame
from sara_app.errors import InputError


def bench_rows(n: int = 2000) -> list[tuple[str, float, float, str]]:
    """Scene update cost (Python side, no browser) for 1 human x 7 sets x 14 capsules and
    10 intervals x 8 links, with the robot moving and standing, in the default view (the
    effective set, the occupancy coloured by contact) and with every set shown; serves on
    127.0.0.1."""
    from sara_app.bench import timeit_us
    from sara_app.dashboard.viewer import Dashboard

    n = max(n // 10, 20)
    frames = [demo_frame(0.01 * i) for i in range(64)]
    standing = [replace(f, q=frames[0].q) for f in frames]
    dash = Dashboard()
    dash.start(port=8780)
    scene = dash.scene
    if scene is None:  # set by start()
        raise InputError("the dashboard started without a scene")
    rows = []
    try:
        for shown in ("default view", "every set shown"):
            if shown == "every set shown":  # as a browser that ticks every box
                for name in VIEW_NAMES:
                    scene.set_visible(name, True)
            for label, seq in (("robot moving", frames), ("robot standing", standing)):
                it = itertools.cycle(seq)

                def step(it: Iterator[DisplayFrame] = it) -> None:
                    scene.update(next(it))

                med, p99 = timeit_us(step, n, warmup=20)
                rows.append((f"dashboard scene update, {label}, {shown}", med, p99,
                             "1 human x 7 sets x 14, 10 x 8"))  # fmt: skip
        it = itertools.cycle(standing)
        med, p99 = timeit_us(lambda: dash.update(next(it)), n, warmup=20)
        rows.append(("dashboard update (scene + panels)", med, p99, "robot standing"))
    finally:
        dash.stop()
    return rows
