"""The worker's PFL/JSSA display messages agree with the results they summarise (a real PFL
check on a Panda, a person and a table; a real JSSA cycle), and survive the wire format."""

from __future__ import annotations

from typing import Any

import numpy as np
import pytest

from sara_app.bench.pfl import check_scene
from sara_app.bus.codec import decode
from sara_app.bus.messages import OccupancyMsg, encode
from sara_app.human.skeleton import skeleton
from sara_app.runtime.display import CLASS_BY_CODE, jssa_state, part_labels, pfl_contacts, pfl_links


@pytest.fixture(scope="module")
def pfl_case():
    pfl, sc = check_scene(10)
    res = pfl.check_trajectory(
        sc["q"], sc["q_dot"], sc["qd_bound"], sc["t"], sc["h_ends"], sc["h_radius"],
        sc["T_world_box"], sc["half_extents_m"],
    )  # fmt: skip
    return pfl, res


def test_contacts_cover_every_possible_contact_with_its_first_class(pfl_case):
    pfl, res = pfl_case
    names = pfl.model.link_names
    labels = part_labels(["h1"], skeleton("full").parts)
    msgs = pfl_contacts(res, names, labels)
    hit = res.cls > 0
    assert hit.any(), "the bench scene must have contacts for this test to mean anything"
    expected = {(names[i], labels[p][1]) for i, p in np.argwhere(hit.any(axis=0))}
    assert {(m.link, m.body_part) for m in msgs} == expected
    for m in msgs:
        i, p = names.index(m.link), labels.index((m.human_id, m.body_part))
        k = int(np.flatnonzero(hit[:, i, p])[0])
        assert m.interval == k
        assert m.kind == CLASS_BY_CODE[int(res.cls[k, i, p])]
        assert m.energy_limit_j == pytest.approx(res.threshold_J[hit[:, i, p], i, p].min())


def test_links_report_least_margin_contact(pfl_case):
    pfl, res = pfl_case
    names = pfl.model.link_names
    labels = part_labels(["h1"], skeleton("full").parts)
    links = pfl_links(res, names, labels, ["blunt"] * len(names))
    assert [m.link for m in links] == list(names)
    for i, m in enumerate(links):
        assert m.energy_j == pytest.approx(res.energy_J[:, i].max())
        finite = np.isfinite(res.allowed_J[:, i])
        if not finite.any():
            assert m.limit_j is None and m.margin_j is None
            continue
        margins = np.where(finite, res.allowed_J[:, i] - res.energy_J[:, i], np.inf)
        assert m.margin_j == pytest.approx(margins.min())
        assert m.body_part in skeleton("full").parts and m.contact in CLASS_BY_CODE.values()


def test_messages_survive_encoding(pfl_case):
    pfl, res = pfl_case
    names = pfl.model.link_names
    labels = part_labels(["h1"], skeleton("full").parts)
    msg = OccupancyMsg(
        seq=1,
        stamp_s=1.0,
        contacts=pfl_contacts(res, names, labels),
        links=pfl_links(res, names, labels, ["blunt"] * len(names)),
    )
    back = decode("sara/c1/occupancy", encode(msg)).msg
    assert back == msg


def test_mismatched_labels_give_no_contacts(pfl_case):
    pfl, res = pfl_case
    assert pfl_contacts(res, pfl.model.link_names, part_labels(["a", "b"], ["head"])) == []


def test_jssa_state_from_a_real_cycle():
    from sara_app.robot.model import load_robot
    from sara_app.safety.jssa import JssaController

    robot = load_robot("panda")
    ctl = JssaController(robot)
    q = np.array([0.0, -0.3, 0.0, -2.0, 0.0, 1.8, 0.8])
    h_ends = np.array([[[0.9, 0.0, 0.3], [0.9, 0.0, 0.8]]])
    res = ctl.step(q, np.zeros(7), np.zeros(7), np.zeros(7), h_ends, np.array([0.1]),
                   np.zeros((1, 2, 3)), 0.004)  # fmt: skip
    msg = jssa_state(res, robot.link_names, 0.05)
    assert msg.link == robot.link_names[res.link_index]
    assert msg.robot_point_m is not None and msg.other_point_m is not None
    assert res.distance_m > 0  # apart: the two surface points are the distance apart
    d = np.linalg.norm(np.subtract(msg.robot_point_m, msg.other_point_m))
    assert d == pytest.approx(res.distance_m, abs=1e-6)
    assert msg.active == res.active and msg.d_min_m == 0.05


