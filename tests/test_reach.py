"""Soundness of the reachability models on synthetic motion that obeys each model's bounds.

Every joint follows its own random motion inside the model's assumptions (the models treat
joints independently, so this is a superset of real human motion); measurements carry noise up
to delta_y (and the velocity error bound); the future joint positions, grown by the body part's
half thickness, are checked at densely sampled times of every interval. Zero misses allowed.
"""

from __future__ import annotations

import numpy as np
import pytest

from sara_app.errors import InputError, ParameterError, UnknownNameError
from sara_app.geometry.shapes import point_segment_distance
from sara_app.human.params import load_param_set, parse_param_set, to_reach_params
from sara_app.human.reach import MODELS, HumanReach
from sara_app.human.skeleton import skeleton

KINDS = ("full", "upper")
T_START = np.array([0.0, 0.004, 0.05, 0.1, 0.2])
T_END = np.array([0.004, 0.05, 0.1, 0.2, 0.35])


def _reach(kind: str) -> HumanReach:
    return HumanReach(to_reach_params(load_param_set("schepp2022_table1"), kind))


def _rand_ball(rng: np.random.Generator, shape: tuple[int, ...], radius: np.ndarray) -> np.ndarray:
    """Points uniformly in balls of ``radius`` (broadcast to shape[:-1]); shape ends in 3."""
    d = rng.normal(size=shape)
    d /= np.linalg.norm(d, axis=-1, keepdims=True)
    return d * (np.asarray(radius)[..., None] * rng.random(shape[:-1])[..., None] ** (1 / 3))


def _on_sphere(rng: np.random.Generator, shape: tuple[int, ...], radius: np.ndarray) -> np.ndarray:
    d = rng.normal(size=shape)
    return d / np.linalg.norm(d, axis=-1, keepdims=True) * np.asarray(radius)[..., None]


def _simulate(
    rng: np.random.Generator,
    y0: np.ndarray,
    v0: np.ndarray,
    a_max: np.ndarray,
    v_max: np.ndarray | None,
    times: np.ndarray,
    n_switch: int = 6,
) -> np.ndarray:
    """Joint paths ``(S, H, J, 3)`` at ``times (S,)`` with bang-bang accelerations |a| = a_max
    switching direction at random times; speeds clipped to v_max (clipping only lowers |v|)."""
    dt = np.diff(times, prepend=0.0)
    H, J, _ = y0.shape
    switches = np.sort(rng.random((n_switch,)) * times[-1])
    acc_dirs = _on_sphere(rng, (n_switch + 1, H, J, 3), np.ones((n_switch + 1, H, J)))
    y, v = y0.copy(), v0.copy()
    out = np.empty((len(times), H, J, 3))
    for s, t in enumerate(times):
        seg = np.searchsorted(switches, t)
        a = acc_dirs[seg] * a_max[None, :, None]
        v_new = v + a * dt[s]
        if v_max is not None:
            n = np.linalg.norm(v_new, axis=-1, keepdims=True)
            v_new = v_new * np.minimum(1.0, v_max[None, :, None] / np.maximum(n, 1e-12))
        y = y + 0.5 * (v + v_new) * dt[s]  # trapezoid: exact for the piecewise-linear v
        v = v_new
        out[s] = y
    return out


def _check_contained(reach: HumanReach, model: str, occ_ends, occ_radius, paths, k: int):
    """Every joint of ``paths (S, H, J, 3)`` must lie in interval k's capsules."""
    cap, joint, margin = reach.coverage[model]
    ends = occ_ends[:, k][:, cap]  # (H, M, 2, 3)
    rad = occ_radius[:, k][:, cap]
    d = point_segment_distance(paths[:, :, joint], ends[None])  # (S, H, M)
    excess = d + margin - rad[None]
    return float(excess.max())


def _pose(rng: np.random.Generator, kind: str, H: int) -> np.ndarray:
    """Plausible random poses ``(H, J, 3)`` (limb lengths in a human range)."""
    sk = skeleton(kind)
    base = {
        "head": (0, 0, 1.65),
        "neck": (0, 0, 1.45),
        "pelvis": (0, 0, 0.95),
        "l_shoulder": (-0.18, 0, 1.42),
        "r_shoulder": (0.18, 0, 1.42),
        "l_elbow": (-0.2, 0.05, 1.13),
        "r_elbow": (0.2, 0.05, 1.13),
        "l_wrist": (-0.2, 0.25, 1.0),
        "r_wrist": (0.22, 0.28, 1.02),
        "l_hip": (-0.1, 0, 0.92),
        "r_hip": (0.1, 0, 0.92),
        "l_knee": (-0.1, 0.02, 0.5),
        "r_knee": (0.1, 0.02, 0.5),
        "l_ankle": (-0.1, 0, 0.08),
        "r_ankle": (0.1, 0, 0.08),
    }
    y = np.array([base[j] for j in sk.joints], dtype=float)
    return y[None] + rng.normal(scale=0.02, size=(H,) + y.shape) + rng.normal(size=(H, 1, 3))


