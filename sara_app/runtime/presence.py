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
  stamped at least ``FORGET_AFTER_S`` after the person's newest evidence, that does not list
  them; or when an operator retires them. (The margin: while messages keep arriving on a
  person's key, even refused ones, a tracker's frame that omits them contradicts its own stream
  and does not forget them.) Never on a scenario edit (the presence object outlives cells),
  never on a timeout.
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
"""How much later than a person's newest evidence a frame that omits them must be stamped."""
MAX_OVERFLOW = 256
"""Ids of people beyond ``max_people`` remembered (each is a fault until forgotten)."""


@dataclass
class _Frame:
    stamp_s: float
    people: frozenset[str]


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
        while len(self.tracks) > self.max_people:
            hid = next(reversed(self.tracks))
            self._overflow(hid, self.tracks.pop(hid).evidence_s)

    # -- evidence --------------------------------------------------------------------------------

    def _overflow(self, human_id: str, evidence_s: float) -> None:
        if human_id not in self.overflow and len(self.overflow) >= MAX_OVERFLOW:
            _, dropped_s = self.overflow.popitem()  # the newest entry: its id is gone
            self.dropped_s = max(self.dropped_s, dropped_s, evidence_s)
        self.overflow[human_id] = max(self.overflow.get(human_id, -math.inf), evidence_s)

    def known(self, human_id: str, evidence_s: float) -> Track | None:
        """The track of ``human_id`` (created when new), its evidence time raised to
        ``evidence_s``; None when the cell is full (the id is kept in the overflow)."""
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
        self.known(human_id, now_s)

    def frame(self, tracker_id: str, stamp_s: float, people: Iterable[str]) -> str | None:
        """Take a tracker frame; returns a drop reason (``unknown_tracker``) or None."""
        if tracker_id not in self.trackers:
            return "unknown_tracker"
        seen = frozenset(people)
        old = self.frames.get(tracker_id)
        if old is not None and stamp_s <= old.stamp_s:
            return "out_of_order"
        self.frames[tracker_id] = _Frame(stamp_s, seen)
        for hid in seen:
            self.known(hid, stamp_s)
        self._forget_unlisted()
        return None

    def _absent(self, human_id: str | None, evidence_s: float) -> bool:
        """Every declared tracker's newest frame is ``FORGET_AFTER_S`` later than the evidence
        and omits ``human_id`` (None: whoever it lists)."""
        for tid in self.trackers:
            f = self.frames.get(tid)
            if f is None or not f.stamp_s >= evidence_s + FORGET_AFTER_S or human_id in f.people:
                return False
        return True

    def _forget_unlisted(self) -> None:
        for hid in [h for h, t in self.tracks.items() if self._absent(h, t.evidence_s)]:
            del self.tracks[hid]
        for hid in [h for h, e in self.overflow.items() if self._absent(h, e)]:
            del self.overflow[hid]

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
        self.tracks.pop(human_id, None)
        self.overflow.pop(human_id, None)
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
