"""The tracking quality gate: no flag on clean motion, every scripted glitch flagged, and the
gated skeleton always contains the true joints (held joints widened soundly)."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from sara_app.errors import ParameterError
from sara_app.human.gate import FLAGS, Gate, enclose
from sara_app.human.glitches import Glitches
from sara_app.human.intake import Intake
from sara_app.human.recordings import load_recording
from sara_app.human.tracking_settings import GateSettings
from sara_app.scenario import GateSpec, GlitchSpec

DY = 0.004
V_MAX = np.full(15, 2.0)
RATE_HZ = 60.0


def _walk(seed: int, T: int = 240) -> tuple[np.ndarray, np.ndarray]:
    """A rigid skeleton (the shipped clip's first pose) translated and turned along a random
    path within 1.2 m/s and 15 m/s^2: times ``(T,)`` and true joints ``(T, 15, 3)``."""
    rng = np.random.default_rng(seed)
    pose = load_recording("02_01").positions_m[0]
    pose = pose - pose.mean(axis=0)
    dt = 1.0 / RATE_HZ
    acc = np.repeat(rng.uniform(-1, 1, (T // 6 + 1, 3)) * 8.0, 6, axis=0)[:T]
    acc[:, 2] = 0.0
    v = np.cumsum(acc * dt, axis=0)
    v *= np.minimum(1.0, 0.8 / np.maximum(np.linalg.norm(v, axis=1), 1e-9))[:, None]
    x = np.cumsum(v * dt, axis=0)
    yaw = np.cumsum(rng.uniform(-0.3, 0.3, T)) * dt  # at most 0.3 rad/s: joints < 0.4 m/s more
    c, s = np.cos(yaw), np.sin(yaw)
    R = np.zeros((T, 3, 3))
    R[:, 0, 0], R[:, 0, 1], R[:, 1, 0], R[:, 1, 1], R[:, 2, 2] = c, -s, s, c, 1.0
    y = np.einsum("tab,jb->tja", R, pose) + x[:, None, :]
    return np.arange(T) * dt, y


def _noisy(y: np.ndarray, seed: int) -> np.ndarray:
    rng = np.random.default_rng(seed + 100)
    n = rng.normal(size=y.shape)
    n *= DY * rng.random(y.shape[:-1] + (1,)) / np.linalg.norm(n, axis=-1, keepdims=True)
    return y + n


def _run(t, y_meas, y_true, settings=None, n_measured=15):
    gate = Gate(V_MAX, settings or GateSettings())
    flags, held, refused = [], [], []
    for k in range(len(t)):
        g = gate.check(float(t[k]), y_meas[k], DY, n_measured)
        # soundness: every true joint lies within delta_y + extra of the gated joint
        err = np.linalg.norm(y_true[k] - g.y, axis=1)
        assert np.all(err <= DY + g.extra_m + 1e-9), (k, err - DY - g.extra_m)
        flags.append(g.flags.copy())
        held.append(~g.trusted)
        refused.append(g.refused)
    return gate, np.array(flags), np.array(held), np.array(refused)


@pytest.mark.parametrize("seed", range(4))
def test_clean_motion_is_never_flagged(seed: int) -> None:
    t, y = _walk(seed)
    gate, flags, held, refused = _run(t, _noisy(y, seed), y)
    assert not flags.any() and not held.any() and not refused.any()
    assert not np.isnan(gate.length_m).any()  # learned from the first frames


def _glitched(kind: str, seed: int = 0, **kw: object):
    t, y = _walk(seed)
    spec = GlitchSpec(kind=kind, joint="l_wrist", start_s=1.0, **kw)  # type: ignore[arg-type]
    g = Glitches([spec])
    meas = np.array([g.apply(float(tk), yk) for tk, yk in zip(t, _noisy(y, seed))])
    on = (t >= 1.0) & (t < 1.0 + spec.duration_s)
    return t, y, meas, on


def test_a_swap_is_held_soundly_and_trusted_again_after_it() -> None:
    t, y, meas, on = _glitched("swap", other="head", duration_s=0.3)
    gate, flags, held, refused = _run(t, meas, y)
    j = 7  # l_wrist
    assert flags[on, j, FLAGS.index("bone")].all()
    assert held[on, j].all() and not held[~on, j].any()
    assert not held[:, np.arange(15) != j].any()  # the elbow is not blamed
    assert gate.counts["bone"] == on.sum()
    assert not refused.any()


def test_a_frozen_joint_is_held_from_its_first_repeat() -> None:
    t, y, meas, on = _glitched("freeze", duration_s=0.3)
    gate, flags, held, _ = _run(t, meas, y)
    first = np.flatnonzero(on)[0]
    frozen = flags[:, 7, FLAGS.index("frozen")]
    assert frozen[first + 1 : np.flatnonzero(on)[-1] + 1].all() and not frozen[~on].any()
    assert gate.counts["frozen"] == on.sum() - 1


def test_a_spike_along_its_bone_is_held_and_its_set_holds_both_positions() -> None:
    """Along its bone a spike cannot be told from real motion: held (flagged ``jump``, with the
    speed it needed for the monitor), and its set encloses both the history and the spike."""
    t, y, meas, on = _glitched("spike", offset_m=(0.0, 0.0, 0.0), duration_s=0.02)
    _, flags, _, _ = _run(t, meas, y)
    assert not flags.any()  # a zero spike is no glitch
    t, y = _walk(1)
    meas = _noisy(y, 1)
    k = 80
    bone = y[k, 7] - y[k, 5]  # l_elbow -> l_wrist
    side = np.cross(bone, [1.0, 0.0, 0.0])
    meas[k, 7] = y[k, 7] + 0.1 * side / np.linalg.norm(side)  # 0.1 m across: length +2.5 cm
    gate = Gate(V_MAX)
    for i in range(len(t)):
        g = gate.check(float(t[i]), meas[i], DY, 15)
        if i == k:
            assert g.flags[7, FLAGS.index("jump")] and not g.trusted[7]
            assert g.jump_speed_mps[7] > V_MAX[7]
            # the measurement is kept: the spike lies in the joint's set as well as the truth
            for point in (meas[k, 7], y[k, 7]):
                assert np.linalg.norm(point - g.y[7]) <= DY + g.extra_m[7] + 1e-12
        elif i == k + 1:
            assert g.trusted.all()  # history and measurement agree again


def test_a_whole_skeleton_jump_keeps_both_places_until_they_agree() -> None:
    """A person measured 2.5 m away from one frame to the next: every joint's set holds the
    old place (grown at v_max) and the new one until the new one is within reach of the old
    one; no joint's velocity is estimated across the jump meanwhile."""
    t, y = _walk(3)
    y[:] = y[0]  # standing still
    meas = _noisy(y, 3)
    k = 60
    meas[k:] += [2.5, 0.0, 0.0]
    gate = Gate(V_MAX, GateSettings(max_hold_s=5.0))
    seen_agreement = False
    for i in range(len(t)):
        g = gate.check(float(t[i]), meas[i], DY, 15)
        if i < k:
            continue
        lag = t[i] - t[k - 1]
        agree = 2.5 + 0.05 <= 2 * DY + 2.0 * lag  # surely within reach
        if 2.5 - 0.05 > 2 * DY + 2.0 * lag:  # surely not
            assert not g.trusted.any() and g.flags[:, FLAGS.index("jump")].all()
            # the new place (measured), the old one (measured, and here the truth) are kept
            for points in (meas[i], y[i], meas[k - 1]):
                err = np.linalg.norm(points - g.y, axis=1)
                assert np.all(err <= DY + g.extra_m + 1e-9)
        elif agree:
            assert g.trusted.all() and not g.extra_m.any()
            seen_agreement = True
    assert seen_agreement


@settings(max_examples=300, deadline=None)
@given(
    st.lists(st.floats(-2, 2), min_size=6, max_size=6),
    st.floats(0, 1), st.floats(0, 1), st.booleans(), st.integers(0, 2**31),
)  # fmt: skip
def test_enclose_contains_both_balls_and_is_no_larger_than_needed(
    xs: list[float], r1: float, r2: float, missing: bool, seed: int
) -> None:
    c1, c2 = np.array([xs[:3]]), np.array([xs[3:]])
    R2 = np.array([-np.inf if missing else r2])
    c, R = enclose(c1, np.array([r1]), c2, R2)
    rng = np.random.default_rng(seed)
    u = rng.normal(size=(200, 3))
    u /= np.linalg.norm(u, axis=1, keepdims=True)
    balls = [(c1[0], r1)] + ([] if missing else [(c2[0], r2)])
    for centre, r in balls:  # the far side of each ball, and random boundary points
        off = centre - c[0]
        n = np.linalg.norm(off)
        far = [centre + r * off / n] if n > 1e-9 else []
        for p in np.vstack([*far, centre + r * u]):
            assert np.linalg.norm(p - c[0]) <= R[0] + 1e-9
    d = np.linalg.norm(c2 - c1)
    smallest = r1 if missing else max(r1, r2, (d + r1 + r2) / 2)  # the diameter needs it
    assert R[0] <= smallest + 1e-12


def test_a_joint_held_too_long_refuses_the_frame() -> None:
    t, y, meas, on = _glitched("swap", other="head", duration_s=1.0)
    _, _, held, refused = _run(t, meas, y, GateSettings(max_hold_s=0.5))
    hold_s = t[on] - t[on][0]
    assert refused[on].tolist() == (hold_s > 0.5 + 1e-9).tolist()
    assert not refused[~on].any()


def test_an_upper_body_source_leaves_the_legs_unchecked() -> None:
    t, y = _walk(2)
    meas = _noisy(y, 2)
    meas[:, 9:] = 0.0  # placeholders, all at one point: bones of length 0, never moving
    gate = Gate(V_MAX)
    for k in range(len(t)):
        g = gate.check(float(t[k]), meas[k], DY, 9)
        assert g.trusted.all() and not g.flags.any()


def test_settings_are_checked() -> None:
    with pytest.raises(ParameterError, match="max_hold_s"):
        GateSettings(max_hold_s=0.0)


def test_bone_lengths_from_the_scenario_are_checked_from_the_first_frame() -> None:
    """A known forearm length: a wrist swapped to the head in the person's FIRST frames (before
    anything could be learned) is flagged; a wrong known length is flagged at once too."""
    t, y = _walk(3)
    meas = _noisy(y, 3)
    forearm = float(np.linalg.norm(y[0, 7] - y[0, 5]))
    meas[2:6, 7] = meas[2:6, 0]  # frames 2-5: l_wrist at the head
    spec = GateSpec(bone_lengths_m={"l_elbow-l_wrist": forearm})
    gate = Gate(V_MAX, spec.intake().gate)
    flags = [gate.check(float(t[k]), meas[k], DY, 15).flags[7, FLAGS.index("bone")]
             for k in range(8)]  # fmt: skip
    assert flags == [False, False, True, True, True, True, False, False]
    wrong = GateSpec(bone_lengths_m={"l_elbow-l_wrist": forearm + 0.3}).intake().gate
    g = Gate(V_MAX, wrong).check(0.0, meas[0], DY, 15)
    assert g.flags[:, FLAGS.index("bone")].any()
    with pytest.raises(ValueError, match="unknown bone 'l_wrist-l_elbow'"):
        GateSpec(bone_lengths_m={"l_wrist-l_elbow": 0.25})


def test_the_present_state_names_the_held_joint_why_and_since_when() -> None:
    """What the operator sees of tracking (``Intake.now``): during a swap the wrist is held
    for its bone since the glitch's first frame; after it every joint is trusted and the newest
    flag is the glitch's last frame; a clean person was never flagged."""
    t, y, meas, on = _glitched("swap", other="head", duration_s=0.3)
    intake = Intake(DY, V_MAX, np.full(15, 1e3))
    first, last = t[on][0], t[on][-1]
    for k in range(len(t)):
        intake.take(float(t[k]), meas[k], DY, 15)
        now = intake.now()
        if on[k]:
            assert now is not None and now.held == (("l_wrist", "bone", first),), now
        elif t[k] < first:
            assert now is None
        else:
            assert now is not None and now.held == () and now.last_flag == ("l_wrist", "bone", last)
    clean = Intake(DY, V_MAX, np.full(15, 1e3))
    tc, yc = _walk(1)
    for k in range(len(tc)):
        clean.take(float(tc[k]), _noisy(yc, 1)[k], DY, 15)
    assert clean.now() is None