@pytest.mark.parametrize("kind", KINDS)
@pytest.mark.parametrize("seed", range(4))
def test_vel_and_iso_contain_speed_bounded_motion(kind: str, seed: int) -> None:
    rng = np.random.default_rng(seed)
    reach = _reach(kind)
    p = reach.params
    H = 16
    y_true = _pose(rng, kind, H)
    y_meas = y_true + _rand_ball(rng, y_true.shape, np.full(y_true.shape[:2], p.delta_y_m))
    occ = {m: reach.model(m, y_meas, None, None, T_START, T_END) for m in ("vel", "iso13855")}
    v_lim = {"vel": p.v_max_mps, "iso13855": np.full_like(p.v_max_mps, p.iso_v_max_mps)}
    for m, o in occ.items():
        J = y_true.shape[1]
        v0 = _rand_ball(rng, y_true.shape, np.broadcast_to(v_lim[m], y_true.shape[:2]))
        for k in range(len(T_START)):
            times = np.linspace(0, T_END[k] + p.delay_s, 60)
            paths = _simulate(rng, y_true, v0, np.full(J, 300.0), v_lim[m], times)
            sel = times >= T_START[k] + p.delay_s
            assert _check_contained(reach, m, o.ends, o.radius, paths[sel], k) <= 1e-12, m


@pytest.mark.parametrize("kind", KINDS)
@pytest.mark.parametrize("seed", range(4))
def test_acc_contains_acceleration_bounded_motion(kind: str, seed: int) -> None:
    rng = np.random.default_rng(100 + seed)
    reach = _reach(kind)
    p = reach.params
    H = 16
    y_true = _pose(rng, kind, H)
    v_true = _rand_ball(rng, y_true.shape, np.full(y_true.shape[:2], 3.0))  # any speed
    dv = np.full(y_true.shape[:2], 0.3)
    y_meas = y_true + _rand_ball(rng, y_true.shape, np.full(y_true.shape[:2], p.delta_y_m))
    v_meas = v_true + _on_sphere(rng, y_true.shape, dv)  # worst case: error at its bound
    o = reach.model("acc", y_meas, v_meas, dv, T_START, T_END)
    for k in range(len(T_START)):
        times = np.linspace(0, T_END[k] + p.delay_s, 80)
        paths = _simulate(rng, y_true, v_true, p.a_max_mps2, None, times)
        sel = times >= T_START[k] + p.delay_s
        assert _check_contained(reach, "acc", o.ends, o.radius, paths[sel], k) <= 1e-12


@pytest.mark.parametrize("kind", KINDS)
@pytest.mark.parametrize("seed", range(4))
def test_pos_contains_rigid_limbs_in_any_configuration(kind: str, seed: int) -> None:
    rng = np.random.default_rng(200 + seed)
    reach = _reach(kind)
    p = reach.params
    H = 32
    y_true = _pose(rng, kind, H)
    y_meas = y_true + _rand_ball(rng, y_true.shape, np.full(y_true.shape[:2], p.delta_y_m))
    o = reach.model("pos", y_meas, None, None, T_START, T_END)
    k = len(T_START) - 1
    for _ in range(20):
        fut = pos_future(rng, reach, y_true, T_END[k] + p.delay_s)
        assert _check_contained(reach, "pos", o.ends, o.radius, fut[None], k) <= 1e-12


def pos_future(rng: np.random.Generator, reach: HumanReach, y_true: np.ndarray, tau: float):
    """Joints ``(H, J, 3)`` at ``tau`` under R_POS's assumptions: a limb's root moves at most
    v_root tau and every segment keeps its true length at any angle; head and torso joints
    obey the vel model."""
    sk, p = reach.skeleton, reach.params
    H = y_true.shape[0]
    fut = y_true + _rand_ball(rng, y_true.shape, np.full(y_true.shape[:2], 2.0 * tau))
    for chain in sk.limb_chains:
        root = chain[0]
        fut[:, root] = y_true[:, root] + _on_sphere(
            rng, (H, 3), np.full(H, p.v_max_mps[root] * tau)
        )
        for a, b in zip(chain[:-1], chain[1:]):
            length = np.linalg.norm(y_true[:, b] - y_true[:, a], axis=-1)
            fut[:, b] = fut[:, a] + _on_sphere(rng, (H, 3), length)
    for j in ("head", "neck", "pelvis"):
        i = sk.joint_index(j)
        fut[:, i] = y_true[:, i] + _on_sphere(rng, (H, 3), np.full(H, p.v_max_mps[i] * tau))
    return fut


