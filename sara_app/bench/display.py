"""The worker's display message for ``sara-app bench``: the occupancy message (every enabled
model's capsules per person, widened as verified, their effective set, the robot's capsules)
that the cell worker builds on its verification thread at 15 Hz, for 1 and 16 people (the
default ``inputs.max_people``) standing beside the robot's path in ``standing_beside_path``,
each measured twice (velocities known), at staggered times; and the dashboard's mesh of the
effective set's leg capsules cut at their height bound (:mod:`sara_app.geometry.capsule_mesh`)
for 1 and 16 upper-body people in ``bench_handover_upper``."""

from __future__ import annotations

from functools import partial

import numpy as np

from sara_app.bench import timeit_us
from sara_app.cell.build import Cell, build_cell
from sara_app.cell.intake import Track, take_measurement, track_for
from sara_app.dashboard.frame import EFFECTIVE
from sara_app.geometry.capsule_mesh import cut_capsule_mesh
from sara_app.human.scripted import joints, standing
from sara_app.runtime.display import occupancy_msg
from sara_app.scenario import load_scenario

Row = tuple[str, float, float, str]


def _people(cell: Cell, people: int, legs_measured: bool = True) -> list[Track]:
    """``people`` tracks standing beside the path, each measured twice, at staggered times."""
    tracks: list[Track] = []
    for i in range(people):
        tr = track_for(cell, f"p{i}")
        y = joints(standing((1.2 + 0.1 * (i % 4), -0.6 + 0.1 * (i // 4)), 0.3 * i))
        for k in range(2):
            take_measurement(cell, tr, 10.0 - 0.002 * i - 0.02 * (1 - k), y + 0.005 * k,
                             legs_measured=legs_measured)  # fmt: skip
        tracks.append(tr)
    return tracks


def bench_rows(n: int = 2000) -> list[Row]:
    """Median and p99 (us) of one occupancy message of 1 and of 16 people, and of the
    dashboard's cut leg capsules of 1 and 16 upper-body people."""
    cell = build_cell(load_scenario("standing_beside_path"))
    rows: list[Row] = []
    now = 10.01
    for people in (1, 16):
        tracks = _people(cell, people)
        res = cell.shield.cycle(now, [tr.state for tr in tracks])
        med, p99 = timeit_us(partial(occupancy_msg, cell, tracks, res, now, lambda: 0, _ignore),
                             max(n // 20, 50), warmup=10)  # fmt: skip
        models = "/".join(cell.shield.verifier.models)
        note = f"occupancy at 15 Hz on the loop's thread; models {models} + effective"
        rows.append((f"worker display message, {people} people", med, p99, note))
    cell = build_cell(load_scenario("bench_handover_upper"))
    for people in (1, 16):
        tracks = _people(cell, people, legs_measured=False)
        res = cell.shield.cycle(now, [tr.state for tr in tracks])
        occ = occupancy_msg(cell, tracks, res, now, lambda: 0, _ignore)
        sets = [h.models[EFFECTIVE] for h in occ.humans if EFFECTIVE in h.models]
        below = np.concatenate([s.cuts() for s in sets])
        cut = np.isfinite(below)
        arrays = [s.arrays() for s in sets]
        ends = np.concatenate([e for e, _ in arrays])[cut]
        radius = np.concatenate([r for _, r in arrays])[cut]
        mesh = partial(cut_capsule_mesh, ends, radius, below[cut])
        v, f = mesh()
        med, p99 = timeit_us(mesh, max(n // 20, 50), warmup=5)
        note = (f"{len(radius)} cut capsules: {(v.nbytes + f.nbytes) / 1e3:.0f} kB per frame "
                "sent at 15 Hz to each browser showing the set")  # fmt: skip
        who = "person" if people == 1 else "people"
        rows.append((f"dashboard cut leg sets, {people} upper-body {who}", med, p99, note))
    return rows


def _ignore(*_: object) -> None:
    """No error is expected here: a display message with an error is still timed."""
