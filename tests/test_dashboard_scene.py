"""Dashboard server side without a browser: a real viser server on 127.0.0.1, the scene's node
state after updates, capacity growth, toggles, malformed frames, scenario-tab callbacks."""

from __future__ import annotations

from collections.abc import Iterator
from dataclasses import replace

import numpy as np
import pytest
from browser import wait_for
from viser_client import ViserClient

from sara_app.bus.messages import JointFlagMsg, TrackingNowMsg, VerdictMsg, ViolationMsg
from sara_app.bus.session import free_port
from sara_app.dashboard.frame import (
    CONTACT_ENV,
    CONTACT_SELF,
    CONTACT_UNCONSTRAINED,
    EFFECTIVE,
    MODEL_NAMES,
    LinkEnergy,
)
from sara_app.dashboard.from_messages import verdict_status
from sara_app.dashboard.panels import RollingSeries, flatten, unflatten
from sara_app.dashboard.scene import (
    CONTACT_RGB,
    CRITICAL_ACTIVE_RGB,
    CRITICAL_IDLE_RGB,
    DEFAULT_VISIBLE,
    PELVIS,
    UNVERIFIED_RGB,
    VERIFIED_RGB,
    VIEW_NAMES,
    demo_frame,
    occupancy_colors,
)
from sara_app.dashboard.status_text import (
    MARGIN_RGB,
    link_energy_markdown,
    margin_level,
    status_markdown,
)
from sara_app.dashboard.tracking_text import totals_markdown
from sara_app.dashboard.viewer import Dashboard
from sara_app.errors import ScenarioError, UnknownNameError
from sara_app.scenario import load_scenario, scenario_names


@pytest.fixture(scope="module")
def dash() -> Iterator[Dashboard]:
    d = Dashboard()
    d.start(port=free_port())
    assert d.scene is not None
    for name in (*MODEL_NAMES, "occupancy"):  # every group sends its data
        d.scene.set_visible(name, True)
    yield d
    d.stop()


def test_by_default_the_effective_set_and_the_robot_are_shown() -> None:
    """What a new dashboard shows before any browser chose otherwise: each person's effective
    set (no per-model sets), the robot, its occupancy coloured by contact class; a hidden set
    is not sent."""
    d = Dashboard()
    d.start(port=free_port())
    try:
        scene = d.scene
        assert scene is not None
        assert d.update(demo_frame(1.0))
        shown = {m for m, g in scene.models.items() if g.visible}
        assert shown == {EFFECTIVE}
        assert scene.robot_frame.visible and scene.occupancy_contact.visible
        assert not scene.occupancy.visible
        assert scene.models[EFFECTIVE].count == 14 and scene.models["pos"].count == 0
        hidden = np.asarray(scene.models["pos"].tubes.handle.batched_scales)  # type: ignore[union-attr]
        assert np.all(hidden == 0.0)
        assert set(DEFAULT_VISIBLE) == set(VIEW_NAMES)
    finally:
        d.stop()


def test_start_reports_real_port_on_loopback(dash: Dashboard) -> None:
    other = Dashboard()
    url = other.start(port=int(dash.url.rsplit(":", 1)[1]))  # type: ignore[union-attr]
    try:
        assert url.startswith("http://127.0.0.1:") and url != dash.url
        assert other.server is not None and url.endswith(f":{other.server.get_port()}")
    finally:
        other.stop()


def test_occupancy_colours_follow_verdict_and_contact(dash: Dashboard) -> None:
    scene = dash.scene
    assert scene is not None
    for verified, rgb in ((True, VERIFIED_RGB), (False, UNVERIFIED_RGB)):
        frame = demo_frame(1.0, verified=verified)
        assert dash.update(frame)
        n = frame.robot_radius.size
        plain = np.asarray(scene.occupancy.tubes.handle.batched_colors)[:n]  # type: ignore[union-attr]
        assert np.all(plain == rgb)  # the verdict colouring
        colors = np.asarray(scene.occupancy_contact.tubes.handle.batched_colors)[:n]  # type: ignore[union-attr]
        cc = frame.contact_class.reshape(-1)  # type: ignore[union-attr]
        assert np.all(colors[cc == 0] == rgb)
        for cls in (CONTACT_UNCONSTRAINED, CONTACT_ENV, CONTACT_SELF):
            assert np.all(colors[cc == cls] == CONTACT_RGB[cls])
        # the caps of capsule i carry capsule i's colour
        caps = np.asarray(scene.occupancy_contact.caps.handle.batched_colors)[: 2 * n]  # type: ignore[union-attr]
        assert np.all(caps.reshape(n, 2, 3) == colors[:, None])
    plain = occupancy_colors(4, True, np.array([0, 1, 2, 3]), by_contact=False)
    assert np.all(plain == VERIFIED_RGB)