def test_sets_grow_with_age_and_delay() -> None:
    reach = _reach("full")
    y = _pose(np.random.default_rng(1), "full", 1)
    v = np.zeros_like(y)
    for m in MODELS:
        young = reach.model(m, y, v, None, [0.0], [0.1])
        old = reach.model(m, y, v, None, [0.05], [0.15])  # same horizon, measurement 50 ms older
        assert np.all(old.radius >= young.radius - 1e-12), m
        assert np.any(old.radius > young.radius), m


def test_every_joint_is_covered_by_every_model() -> None:
    for kind in KINDS:
        reach = _reach(kind)
        for m in MODELS:
            _, joint, _ = reach.coverage[m]
            assert set(joint.tolist()) == set(range(reach.skeleton.n_joints)), (kind, m)


@pytest.mark.parametrize(
    "bad, match",
    [
        (np.full((15, 3), np.nan), "not finite"),
        (np.zeros((14, 3)), "expected"),
        (np.zeros((2, 15, 2)), "expected"),
    ],
)
def test_bad_positions_raise_domain_errors(bad: np.ndarray, match: str) -> None:
    reach = _reach("full")
    with pytest.raises(InputError, match=match):
        reach.model("vel", bad, None, None, [0.0], [0.1])


def test_infinite_coordinate_named() -> None:
    reach = _reach("full")
    y = _pose(np.random.default_rng(0), "full", 1)
    y[0, 5, 1] = np.inf
    with pytest.raises(InputError, match="l_elbow"):
        reach.model("pos", y, None, None, [0.0], [0.1])


def test_bad_intervals_and_missing_velocities() -> None:
    reach = _reach("upper")
    y = _pose(np.random.default_rng(0), "upper", 1)
    with pytest.raises(InputError, match="start <= end"):
        reach.model("vel", y, None, None, [0.2], [0.1])
    with pytest.raises(InputError, match="velocities"):
        reach.model("acc", y, None, None, [0.0], [0.1])
    with pytest.raises(UnknownNameError, match="valid choices"):
        reach.model("nope", y, None, None, [0.0], [0.1])


def test_parameter_sets_are_complete_by_name() -> None:
    data = load_param_set("schepp2022_table1").model_dump()
    del data["joints"]["l_elbow"]
    with pytest.raises(ParameterError, match="l_elbow"):
        parse_param_set(data)
    data = load_param_set("schepp2022_table1").model_dump()
    data["body_parts"]["tail"] = data["body_parts"]["head"]
    with pytest.raises(ParameterError, match="tail"):
        parse_param_set(data)
    data = load_param_set("schepp2022_table1").model_dump()
    data["joints"]["head"]["v_max_mps"] = 0.0
    with pytest.raises(ParameterError, match="v_max_mps"):
        parse_param_set(data)
    with pytest.raises(UnknownNameError, match="schepp2022_table1"):
        load_param_set("no_such_set")


