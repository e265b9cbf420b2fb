"""Who is in the cell: tracker liveness and one track per person, forgotten on positive evidence
only (DESIGN 8, "positive evidence only").

A tracker frame (``TrackerFrameMsg``) says which people one tracker sees at its stamp. Rules:

- **Liveness.** The robot may move only while every tracker the scenario declares has sent a
  frame within ``tracker_timeout_s`` (and none from the future): a silent tracker is a fault.
  Silence is never an empty cell.
- **Known people.** A person becomes known by any evidence: a skeleton on their key (accepted
  or refused), or a frame that lists them. A known person without a usable, fresh skeleton is a
  fault (the shield's "no measurement" / "old" rules), so a refused message counts as that
  person unseen.
- **Forgetting.** A person is forgotten only when every declared tracker has sent a frame,
  stamped at least ``FORGET_AFTER_S`` after the person's newest evidence and received at least
  ``FORGET_AFTER_S`` after the newest message on their key, that does not list them, and a
  tracker whose frames listed them since they became known (in its current stream) is among
  them: that tracker saw them leave. Or when an operator retires them. Never on a scenario
  edit (the presence object outlives cells), never on a timeout. The two margins: while
  messages keep arriving on a person's key, even refused ones or ones stamped late (a slow
  skeleton pipeline), a tracker's frame that omits them contradicts the stream and does not
  forget them. "Saw them leave": a person no tracker ever listed (skeletons from a source no
  frame vouches for) and the people a tracker knew before it restarted (its new stream does
  not know who left meanwhile: a restarted tracker's first, empty frames forgot everyone) stay
  known, a fault once unseen, until a tracker lists them again or an operator retires them.
- **Contradictory frames.** A frame the decoder refused on a declared tracker's key (its
  ``seq`` out of order: two publishers on one tracker id, such as a second tracker started
  with the replayer's id; or malformed) makes that tracker a fault for ``CONFLICT_HOLD_S``
  and its frames forget nobody meanwhile: whichever publisher's frames are accepted, the
  other's people are not its to forget (hostile-tracker probe, 2026-11-30). A frame whose
  stamp does not advance on an advancing ``seq`` (one publisher's clock) is dropped only.
- **Bounded.** At most ``max_people`` tracks; further people are kept as ids only (at most
  ``MAX_OVERFLOW``) and the cell faults while any is known. Over ``MAX_OVERFLOW`` ids the oldest
  id is dropped from the list (each frame checks every id: the list is kept short); the fault
  then also stays until every declared tracker has sent a frame ``FORGET_AFTER_S`` after the
  drop (its frames list everyone it sees: a dropped id still in view is known again).

``Presence`` is plain Python with small per-message work; the worker calls it from its loop.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Iterable
from dataclasses import dataclass, field

from sara_app.cell.intake import Track
from sara_app.human.conformance import Violation
from sara_app.human.intake import TrackingNow
from sara_app.safety.settings import FUTURE_TOLERANCE_S
from sara_app.safety.shield import HumanState

FORGET_AFTER_S = 0.05
"""How much later than a person's newest evidence a frame that omits them must be stamped, and
than the newest message on their key it must be received."""
CONFLICT_HOLD_S = 1.0
"""How long a refused frame on a declared tracker's key keeps that tracker a fault (and its
frames from forgetting anyone): as long as the contract's restart rule lets a second publisher's
stream take over (a frame 1 s newer than the last accepted one)."""
MAX_OVERFLOW = 256
"""Ids of people beyond ``max_people`` remembered (each is a fault until forgotten)."""


@dataclass
class _Frame:
    stamp_s: float
    people: frozenset[str]
    arrived_s: float
    seq: int | None


@dataclass
class Presence:
    """People and trackers of one cell. ``new_track(human_id)`` builds an unmeasured track."""

    trackers: tuple[str, ...]
    tracker_timeout_s: float
    max_people: int
    new_track: Callable[[str], Track]
    future_tolerance_s: float = FUTURE_TOLERANCE_S
    tracks: dict[str, Track] = field(default_factory=dict)
    overflow: dict[str, float] = field(default_factory=dict)
    frames: dict[str, _Frame] = field(default_factory=dict)
    dropped_s: float = -math.inf
    """The newest evidence of an id dropped from the full overflow list."""
    arrived: dict[str, float] = field(default_factory=dict)
    """Per known person, when the newest message on their key was received (cell time)."""
    listed_by: dict[str, set[str]] = field(default_factory=dict)
    """Per known person, the trackers whose current stream listed them since they became
    known."""
    conflict_s: dict[str, float] = field(default_factory=dict)
    """Per tracker, when a frame on its key was last refused (cell time)."""

    def configure(
        self,
        trackers: Iterable[str],
        tracker_timeout_s: float,
        max_people: int,
        new_track: Callable[[str], Track],
    ) -> None:
        """A scenario edit: new trackers, bounds and track factory; every person stays known.
        Tracks beyond a lower ``max_people`` move to the overflow (a fault until forgotten)."""
        self.trackers = tuple(trackers)
        self.tracker_timeout_s = float(tracker_timeout_s)
        self.max_people = int(max_people)
        self.new_track = new_track
        for tid in [t for t in self.frames if t not in self.trackers]:
            del self.frames[tid]
        for listed in self.listed_by.values():  # only a declared tracker saw anyone leave
            listed.intersection_update(self.trackers)
        while len(self.tracks) > self.max_people:
            hid = next(reversed(self.tracks))
            self._overflow(hid, self.tracks.pop(hid).evidence_s)

    # -- evidence --------------------------------------------------------------------------------

    def _overflow(self, human_id: str, evidence_s: float) -> None:
        if human_id not in self.overflow and len(self.overflow) >= MAX_OVERFLOW:
            gone, dropped_s = self.overflow.popitem()  # the newest entry: its id is gone
            self.arrived.pop(gone, None)
            self.listed_by.pop(gone, None)
            self.dropped_s = max(self.dropped_s, dropped_s, evidence_s)
        self.overflow[human_id] = max(self.overflow.get(human_id, -math.inf), evidence_s)

    def known(
        self, human_id: str, evidence_s: float, arrived_s: float | None = None
    ) -> Track | None:
        """The track of ``human_id`` (created when new), its evidence time raised to
        ``evidence_s``; ``arrived_s``: a message on their key was received then (cell time;
        None: a frame listed them); None when the cell is full (the id is kept in the
        overflow)."""
        if arrived_s is not None:
            self.arrived[human_id] = max(self.arrived.get(human_id, -math.inf), arrived_s)
        tr = self.tracks.get(human_id)
        if tr is None:
            if len(self.tracks) >= self.max_people:
                self._overflow(human_id, evidence_s)
                return None
            tr = self.tracks[human_id] = self.new_track(human_id)
            self.overflow.pop(human_id, None)
        tr.evidence_s = max(tr.evidence_s, evidence_s)
        return tr

    def refused(self, human_id: str, now_s: float) -> None:
        """A message on ``human_id``'s key was refused: that person is known and unseen."""
        self.known(human_id, now_s, now_s)

    def frame(
        self,
        tracker_id: str,
        stamp_s: float,
        people: Iterable[str],
        arrived_s: float | None = None,
        seq: int | None = None,
    ) -> str | None:
        """Take a tracker frame (received at cell time ``arrived_s``, default its stamp;
        ``seq`` not above the last one's: the tracker restarted, a new stream); returns a drop
        reason (``unknown_tracker``, ``out_of_order``) or None."""
        if tracker_id not in self.trackers:
            return "unknown_tracker"
        arrived = stamp_s if arrived_s is None else arrived_s
        seen = frozenset(people)
        old = self.frames.get(tracker_id)
        if old is not None and stamp_s <= old.stamp_s:  # one publisher's clock stood still
            return "out_of_order"  # (two publishers: the decoder refuses one's seq first)
        if old is not None and seq is not None and old.seq is not None and seq <= old.seq:
            for trackers in self.listed_by.values():  # a new stream: who left is not known
                trackers.discard(tracker_id)
        self.frames[tracker_id] = _Frame(stamp_s, seen, arrived, seq)
        for hid in seen:
            if self.known(hid, stamp_s) is not None or hid in self.overflow:
                self.listed_by.setdefault(hid, set()).add(tracker_id)
        self._forget_unlisted()
        return None

    def frame_refused(self, tracker_id: str, arrived_s: float) -> None:
        """A frame on ``tracker_id``'s key was refused (received at cell time ``arrived_s``)."""
        if tracker_id in self.trackers:
            self.conflict_s[tracker_id] = max(self.conflict_s.get(tracker_id, -math.inf),
                                              arrived_s)  # fmt: skip

    def _in_conflict(self, tracker_id: str, now_s: float) -> bool:
        return now_s - self.conflict_s.get(tracker_id, -math.inf) <= CONFLICT_HOLD_S

    def _absent(self, human_id: str | None, evidence_s: float) -> bool:
        """Every declared tracker's newest frame is ``FORGET_AFTER_S`` later than the evidence
        (stamped) and the newest message on their key (received), omits ``human_id`` (None:
        whoever it lists), and no tracker is in conflict; for a person, one of the trackers
        listed them in its current stream."""
        arrived = -math.inf if human_id is None else self.arrived.get(human_id, -math.inf)
        for tid in self.trackers:
            f = self.frames.get(tid)
            if (
                f is None
                or not f.stamp_s >= evidence_s + FORGET_AFTER_S
                or not f.arrived_s >= arrived + FORGET_AFTER_S
                or human_id in f.people
                or self._in_conflict(tid, f.arrived_s)
            ):
                return False
        return human_id is None or bool(self.listed_by.get(human_id))

    def _forget(self, human_id: str) -> None:
        self.tracks.pop(human_id, None)
        self.overflow.pop(human_id, None)
        self.arrived.pop(human_id, None)
        self.listed_by.pop(human_id, None)

    def _forget_unlisted(self) -> None:
        for hid in [h for h, t in self.tracks.items() if self._absent(h, t.evidence_s)]:
            self._forget(hid)
        for hid in [h for h, e in self.overflow.items() if self._absent(h, e)]:
            self._forget(hid)

    def retire(self, human_id: str, now_s: float) -> str:
        """An operator's retire action at cell time ``now_s``: ``""`` when the person is
        forgotten, else why not: not known, or still reported (their newest evidence, a
        skeleton or a frame that lists them, is at most ``tracker_timeout_s`` old: forgetting a
        person a tracker reports would hide them until their next message; retire is for a
        person no tracker reports any more)."""
        track = self.tracks.get(human_id)
        evidence_s = track.evidence_s if track is not None else self.overflow.get(human_id)
        if evidence_s is None:
            return f"human {human_id!r} is not known"
        age_s = now_s - evidence_s
        if not age_s > self.tracker_timeout_s:  # NaN too
            return (
                f"human {human_id!r} is still reported (newest evidence {age_s:.3f} s old <= "
                f"the trackers' timeout {self.tracker_timeout_s} s): retire is for a person no "
                "tracker reports any more"
            )
        self._forget(human_id)
        return ""

    # -- the cycle's view ------------------------------------------------------------------------

    def faults(self, now_s: float) -> list[str]:
        """Tracker liveness and cell capacity, as fault strings."""
        out = []
        for tid in self.trackers:
            f = self.frames.get(tid)
            if f is None:
                out.append(f"tracker {tid!r}: no frame received")
                continue
            age = now_s - f.stamp_s
            if age > self.tracker_timeout_s:
                out.append(
                    f"tracker {tid!r}: last frame {age:.3f} s old > {self.tracker_timeout_s}"
                )
            elif age < -self.future_tolerance_s:
                out.append(f"tracker {tid!r}: frame stamped {-age:.4f} s in the future")
            if self._in_conflict(tid, now_s):
                out.append(
                    f"tracker {tid!r}: a frame refused {now_s - self.conflict_s[tid]:.3f} s ago "
                    "(out of order: two publishers on one tracker id?); its frames forget "
                    f"nobody until {CONFLICT_HOLD_S} s without one"
                )
        lost = self.dropped_s > -math.inf and not self._absent(None, self.dropped_s)
        if self.overflow or lost:
            out.append(
                f"{len(self.tracks) + len(self.overflow)} people known > max_people "
                f"{self.max_people}"
            )
        return out

    def tracking(self) -> dict[str, dict[str, int]]:
        """Per person with any flag: the gate's and the monitor's counts."""
        out = {}
        for hid, t in self.tracks.items():
            c = t.intake.counts()
            if any(c.values()):
                out[hid] = {k: v for k, v in c.items() if v}
        return out

    def tracking_now(self) -> dict[str, TrackingNow]:
        """Per person ever flagged: which joints are held now, since when, and the newest
        flag."""
        found = ((hid, t.intake.now()) for hid, t in self.tracks.items())
        return {hid: n for hid, n in found if n is not None}

    def violations(self) -> list[tuple[str, Violation]]:
        """``(human id, violation)`` of every person now faulted for breaking the bounds."""
        return [(hid, v) for hid, t in self.tracks.items() if t.intake.monitor.violating
                for v in t.intake.monitor.last]  # fmt: skip

    def conformance(self) -> list[str]:
        """The faults of people whose motion broke the parameter set's bounds."""
        found = (t.intake.fault(hid) for hid, t in self.tracks.items())
        return [f for f in found if f is not None]

    def humans(self) -> list[HumanState]:
        return [t.state for t in self.tracks.values()]
