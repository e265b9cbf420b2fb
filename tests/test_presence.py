"""Presence: tracker liveness, people known on any evidence and forgotten only on positive
evidence (every declared tracker's later frame omits them, or a retire), bounded capacity."""

from __future__ import annotations

import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st

from sara_app.cell.intake import unmeasured_track
from sara_app.runtime.presence import FORGET_AFTER_S, Presence

A_MAX = np.full(15, 50.0)
V_MAX = np.full(15, 2.0)


def _presence(trackers=("main",), max_people: int = 4) -> Presence:
    return Presence(
        tuple(trackers),
        0.2,
        max_people,
        lambda h: unmeasured_track(h, 0.004, V_MAX, A_MAX),
    )


def test_a_silent_or_missing_tracker_is_a_fault() -> None:
    p = _presence(("a", "b"))
    assert len(p.faults(10.0)) == 2  # nobody spoke: not an empty cell
    p.frame("a", 10.0, [])
    assert [f for f in p.faults(10.05) if "'b'" in f]
    p.frame("b", 10.05, [])
    assert p.faults(10.1) == []
    assert any("old" in f for f in p.faults(10.3))  # a went silent
    p.frame("a", 10.31, [])
    assert any("future" in f for f in p.faults(10.30))  # clocks disagree
    assert p.frame("intruder", 10.3, []) == "unknown_tracker"


def test_forgotten_only_when_every_tracker_omits_them_after_their_evidence() -> None:
    p = _presence(("a", "b"))
    p.known("h1", 5.0)  # a skeleton stamped 5.0
    p.frame("a", 4.9, [])  # older than the evidence: proves nothing
    p.frame("b", 4.9, [])
    assert "h1" in p.tracks
    p.frame("a", 5.1, [])
    assert "h1" in p.tracks  # b has not spoken since
    p.frame("b", 5.1, ["h1"])  # b still sees them
    assert "h1" in p.tracks and p.tracks["h1"].evidence_s == 5.1
    p.frame("a", 5.12, [])
    p.frame("b", 5.12, [])
    assert "h1" in p.tracks  # too soon after their last evidence: their stream may go on
    p.frame("a", 5.2, [])
    p.frame("b", 5.2, [])
    assert "h1" not in p.tracks
    p.frame("a", 5.3, ["h2"])  # listed: known (and unmeasured: a fault for the shield)
    assert p.tracks["h2"].state.stamp_s is None


def test_a_refused_message_makes_the_person_known_and_a_retire_forgets() -> None:
    p = _presence()
    p.frame("main", 1.0, [])
    p.refused("ghost", 1.5)
    assert p.tracks["ghost"].state.stamp_s is None  # known, unseen
    p.frame("main", 1.4, [])  # out of order: stamp not newer than the last frame
    assert "ghost" in p.tracks
    assert "still reported" in p.retire("ghost", 1.6)  # its stream went on 0.1 s ago
    assert "ghost" in p.tracks
    assert p.retire("ghost", 1.71) == "" and "ghost" not in p.tracks
    assert "not known" in p.retire("ghost", 1.8)


def test_a_person_a_tracker_still_reports_is_not_retired() -> None:
    """Retire is for a person no tracker reports any more: while skeletons or frames listing
    them keep coming (newest evidence within the trackers' timeout), it is refused."""
    p = _presence(max_people=1)
    p.frame("main", 1.0, [])
    p.known("h1", 1.0)
    assert "still reported" in p.retire("h1", 1.0)
    assert "still reported" in p.retire("h1", 1.2)  # at the timeout: still
    p.frame("main", 1.15, ["h1"])  # a frame lists them: evidence renewed
    assert "still reported" in p.retire("h1", 1.3)
    assert "h1" in p.tracks
    assert "still reported" in p.retire("h1", float("nan"))  # no clock: no retire
    assert p.retire("h1", 1.36) == "" and "h1" not in p.tracks
    p.known("h2", 2.0)
    p.known("h3", 2.0)  # the cell is full: an id in the overflow, same rule
    assert "h3" in p.overflow and "still reported" in p.retire("h3", 2.1)
    assert p.retire("h3", 2.3) == "" and "h3" not in p.overflow