def test_capacity_grows_and_buffers_are_reused(dash: Dashboard) -> None:
    scene = dash.scene
    assert scene is not None
    group = scene.models["pos"]
    big = demo_frame(2.0, n_capsules=70)
    assert dash.update(big)
    assert group.tubes.capacity >= 70 and group.caps.capacity >= 140
    buf = group.tubes.positions
    small = demo_frame(2.1, n_capsules=3)
    assert dash.update(small)
    assert group.tubes.positions is buf  # no reallocation when shrinking
    scales = np.asarray(group.tubes.handle.batched_scales)  # type: ignore[union-attr]
    assert np.all(scales[3:] == 0.0) and np.all(scales[:3, 0] > 0.0)
    ends, radius = small.humans[0].models["pos"]
    sent = np.asarray(group.tubes.handle.batched_positions)[:3]  # type: ignore[union-attr]
    np.testing.assert_allclose(sent, ends.mean(axis=1), atol=1e-6)


def test_model_toggle_and_unknown_model(dash: Dashboard) -> None:
    scene = dash.scene
    assert scene is not None
    scene.set_visible("vel", False)
    assert not scene.models["vel"].tubes.handle.visible  # type: ignore[union-attr]
    assert dash.update(demo_frame(3.0))
    scene.set_visible("vel", True)
    assert scene.models["vel"].caps.handle.visible  # type: ignore[union-attr]
    with pytest.raises(
        UnknownNameError, match="valid choices: effective, pos, vel.*robot, occupancy"
    ):
        scene.set_visible("speed", True)
    scene.set_visible("skeletons", False)
    assert dash.update(demo_frame(3.05)) and not scene.skeleton.visible
    scene.set_visible("skeletons", True)
    assert dash.update(demo_frame(3.06)) and scene.skeleton.visible and scene.joints.visible
    scene.set_visible("robot", False)
    assert not scene.robot_frame.visible
    scene.set_visible("robot", True)
    frame = demo_frame(3.1)
    frame.humans[0].models["speed"] = frame.humans[0].models["pos"]
    assert not dash.update(frame)


def test_malformed_frames_are_rejected_visibly(dash: Dashboard) -> None:
    assert dash.panels is not None
    before = dash.frames_rejected
    assert dash.scene is not None
    handle = dash.scene.models["pos"].tubes.handle
    assert dash.update(demo_frame(3.9))
    shown = np.array(handle.batched_positions)  # type: ignore[union-attr]
    assert not dash.update(replace(demo_frame(4.0), q=np.zeros(3)))
    assert not dash.update(replace(demo_frame(4.0), robot_radius=np.zeros((2, 2))))
    # a frame rejected late (occupancy shape) changed nothing earlier in it either
    np.testing.assert_array_equal(handle.batched_positions, shown)  # type: ignore[union-attr]
    assert dash.frames_rejected == before + 2
    assert dash.panels.error.visible and "expected" in dash.panels.error.content
    # NaNs are not malformed: they are hidden, the frame is shown
    frame = demo_frame(4.1)
    frame.robot_ends[0, 0] = np.nan
    frame.humans[0].joint_positions[2] = np.nan
    assert dash.update(frame)