def test_the_effective_set_is_per_body_part_the_least_model_capsule_that_holds_it() -> None:
    """``effective_set`` on real reach models of a walking pose: one capsule per body part,
    each one of the models' own capsules for that part and the one of least volume (checked
    against a brute-force loop), and every point of the part's body inside it."""
    from sara_app.geometry.shapes import point_segment_distance
    from sara_app.human.params import load_param_set, to_reach_params
    from sara_app.human.reach import HumanReach, part_capsules
    from sara_app.human.scripted import joints, standing
    from sara_app.runtime.display import effective_set

    reach = HumanReach(to_reach_params(load_param_set("work"), "full"))
    y = joints(standing((1.0, 0.2), 0.3))
    rng = np.random.default_rng(3)
    v = rng.normal(scale=0.8, size=y.shape)
    dv = np.full(len(y), 0.04)
    sets = []
    for name in ("pos", "vel", "acc", "combined"):
        o = reach.model(name, y[None], v[None], dv[None], np.array([0.01]), np.array([0.3]))
        sets.append((o.ends[0, 0], o.radius[0, 0], part_capsules(reach, name)))
    eff = effective_set(sets)
    assert eff is not None and effective_set([]) is None
    ends, radius = eff
    P = reach.skeleton.n_parts
    assert ends.shape == (P, 2, 3) and radius.shape == (P,)

    def volume(e: np.ndarray, r: float) -> float:
        return float(np.pi * r**2 * (np.linalg.norm(e[1] - e[0]) + 4.0 / 3.0 * r))

    half = reach.params.half_thickness_m
    for p, (a, b) in enumerate(reach.skeleton.part_joints):
        options = [(volume(e[m[p]], r[m[p]]), e[m[p]], r[m[p]]) for e, r, m in sets]
        best = min(options, key=lambda o: o[0])
        np.testing.assert_array_equal(ends[p], best[1])
        assert radius[p] == best[2]
        assert volume(ends[p], radius[p]) <= min(o[0] for o in options)
        for s in np.linspace(0.0, 1.0, 5):  # the part's axis, grown by its half thickness
            x = (1 - s) * y[a] + s * y[b]
            assert float(point_segment_distance(x, ends[p])) + half[p] <= radius[p] + 1e-9


def _upper_and_full_at_a_bench() -> tuple[Any, list[Any], Any, OccupancyMsg]:
    """``bench_handover_upper``'s cell with the same standing person tracked twice, once
    upper-body (legs bounded in height) and once full-body, measured at 10 s; the cycle at
    10.01 s and its occupancy message."""
    from sara_app.cell.build import build_cell
    from sara_app.cell.intake import take_measurement, track_for
    from sara_app.human.scripted import joints, standing
    from sara_app.runtime.display import occupancy_msg
    from sara_app.scenario import load_scenario

    cell = build_cell(load_scenario("bench_handover_upper"))
    y = joints(standing((1.2, 0.9), 3.0))
    tracks = [track_for(cell, "upper"), track_for(cell, "full")]
    for tr, legs in zip(tracks, (False, True), strict=True):
        assert take_measurement(cell, tr, 10.0, y, legs_measured=legs) is None
    res = cell.shield.cycle(10.01, [tr.state for tr in tracks])
    seq = iter(range(10))
    occ = occupancy_msg(cell, tracks, res, 10.01, lambda: next(seq), lambda *a: None)
    return cell, tracks, res, occ


