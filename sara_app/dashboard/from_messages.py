"""Bus messages to display: a verdict's status entries, an occupancy message's humans, robot
occupancy, PFL contact classes, body parts in contact, link energies and the JSSA state, filled
into a :class:`DisplayFrame` (no bus, no viser: pure functions of the messages)."""

from __future__ import annotations

from typing import Any

import numpy as np

from sara_app.bus.messages import (
    ContactMsg,
    HumanOccupancyMsg,
    JssaMsg,
    LinkEnergyMsg,
    OccupancyMsg,
    StatusMsg,
    VerdictMsg,
)
from sara_app.bus.verdict_words import verdict_words
from sara_app.dashboard.frame import (
    CONTACT_CODES,
    ContactParts,
    DisplayFrame,
    EnvBoxes,
    HumanDisplay,
    LinkEnergy,
)
from sara_app.dashboard.tracking_text import tracking_now_status
from sara_app.geometry.poses import box_arrays
from sara_app.human.skeleton import skeleton
from sara_app.scenario import Scenario

BONES = skeleton("full").part_joints[
    skeleton("full").part_joints[:, 0] != skeleton("full").part_joints[:, 1]
]


PART_RADIUS_M = 0.07
"""Radius of the capsule that highlights a body part in possible contact (display only)."""


def contact_class_grid(
    contacts: list[ContactMsg], link_names: list[str], n_intervals: int
) -> np.ndarray:
    """``(K, L)`` int8 ``CONTACT_*`` values: a contact at interval ``k`` on a link marks capsule
    ``(k, link)``; several contacts on one capsule: the most constrained class (self > env >
    unconstrained). Contacts naming an unknown link or an interval beyond ``K`` are skipped."""
    grid = np.zeros((n_intervals, len(link_names)), dtype=np.int8)
    index = {name: i for i, name in enumerate(link_names)}
    for c in contacts:
        i = index.get(c.link)
        if i is not None and c.interval < n_intervals:
            grid[c.interval, i] = max(grid[c.interval, i], CONTACT_CODES[c.kind])
    return grid


def contact_parts_of(
    contacts: list[ContactMsg], humans: list[HumanOccupancyMsg]
) -> ContactParts | None:
    """The body parts in possible contact as capsules between each part's end joints (most
    constrained class per part); parts of unknown humans or names are skipped."""
    classes: dict[tuple[str, str], int] = {}
    for c in contacts:
        key = (c.human_id, c.body_part)
        classes[key] = max(classes.get(key, 0), CONTACT_CODES[c.kind])
    if not classes:
        return None
    by_id = {h.id: h for h in humans}
    ends, codes = [], []
    for (hid, part), code in classes.items():
        h = by_id.get(hid)
        if h is None:
            continue
        sk = skeleton(h.kind)
        if part not in sk.parts:
            continue
        y = np.asarray(h.joints_m).reshape(-1, 3)
        ends.append(y[sk.part_joints[sk.parts.index(part)]])
        codes.append(code)
    if not ends:
        return None
    return ContactParts(np.stack(ends), np.full(len(ends), PART_RADIUS_M), np.array(codes))


def link_rows(links: list[LinkEnergyMsg]) -> list[LinkEnergy]:
    return [
        LinkEnergy(
            e.link,
            e.energy_j,
            e.limit_j,
            e.margin_j,
            e.human_id,
            e.body_part,
            e.contact,
            e.shape,
        )
        for e in links
    ]


def jssa_display(j: JssaMsg | None) -> tuple[dict[str, Any] | None, np.ndarray | None]:
    """The status entry of a JSSA state and its critical pair ``(2, 3)`` (robot point, other
    point; None when either is missing)."""
    if j is None:
        return None, None
    status = j.model_dump(exclude={"robot_point_m", "other_point_m"})
    pair = None
    if j.robot_point_m is not None and j.other_point_m is not None:
        pair = np.array([j.robot_point_m, j.other_point_m])
    return status, pair


def verdict_status(
    v: VerdictMsg, cycle_us: np.ndarray, worker: StatusMsg | None = None
) -> dict[str, Any]:
    """The status entries of a verdict (keys documented on :class:`DisplayFrame`);
    ``cycle_us (n,)``: recent cycle times [us] for the percentiles; ``worker``: the worker's
    newest status (its whole step's time and missed periods)."""
    return {
        "mode": v.mode,
        "safety_mode": v.safety_mode,
        "min_distance_m": v.min_distance_m,
        "cycle_p50_us": float(np.median(cycle_us)) if cycle_us.size else None,
        "cycle_p99_us": float(np.percentile(cycle_us, 99)) if cycle_us.size else None,
        "loop_p99_us": None if worker is None else worker.loop_time_p99_us,
        "overruns": None if worker is None else worker.overruns,
        "phase_lock": None if worker is None else worker.phase_lock,
        "robot_q_measured": None if worker is None else worker.robot_q_measured,
        "skeleton_age_ms": {k: 1e3 * a for k, a in v.skeleton_age_s.items()},
        "dropped": dict(v.dropped),
        "models": dict(v.results),
        "faults": list(v.faults),
        "intervened": v.intervened,
        "speed_scale": v.speed_scale,
        "tracking": {h: dict(c) for h, c in v.tracking.items()},
        "tracking_now": tracking_now_status(v),
        "violations": [x.model_dump() for x in v.violations],
        "jssa": None,
        **_words(v),
    }


def _words(v: VerdictMsg) -> dict[str, str]:
    w = verdict_words(v)
    return {"verdict_state": w.state, "verdict_text": w.sentence, "verdict_colour": w.colour}


def occupancy_into(frame: DisplayFrame, occ: OccupancyMsg) -> None:
    """Fill ``frame`` with an occupancy message: humans, robot occupancy (its verdict), PFL
    contact classes, body parts in contact and link energies, the JSSA state and pair."""
    for h in occ.humans:
        models = {name: caps.arrays() for name, caps in h.models.items()}
        y = np.asarray(h.joints_m).reshape(-1, 3)
        cuts = {name: caps.cuts() for name, caps in h.models.items() if caps.below_m}
        frame.humans.append(HumanDisplay(h.id, y, BONES, models, h.legs_below_m, cuts))
    legs = {h.id: h.legs_below_m for h in occ.humans if h.legs_below_m is not None}
    if legs:
        frame.status["legs_below_m"] = legs
    if occ.robot is not None:
        r = occ.robot
        e, rad = r.capsules.arrays()
        K, L = r.n_intervals, len(r.link_names)
        frame.robot_ends, frame.robot_radius = e.reshape(K, L, 2, 3), rad.reshape(K, L)
        frame.verified = r.verified
        frame.contact_class = contact_class_grid(occ.contacts, r.link_names, K)
    frame.contact_parts = contact_parts_of(occ.contacts, occ.humans)
    frame.links = link_rows(occ.links)
    jssa, frame.critical_pair = jssa_display(occ.jssa)
    frame.status["jssa"] = jssa
    frame.critical_active = bool(jssa and jssa["active"])


def boxes_of(sc: Scenario) -> EnvBoxes | None:
    return EnvBoxes(*box_arrays(sc.environment)) if sc.environment else None