def test_scenario_callbacks_and_refusals(dash: Dashboard) -> None:
    panels = dash.panels
    assert panels is not None
    got: list[object] = []

    def select(name: str) -> None:
        got.append(("select", name))

    def save(name: str) -> None:
        if not name:
            raise ScenarioError("scenario name '' is empty; expected letters, digits, '_'")
        got.append(("save", name))

    def edit(params: dict) -> None:
        if params["human"]["v_max"] <= 0:
            raise ScenarioError(f"v_max = {params['human']['v_max']}; expected > 0")
        got.append(("edit", params))

    panels.on_select_scenario, panels.on_save_as, panels.on_params_edit = select, save, edit
    assert panels.load_selected() and panels.message.content == "Load: done"
    panels.on_select_scenario = lambda name: panels.show_message(f"loaded {name}")
    assert panels.load_selected() and panels.message.content == "loaded (no scenarios)"
    panels.on_select_scenario = select
    panels.set_scenarios(["walk_in", "reach_over"], current="reach_over")
    assert panels.load_selected() and got[-1] == ("select", "reach_over")
    assert not panels.save_as() and "refused" in panels.message.content
    panels.save_name.value = " mine "
    assert panels.save_as() and got[-1] == ("save", "mine")
    params = {"human": {"v_max": 2.0, "full_body": True, "name": "x", "radii": [0.1, 0.2]}}
    panels.set_params(params)
    assert panels.apply_params() and got[-1] == ("edit", params)
    # a box's centre is a vector input of its own; editing it edits that box only
    boxes = {"human": params["human"], "environment": [
        {"name": "table", "center_m": [0.6, 0.0, 0.1], "size_m": [0.5, 1.6, 0.2]},
        {"name": "shelf", "center_m": [0.0, 0.8, 0.5], "size_m": [0.3, 0.3, 1.0]}]}  # fmt: skip
    panels.set_params(boxes)
    centre = panels._param_inputs["environment[1].center_m"]
    assert tuple(centre.value) == (0.0, 0.8, 0.5)
    centre.value = (0.1, 0.9, 0.5)
    assert panels.apply_params()
    sent = got[-1][1]
    assert sent["environment"][1]["center_m"] == [0.1, 0.9, 0.5]
    assert sent["environment"][0] == boxes["environment"][0]
    panels.set_params(params)
    panels._param_inputs["human.v_max"].value = -1.0
    n = len(got)
    assert not panels.apply_params() and len(got) == n
    assert "v_max = -1.0" in panels.message.content


def test_a_clients_huge_number_in_an_integer_field_leaves_every_view_connected() -> None:
    """A client that is not a browser (tests/viser_client.py) sends 1e300 to an integer
    parameter (a number field: viser casts the value to the field's type). The field held
    int(1e300) and msgpack cannot encode it: every browser's connection to the view failed
    from then on (1011), the next browser's too, until the dashboard restarted. Integer
    parameters are float fields now; a whole number goes back as an integer, any other as the
    number sent (the scenario's validation refuses it)."""
    d = Dashboard()
    d.start(port=free_port())
    try:
        panels = d.panels
        assert panels is not None and d.server is not None
        edits: list[dict] = []
        panels.on_params_edit = edits.append
        panels.set_params({"task": {"cycles": 6}, "sim": {"seed": 0}})
        hostile = ViserClient(d.server.get_port())
        try:
            hostile.send("task.cycles", value=1e300)
            cycles = panels._param_inputs["task.cycles"]  # noqa: SLF001
            wait_for(lambda: cycles.value == 1e300, 10.0, "the value taken")
            other = ViserClient(d.server.get_port())  # the next browser still gets the view
            try:
                other.field("sim.seed")
                hostile.send("sim.seed", value=7.0)
                wait_for(lambda: panels._param_inputs["sim.seed"].value == 7.0, 10.0, "7")  # noqa: SLF001
            finally:
                other.close()
        finally:
            hostile.close()
        assert panels.apply_params()
        assert edits[-1] == {"task": {"cycles": int(1e300)}, "sim": {"seed": 7}}
        assert isinstance(edits[-1]["sim"]["seed"], int)
        cycles.value = 6.5
        assert panels.apply_params() and edits[-1]["task"]["cycles"] == 6.5
    finally:
        d.stop()