def test_overflow_is_a_fault_until_forgotten() -> None:
    p = _presence(max_people=2)
    p.frame("main", 1.0, [])
    made = [p.known(f"h{i}", 2.0) for i in range(5)]
    assert sum(m is not None for m in made) == 2 and len(p.overflow) == 3
    assert any("max_people" in f for f in p.faults(2.0))
    p.frame("main", 2.1, ["h0"])
    assert list(p.tracks) == ["h0"] and not p.overflow
    assert not any("max_people" in f for f in p.faults(2.1))


def test_configure_keeps_people_and_moves_extra_tracks_to_the_overflow() -> None:
    p = _presence(max_people=3)
    for i in range(3):
        p.known(f"h{i}", 1.0)
    p.configure(("main",), 0.2, 1, p.new_track)
    assert len(p.tracks) == 1 and len(p.overflow) == 2
    assert any("max_people" in f for f in p.faults(1.0))


@settings(max_examples=200, deadline=None)
@given(
    st.lists(
        st.tuples(
            st.sampled_from(["skel", "refuse", "frame_a", "frame_b", "retire"]),
            st.sampled_from(["h1", "h2", "h3"]),
            st.floats(0.0, 0.3),
            st.sets(st.sampled_from(["h1", "h2", "h3"])),
        ),
        max_size=40,
    )
)
def test_forgetting_needs_positive_evidence(events) -> None:
    """Brute force: after any event sequence, a person is unknown only if retired after their
    last evidence, or if both trackers' newest frames are ``FORGET_AFTER_S`` later than it and
    omit them."""
    p = _presence(("a", "b"), max_people=8)
    evidence: dict[str, float] = {}
    retired_at: dict[str, int] = {}
    t = 0.0
    for i, (kind, hid, dt, people) in enumerate(events):
        t += dt + 1e-3
        if kind == "skel":
            p.known(hid, t)
            evidence[hid] = t
        elif kind == "refuse":
            p.refused(hid, t)
            evidence[hid] = t
        elif kind == "retire":
            fresh = hid in evidence and t - evidence[hid] <= 0.2
            if p.retire(hid, t) == "":
                assert not fresh, (hid, t, evidence[hid])  # never a person still reported
                retired_at[hid] = i
                evidence.pop(hid, None)
        else:
            p.frame(kind[-1], t, people)
            for h in people:
                evidence[h] = t
    for hid, ev in evidence.items():
        frames = [p.frames.get(tid) for tid in ("a", "b")]
        omitted = all(
            f is not None and f.stamp_s >= ev + FORGET_AFTER_S and hid not in f.people
            for f in frames
        )
        assert (hid in p.tracks) == (not omitted), (hid, ev, p.frames)


def test_a_full_overflow_list_faults_until_every_tracker_has_spoken_since() -> None:
    from sara_app.runtime.presence import MAX_OVERFLOW

    p = _presence(("a", "b"), max_people=1)
    p.frame("a", 1.0, [])
    p.frame("b", 1.0, [])
    for i in range(MAX_OVERFLOW + 5):
        p.known(f"h{i}", 2.0)
    assert len(p.overflow) == MAX_OVERFLOW
    p.retire("h0", 2.5)
    for h in list(p.overflow):
        p.retire(h, 2.5)
    assert not p.tracks and not p.overflow
    assert any("max_people" in f for f in p.faults(2.0))  # dropped ids: not forgotten yet
    p.frame("a", 2.1, [])
    assert any("max_people" in f for f in p.faults(2.1))
    p.frame("b", 2.1, [])
    assert not any("max_people" in f for f in p.faults(2.1))