def test_models_give_the_same_sets_whatever_the_input_and_parameter_dtypes() -> None:
    """The model methods call their compiled code without numba's dispatch (kernel_types.entry),
    which would read an int64 or float32 array as if it were float64: every input dtype and
    layout, and parameters given as integers, must give the float64 result."""
    import dataclasses

    reach = _reach("full")
    rng = np.random.default_rng(3)
    y = np.round(_pose(rng, "full", 2) * 10)  # integral values: exact in every dtype below
    v = np.round(rng.normal(size=y.shape) * 2)
    dv = np.full(y.shape[:2], 1.0)
    ts, te = np.array([0.0, 1.0]), np.array([1.0, 2.0])

    def sets(y, v, dv, ts, te):  # type: ignore[no-untyped-def]
        """Every model's arrays, from the methods the hot paths call (no input checks)."""
        out = [reach.pos(y, te), reach.vel(y, te), reach.iso13855(y, te)]
        out += [reach.acc(y, v, dv, ts, te), reach.combined(y, v, dv, ts, te)]
        return [(o.model, o.ends.copy(), o.radius.copy()) for o in out]

    ref = sets(y, v, dv, ts, te)
    variants = [
        lambda a: a.astype(np.int64),
        lambda a: a.astype(np.float32),
        lambda a: a.astype(">f8"),
        lambda a: np.asfortranarray(a),
        lambda a: a.tolist(),
    ]
    args = (y, v, dv, ts, te)
    for make in variants:
        # all arguments converted, then each alone (the methods test the dtypes of all at once)
        for which in (range(5), *([i] for i in range(5))):
            got = sets(*(make(a) if i in which else a for i, a in enumerate(args)))
            for (m, ends, radius), (_, want_ends, want_radius) in zip(got, ref):
                np.testing.assert_array_equal(ends, want_ends, err_msg=f"{m}, {list(which)}")
                np.testing.assert_array_equal(radius, want_radius, err_msg=f"{m}, {list(which)}")
    p = reach.params
    as_int = dataclasses.replace(
        p, v_max_mps=np.ceil(p.v_max_mps).astype(np.int64),
        a_max_mps2=np.ceil(p.a_max_mps2).astype(np.int64),
    )  # fmt: skip
    as_float = dataclasses.replace(
        p, v_max_mps=np.ceil(p.v_max_mps), a_max_mps2=np.ceil(p.a_max_mps2)
    )
    r_int, r_float = HumanReach(as_int), HumanReach(as_float)
    for m in ("pos", "vel", "acc", "combined"):
        a, b = r_int.model(m, y, v, dv, ts, te), r_float.model(m, y, v, dv, ts, te)
        np.testing.assert_array_equal(a.radius, b.radius, err_msg=m)
        np.testing.assert_array_equal(a.ends, b.ends, err_msg=m)


@pytest.mark.parametrize("kind", ["full", "upper"])
def test_people_sets_are_each_persons_own_model_set(kind: str) -> None:
    """Every model over several people at once, each on the interval from their own
    measurement, equals the model on that person alone (the compiled kernels are the checks'
    own); a wrong number of ages is a domain error."""
    reach = _reach(kind)
    rng = np.random.default_rng(8)
    H, J = 5, reach.skeleton.n_joints
    y = rng.normal(scale=0.5, size=(H, J, 3))
    v = rng.normal(size=(H, J, 3))
    dv = rng.uniform(0.0, 0.1, (H, J))
    age = rng.uniform(0.0, 0.1, H)
    for name in MODELS:
        ends, radius = reach.people_sets(name, y, v, dv, age, 0.2)
        for h in range(H):
            one = reach.model(name, y[h : h + 1], v[h : h + 1], dv[h : h + 1], age[h : h + 1],
                              age[h : h + 1] + 0.2)  # fmt: skip
            np.testing.assert_array_equal(ends[h], one.ends[0, 0])
            np.testing.assert_array_equal(radius[h], one.radius[0, 0])
    with pytest.raises(InputError, match="age_s"):
        reach.people_sets("vel", y, v, dv, age[:2], 0.2)


def test_people_sets_refuse_what_model_refuses_and_take_what_it_takes() -> None:
    """The quick whole-array checks of ``people_sets`` fall back on the detailed ones: a
    non-finite joint, velocity or age is named; one velocity bound per joint (broadcast over the
    people) gives the sets of the bounds written out."""
    reach = _reach("full")
    rng = np.random.default_rng(9)
    H, J = 3, reach.skeleton.n_joints
    y, v = rng.normal(size=(H, J, 3)), rng.normal(size=(H, J, 3))
    dv, age = np.full((H, J), 0.05), np.array([0.0, 0.01, 0.02])
    bad_y = y.copy()
    bad_y[1, 4, 2] = np.nan
    with pytest.raises(InputError, match="not finite"):
        reach.people_sets("vel", bad_y, v, dv, age, 0.1)
    bad_v = v.copy()
    bad_v[0, 0, 0] = np.inf
    with pytest.raises(InputError, match="velocities are not finite"):
        reach.people_sets("acc", y, bad_v, dv, age, 0.1)
    reach.people_sets("vel", y, bad_v, dv, age, 0.1)  # not read by the velocity bound
    with pytest.raises(InputError, match="finite"):
        reach.people_sets("pos", y, v, dv, np.array([0.0, np.nan, 0.0]), 0.1)
    with pytest.raises(InputError, match="0 <= start"):
        reach.people_sets("pos", y, v, dv, age, -0.5)
    one = reach.people_sets("acc", y, v, np.full(J, 0.05), age, 0.1)
    full = reach.people_sets("acc", y, v, dv, age, 0.1)
    np.testing.assert_array_equal(one[1], full[1])