def test_a_client_sets_a_fields_value_and_nothing_else() -> None:
    """viser applies whatever properties a client's update names, and the server's fields are
    every browser's: a client that is not a browser hid, relabelled and re-enabled fields for
    everybody. Updates naming anything but the value are dropped (viser's page sends values
    only), for the shared fields and for this browser's own; values still arrive."""
    d = Dashboard()
    d.start(port=free_port())
    try:
        panels, views = d.panels, d.views
        assert panels is not None and views is not None and d.server is not None
        panels.set_params({"task": {"cycles": 6}})
        client = ViserClient(d.server.get_port())
        try:
            client.send("Safety mode", visible=False)
            client.send("Safety mode", value="PFL", label="Load")
            client.send("Apply parameters", disabled=True, label="Save as")
            client.send("Robot", label="hidden", value=False)  # this browser's own field
            client.send("task.cycles", value=3.0)  # after the others: they were handled first
            wait_for(lambda: panels._param_inputs["task.cycles"].value == 3.0, 10.0, "3")  # noqa: SLF001
            client.send("Robot", value=False)
            (b,) = views._browsers.values()  # noqa: SLF001
            # hidden in this browser's scene: its callback ran before the client goes
            wait_for(lambda: not b.frames["robot"].visible, 10.0, "this browser's robot hidden")
        finally:
            client.close()
        mode = panels.safety_mode
        assert mode.visible and mode.label == "Safety mode" and mode.value == "SSM"
        assert b.boxes["robot"].label != "hidden"
        apply = next(h for h in d.server.gui._gui_input_handle_from_uuid.values()  # noqa: SLF001
                     if h.label == "Apply parameters")  # fmt: skip
        assert not apply.disabled
    finally:
        d.stop()


def test_flatten_round_trip_and_status_table() -> None:
    nested = {"a": {"b": 1, "c": {"d": [1, 2]}}, "e": "x"}
    assert flatten(nested) == {"a.b": 1, "a.c.d": [1, 2], "e": "x"}
    assert unflatten(flatten(nested)) == nested
    # people and boxes: one input per field of each item; every shipped scenario round-trips
    people = {"humans": [{"id": "p1", "sensor": {"rate_hz": 60.0}}, {"id": "p2"}], "none": []}
    assert flatten(people) == {"humans[0].id": "p1", "humans[0].sensor.rate_hz": 60.0,
                               "humans[1].id": "p2", "none": []}  # fmt: skip
    assert unflatten(flatten(people)) == people
    for name in scenario_names():
        data = load_scenario(name).model_dump(mode="json")
        assert unflatten(flatten(data)) == data, name
    status = {"mode": "failsafe", "min_distance_m": float("inf"),
              "dropped": {"bad": 3, "superseded": 133088}}  # fmt: skip
    md = status_markdown(status)
    assert "failsafe" in md and "inf" in md and "bad: 3" in md and "n/a" in md
    assert "superseded" not in md and "133088" not in md  # normal operation, not a drop
    assert "| Dropped messages | none |" in status_markdown({"dropped": {"superseded": 5}})


def test_rolling_series_keeps_window_and_skips_nonfinite() -> None:
    s = RollingSeries(1, window_s=1.0, capacity=16)
    for i in range(100):
        s.append(0.05 * i, np.array([i * 1.0]))
    s.append(5.0, np.array([np.nan]))
    t, y = s.data()
    assert t[-1] == pytest.approx(0.05 * 99) and t[0] >= t[-1] - 1.0 - 1e-12
    np.testing.assert_allclose(y, t / 0.05)
    assert np.all(np.diff(t) > 0)
    rel, y_rel = s.plot_data()  # the plots' x axis: seconds before the newest sample
    np.testing.assert_allclose(rel, t - t[-1])
    assert rel[-1] == 0.0 and rel[0] >= -1.0 - 1e-12 and np.array_equal(y_rel, y)


def test_all_model_groups_exist(dash: Dashboard) -> None:
    assert dash.scene is not None and tuple(dash.scene.models) == MODEL_NAMES


def test_margin_levels_and_link_table() -> None:
    assert margin_level(None, None) is None and margin_level(1.0, None) is None
    assert margin_level(float("nan"), 2.0) is None
    assert margin_level(-1e-9, 2.0) == "negative"
    assert margin_level(0.0, 2.0) == "small" and margin_level(0.199, 2.0) == "small"
    assert margin_level(0.2, 2.0) == "ok"
    links = [
        LinkEnergy("a|b", 0.5, 0.4, -0.1, "h<1>", "l_hand", "env-constrained", "edge"),
        LinkEnergy("c", 0.1, 2.0, 1.9, "h1", "torso", "unconstrained"),
        LinkEnergy("d", 0.0),
    ]
    md = link_energy_markdown(links)
    rows = md.splitlines()
    assert len(rows) == 2 + 3 and all(r.count(" | ") == 4 for r in rows[2:])  # 5 columns
    r, g, b = MARGIN_RGB["negative"]
    assert f"rgb({r},{g},{b})" in rows[2] and "-0.100" in rows[2] and "a\\|b" in rows[2]
    assert "l_hand (h&lt;1&gt;)<br/>env-constrained, edge" in rows[2]
    r, g, b = MARGIN_RGB["ok"]
    assert f"rgb({r},{g},{b})" in rows[3] and "+1.900" in rows[3]
    assert "no contact possible" in rows[4] and "rgb(" not in rows[4]
    assert "No link energies" in link_energy_markdown([])


