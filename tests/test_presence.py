"""Presence: tracker liveness, people known on any evidence and forgotten only on positive
evidence (every declared tracker's later frame omits them, or a retire), bounded capacity."""

from __future__ import annotations

import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st

from sara_app.cell.intake import unmeasured_track
from sara_app.runtime.presence import CONFLICT_HOLD_S, FORGET_AFTER_S, Presence

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
    p.frame("main", 2.1, ["h0"])  # no tracker has listed h1-h4: none saw them leave
    assert len(p.tracks) + len(p.overflow) == 5
    p.frame("main", 2.2, [f"h{i}" for i in range(5)])
    p.frame("main", 2.3, ["h0"])
    assert list(p.tracks) == ["h0"] and not p.overflow
    assert not any("max_people" in f for f in p.faults(2.3))


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
    omit them and a tracker had listed them since they became known (it saw them leave); and
    then they are unknown."""
    p = _presence(("a", "b"), max_people=8)
    evidence: dict[str, float] = {}
    listed: set[str] = set()  # listed by a frame since they became known (this oracle's own)

    def omitted(hid: str) -> bool:
        frames = [p.frames.get(tid) for tid in ("a", "b")]
        return hid in listed and all(
            f is not None and f.stamp_s >= evidence[hid] + FORGET_AFTER_S
            and hid not in f.people for f in frames
        )  # fmt: skip

    t = 0.0
    for kind, hid, dt, people in events:
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
                evidence.pop(hid, None)
                listed.discard(hid)
        else:
            p.frame(kind[-1], t, people)
            for h in people:
                evidence[h] = t
                listed.add(h)
        for h in [h for h in evidence if omitted(h)]:  # forgotten by this frame: known anew
            assert h not in p.tracks, (h, evidence[h], p.frames)  # by a later one
            del evidence[h]
            listed.discard(h)
    for hid in evidence:
        assert hid in p.tracks, (hid, evidence[hid], p.frames)


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


def test_a_person_no_tracker_listed_is_not_forgotten_by_frames() -> None:
    """Skeletons from a source no frame vouches for (a second program publishing people next
    to the replayer): the frames omit the person from the start, so they never saw them leave;
    the person stays known (a fault once unseen) until listed and omitted, or retired."""
    p = _presence()
    p.known("me", 1.0, 1.0)
    for k in range(1, 30):
        p.frame("main", 1.0 + k * 0.1, ["replayed"])
    assert "me" in p.tracks
    assert p.retire("me", 4.0) == ""


def test_frames_received_while_a_persons_messages_keep_arriving_forget_nobody() -> None:
    """Skeletons stamped 60 ms late (a slow pipeline) but arriving every cycle: a frame that
    omits the person is stamped more than the margin after their evidence, yet received with
    their stream still going: it does not forget them; once their messages stop, it does."""
    p = _presence()
    p.frame("main", 0.0, ["h1"], 0.0)
    t = 0.0
    for _ in range(100):
        t += 0.016
        p.known("h1", t - 0.06, t)  # received now, stamped 60 ms ago
        p.frame("main", t, [], t)  # the tracker's frame omits them
        assert "h1" in p.tracks
    t += 0.04
    p.frame("main", t, [], t)
    assert "h1" in p.tracks  # 40 ms after their last message: within the margin
    t += 0.02
    p.frame("main", t, [], t)
    assert "h1" not in p.tracks


def test_refused_frames_make_the_tracker_a_fault_that_forgets_nobody() -> None:
    """Two publishers on one tracker id: the second's frames are refused (out of order). The
    tracker is a fault while that goes on and for ``CONFLICT_HOLD_S`` after, and its accepted
    frames forget nobody meanwhile."""
    p = _presence()
    p.frame("main", 1.0, ["me"], 1.0, seq=10**9)
    p.known("me", 1.0, 1.0)
    assert p.faults(1.01) == []
    # one publisher whose clock stood still (seq advancing): dropped, no conflict
    assert p.frame("main", 1.0, ["me"], 1.005, seq=10**9 + 1) == "out_of_order"
    assert p.faults(1.01) == []
    p.frame_refused("main", 1.05)  # the other publisher's frame (a lower seq)
    assert any("two publishers" in f for f in p.faults(1.06))
    p.frame("main", 1.2, [], 1.2, seq=10**9 + 1)  # omits "me": in conflict, forgets nobody
    assert "me" in p.tracks
    assert any("two publishers" in f for f in p.faults(1.05 + CONFLICT_HOLD_S - 0.01))
    assert not any("two publishers" in f for f in p.faults(1.05 + CONFLICT_HOLD_S + 0.01))
    p.frame("main", 1.05 + CONFLICT_HOLD_S + 0.02, [], 1.05 + CONFLICT_HOLD_S + 0.02,
            seq=10**9 + 2)  # fmt: skip
    assert "me" not in p.tracks  # listed before, omitted now, no conflict: they left
    assert p.frame("intruder", 9.0, []) == "unknown_tracker"
    p.frame_refused("intruder", 9.0)  # an undeclared tracker's refusal is nobody's fault
    assert not any("intruder" in f for f in p.faults(9.0))


def test_a_restarted_tracker_did_not_see_anyone_leave() -> None:
    """A tracker's new stream (its seq started again) lists nobody at first: the people it
    listed before stay known until it lists them again and then omits them, or a retire."""
    p = _presence()
    p.frame("main", 1.0, ["h1", "h2"], 1.0, seq=500)
    p.frame("main", 3.0, [], 3.0, seq=0)  # restarted (the contract's 1 s rule let it in)
    assert set(p.tracks) == {"h1", "h2"}
    p.frame("main", 3.1, ["h2"], 3.1, seq=1)  # sees h2 again
    p.frame("main", 3.2, [], 3.2, seq=2)
    assert set(p.tracks) == {"h1"}  # h2 left in view of the new stream; h1 not known to it
    assert p.retire("h1", 3.3) == ""