def test_the_occupancy_carries_the_bound_of_unmeasured_legs() -> None:
    """A person of an upper-body source under a set that bounds the legs: the worker's display
    message says how high the legs reach at the end of the horizon shown (the thighs' bound,
    the highest), the same as the bound the check uses; a full-body person's says nothing."""
    from sara_app.runtime.display import legs_below

    cell, tracks, res, occ = _upper_and_full_at_a_bench()
    upper, full = occ.humans
    assert full.legs_below_m is None and upper.legs_below_m is not None
    caps = tracks[0].state.leg_cap
    assert caps is not None
    horizon = 0.0 if res.trajectory is None else res.trajectory.duration_s
    assert upper.legs_below_m == pytest.approx(legs_below(caps, 0.01 + horizon))
    thigh = cell.shield.reach.skeleton.parts.index("l_thigh")
    assert upper.legs_below_m == pytest.approx(caps[thigh, 0] + caps[thigh, 1] * (0.01 + horizon))
    assert legs_below(None, 0.1) is None
    assert decode("sara/cell1/occupancy", encode(occ)).msg == occ


def test_the_legs_capsules_carry_the_cut_the_check_uses() -> None:
    """An upper-body person at a bench (legs bounded in height): every model's capsule that
    holds a leg part is cut at the highest bound of the parts it holds, at the end of the
    horizon shown, and a capsule holding any unbounded part is whole (oracle: a loop over the
    parts); the effective set's capsule of each part is cut at that part's bound. A full-body
    person's capsules carry no cut."""
    from sara_app.dashboard.frame import DisplayFrame
    from sara_app.dashboard.from_messages import occupancy_into

    cell, tracks, res, occ = _upper_and_full_at_a_bench()
    upper, full = occ.humans
    caps = tracks[0].state.leg_cap
    assert caps is not None
    tau = 0.01 + (0.0 if res.trajectory is None else res.trajectory.duration_s)
    part_z = caps[:, 0] + caps[:, 1] * tau  # (P,), inf where unbounded
    assert np.isfinite(part_z).sum() == 6  # thighs, shins, feet
    maps = dict(zip(cell.shield.verifier.models, cell.shield.verifier.part_maps, strict=True))
    cut_somewhere = False
    for name, msg in upper.models.items():
        got = msg.cuts()
        if name == "effective":
            np.testing.assert_allclose(got, part_z)
            continue
        for c in range(len(msg.radius_m)):
            parts = [p for p, m in enumerate(maps[name]) if m == c]
            want = max(part_z[p] for p in parts) if parts else np.inf
            assert got[c] == pytest.approx(want), (name, c)
            cut_somewhere |= bool(np.isfinite(got[c]))
    assert cut_somewhere
    assert all(m.below_m is None for m in full.models.values())
    assert decode("sara/cell1/occupancy", encode(occ)).msg == occ
    frame = DisplayFrame(t_s=0.0, q=np.zeros(7))
    occupancy_into(frame, occ)  # what the dashboard draws
    np.testing.assert_allclose(frame.humans[0].cuts["effective"], part_z)
    assert frame.humans[1].cuts == {}
    assert frame.status["legs_below_m"] == {upper.id: upper.legs_below_m}  # the status row