def test_status_rows_of_the_safety_modes() -> None:
    base = {"mode": "intended", "safety_mode": "ssm"}
    md = status_markdown(base)
    assert "Speed scale" not in md and "JSSA" not in md and "Intervening" not in md
    md = status_markdown({**base, "intervened": False, "speed_scale": 0.255})
    assert "Intervening | no" in md and "Speed scale | 26 %" in md
    jssa = {"phi_m2": None, "active": False, "fallback": False, "d_min_m": 0.05}
    md = status_markdown({**base, "jssa": jssa})
    assert "JSSA | inactive" in md and "JSSA phi | n/a" in md and "n/a / 0.050 m" in md


def test_the_status_says_whose_legs_are_held_below_a_height() -> None:
    """A person whose legs the tracker does not measure: one row with the height the set holds
    them below and what that assumes; none without such a person."""
    md = status_markdown({"mode": "intended", "legs_below_m": {"p1": 1.2172, "p2": None}})
    assert "| Legs not measured | **p1**: held below 1.22 m (assumed: standing work" in md
    assert "**p2**: held below n/a" in md
    assert "Legs not measured" not in status_markdown({"mode": "intended"})


def test_status_rows_of_tracking_flags_and_violations() -> None:
    """A verdict's tracking as it stands (held joints, why, for how long; the newest flag)
    and violations in the status; the totals only in their own table (shown on demand)."""
    held = TrackingNowMsg(
        held=[JointFlagMsg(joint="l_wrist", flag="bone", stamp_s=0.75)],
        last_flag=JointFlagMsg(joint="l_wrist", flag="bone", stamp_s=1.0),
    )
    v = VerdictMsg(seq=1, stamp_s=1.0, cell="c", safety_mode="ssm", mode="fault",
                   cycle_time_us=1.0, tracking={"p1": {"bone": 3, "speed": 2}},
                   tracking_now={"p1": held},
                   violations=[ViolationMsg(human_id="p1", joint="l_wrist", quantity="speed",
                                            value=3.25, bound=2.0, stamp_s=1.0)])  # fmt: skip
    status = verdict_status(v, np.zeros(0))
    md = status_markdown(status)
    assert "Tracking p1 | **held**: l_wrist (bone length off, 0.2 s)" in md
    assert "bone 3" not in md and "| p1 | bone 3, speed 2 |" in totals_markdown(status)
    assert "**p1** l_wrist speed 3.25 > 2.00 m/s: failsafe" in md
    trusted = TrackingNowMsg(last_flag=JointFlagMsg(joint="r_knee", flag="jump", stamp_s=-2.0))
    later = verdict_status(v.model_copy(update={"tracking_now": {"p1": trusted}}), np.zeros(0))
    assert "Tracking p1 | all joints trusted; last flag jump at r_knee 3.0 s ago" in (
        status_markdown(later)
    )
    clean = verdict_status(v.model_copy(update={"tracking": {}, "tracking_now": {},
                                                "violations": []}), np.zeros(0))  # fmt: skip
    assert "Tracking | every joint trusted, no flag" in status_markdown(clean)
    assert totals_markdown(clean).startswith("No tracking flag")


def test_contact_parts_layer_and_critical_colour(dash: Dashboard) -> None:
    scene = dash.scene
    assert scene is not None
    frame = demo_frame(5.0)
    assert frame.contact_parts is not None and dash.update(frame)
    assert scene.contact_parts.count == 2
    rgb = np.asarray(scene.contact_parts.tubes.handle.batched_colors)[:2]  # type: ignore[union-attr]
    assert [tuple(c) for c in rgb] == [CONTACT_RGB[2], CONTACT_RGB[1]]
    assert np.all(np.asarray(scene.critical.colors) == CRITICAL_ACTIVE_RGB)
    assert dash.update(replace(frame, critical_active=False))
    assert np.all(np.asarray(scene.critical.colors) == CRITICAL_IDLE_RGB)
    scene.set_visible("contacts", False)
    assert not scene.contact_parts.visible
    scene.set_visible("contacts", True)
    bad = replace(frame, contact_parts=replace(frame.contact_parts, radius=np.zeros(5)))
    assert not dash.update(bad)