def test_the_occupancy_of_many_people_is_each_persons_sets_as_verified() -> None:
    """Six people measured at different times, with and without widening (one with a model
    widened to infinity): the message built for all of them at once holds, per person, what
    the reach model gives that person alone over their own interval, widened as the check
    widens it, and the effective set of that person's models; a model not finite for a person
    is left out for that person only."""
    from sara_app.cell.build import build_cell
    from sara_app.cell.intake import take_measurement, track_for
    from sara_app.errors import InputError
    from sara_app.human.reach import MODELS, part_capsules
    from sara_app.human.scripted import joints, standing
    from sara_app.human.widening import per_capsule
    from sara_app.runtime.display import EFFECTIVE, effective_set, occupancy_msg
    from sara_app.scenario import load_scenario

    cell = build_cell(load_scenario("standing_beside_path"))
    rng = np.random.default_rng(11)
    tracks = [track_for(cell, f"p{i}") for i in range(6)]
    for i, tr in enumerate(tracks):  # two measurements (velocities known) but for p5
        y = joints(standing((1.0 + 0.3 * i, -0.5 + 0.2 * i), 0.4 * i))
        for k in range(1 if i == 5 else 2):
            stamp = 10.0 - 0.013 * i - 0.02 * (1 - k)
            assert take_measurement(cell, tr, stamp, y + 0.01 * k) is None
    P = cell.shield.reach.skeleton.n_parts
    tracks[1].state.widen_m = rng.uniform(0.0, 0.05, (len(MODELS), P))
    tracks[2].state.widen_m = np.zeros((len(MODELS), P))
    first = cell.shield.verifier.models[0]
    tracks[2].state.widen_m[MODELS.index(first), 3] = np.inf
    now = 10.02
    res = cell.shield.cycle(now, [tr.state for tr in tracks])
    occ = occupancy_msg(cell, tracks, res, now, lambda: 0, lambda *a: None)
    horizon = 0.0 if res.trajectory is None else res.trajectory.duration_s
    reach = cell.shield.reach
    assert [h.id for h in occ.humans] == [tr.state.id for tr in tracks]
    for tr, shown in zip(tracks, occ.humans, strict=True):
        st = tr.state
        age = now - float(st.stamp_s)
        sets = []
        for name in cell.shield.verifier.models:
            try:
                o = reach.model(name, st.y[None], st.v[None], st.dv[None], np.array([age]),
                                np.array([age + horizon]))  # fmt: skip
            except InputError:  # velocities not known yet (one measurement)
                assert name not in shown.models
                continue
            pm = part_capsules(reach, name)
            r = o.radius[0, 0]
            if st.widen_m is not None:
                r = r + per_capsule(st.widen_m[MODELS.index(name)], pm, len(r))
            if not np.isfinite(r).all():
                assert name not in shown.models
                continue
            np.testing.assert_allclose(shown.models[name].ends_m, o.ends[0, 0].ravel(), atol=1e-12)
            np.testing.assert_allclose(shown.models[name].radius_m, r, atol=1e-12)
            sets.append((o.ends[0, 0], r, pm))
        eff = effective_set(sets)
        assert eff is not None
        np.testing.assert_allclose(shown.models[EFFECTIVE].ends_m, eff[0].ravel(), atol=1e-12)
        np.testing.assert_allclose(shown.models[EFFECTIVE].radius_m, eff[1], atol=1e-12)
    assert first not in occ.humans[2].models and first in occ.humans[1].models
    moving = [m for m in cell.shield.verifier.models if m in ("acc", "combined")]
    assert moving and all(m in occ.humans[0].models and m not in occ.humans[5].models
                          for m in moving)  # fmt: skip
    assert len(occ.humans[5].models) > 1  # the models that need no velocities


def test_the_effective_set_of_many_people_is_each_ones() -> None:
    """``effective_set`` over rows of people equals the set of each person alone."""
    from sara_app.runtime.display import effective_set

    rng = np.random.default_rng(5)
    H, P = 4, 6
    maps = [np.array([0, 0, 1, 1, 2, 2]), np.arange(P)]
    sets = [(rng.normal(size=(H, len(np.unique(m)), 2, 3)), rng.uniform(0.1, 0.5,
             (H, len(np.unique(m)))), m) for m in maps]  # fmt: skip
    sets[1][1][2, 4] = np.inf  # one person's capsule of one model unbounded
    eff = effective_set(sets)
    assert eff is not None and eff[0].shape == (H, P, 2, 3) and eff[1].shape == (H, P)
    for h in range(H):
        one = effective_set([(e[h], r[h], m) for e, r, m in sets])
        assert one is not None
        np.testing.assert_array_equal(eff[0][h], one[0])
        np.testing.assert_array_equal(eff[1][h], one[1])