def test_the_legend_names_every_human_model_in_its_colour() -> None:
    from sara_app.dashboard.scene import MODEL_COLORS
    from sara_app.dashboard.status_text import LEGEND_MD

    assert len(set(MODEL_COLORS.values())) == len(MODEL_NAMES)  # distinguishable
    for m in MODEL_NAMES:
        r, g, b = MODEL_COLORS[m]
        assert f'<span style="color:rgb({r},{g},{b})">&#9632;</span> {m}' in LEGEND_MD


def test_the_legs_bound_is_drawn_at_its_height_with_the_effective_set(dash: Dashboard) -> None:
    """A person whose unmeasured legs are bounded gets one thin square at the bound's height
    under their pelvis, shown and hidden with the effective set; a person without a bound (or
    with a non-finite pelvis) gets none."""
    scene = dash.scene
    assert scene is not None
    assert dash.update(demo_frame(4.0))
    assert not scene.legs_bound.scales.any()  # no bound: nothing drawn
    frame = demo_frame(4.05)
    pelvis = frame.humans[0].joint_positions[PELVIS].copy()
    frame.humans[0].legs_below_m = 1.1
    frame.humans.append(replace(frame.humans[0], id="nan", joint_positions=np.full_like(
        frame.humans[0].joint_positions, np.nan)))  # fmt: skip
    assert dash.update(frame)
    b = scene.legs_bound
    np.testing.assert_allclose(b.positions[0], [*pelvis[:2], 1.1], atol=1e-6)
    assert b.scales[0, 2] < 0.01 and b.scales[0, 0] >= 2.0 and not b.scales[1:].any()
    scene.set_visible("effective", False)
    assert not b.visible
    scene.set_visible("effective", True)
    assert b.visible


def test_capsules_with_a_cut_are_drawn_cut_and_the_rest_whole(dash: Dashboard) -> None:
    """A person whose leg capsules carry a cut: those capsules leave the instanced group and
    are drawn as one mesh that stays below each one's cut; the others stay instanced. Hidden
    with their set; bad cut shapes and NaN cuts are refused like bad capsules."""
    scene = dash.scene
    assert scene is not None
    frame = demo_frame(5.0)
    h = frame.humans[0]
    ends, radius = h.models["effective"]
    cut = np.full(radius.shape, np.inf)
    cut[:4] = ends[:4, :, 2].mean(axis=1)  # through the middle of the first four
    h.cuts = {"effective": cut}
    assert dash.update(frame)
    mesh = scene.cut_models["effective"]
    assert scene.models["effective"].count == len(radius) - 4 and mesh.count == 4
    v = mesh.vertices
    assert len(v) and v[:, 2].max() <= cut[:4].max() + 1e-6
    assert not len(scene.cut_models["pos"].vertices)  # no cut there: nothing drawn
    scene.set_visible("effective", False)
    assert not mesh.visible and not len(mesh.vertices)
    scene.set_visible("effective", True)
    assert dash.update(frame)
    assert len(mesh.vertices)
    for bad in (np.full(3, 1.0), np.where(np.arange(len(radius)) < 1, np.nan, np.inf)):
        h.cuts = {"effective": bad}
        assert not dash.update(frame)


def test_at_most_max_cut_capsules_of_a_set_are_drawn_cut(dash: Dashboard) -> None:
    """A message with more cut capsules than the dashboard draws cut: the first
    MAX_CUT_CAPSULES cut, the rest whole (larger than the set, never smaller)."""
    from sara_app.dashboard.scene import MAX_CUT_CAPSULES

    scene = dash.scene
    assert scene is not None
    frame = demo_frame(6.0)
    n = MAX_CUT_CAPSULES + 40
    ends = np.tile(np.array([[[1.0, 0.0, 0.3], [1.0, 0.0, 0.9]]]), (n, 1, 1))
    frame.humans[0].models = {"effective": (ends, np.full(n, 0.1))}
    frame.humans[0].cuts = {"effective": np.full(n, 0.6)}
    assert dash.update(frame)
    assert scene.cut_models["effective"].count == MAX_CUT_CAPSULES
    assert scene.models["effective"].count == 40
