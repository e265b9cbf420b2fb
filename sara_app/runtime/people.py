"""The people's side of the worker's inputs: skeleton messages, tracker frames and retirements,
taken off the bus each cycle into who is in the cell (:mod:`~sara_app.runtime.presence`) and
each person's state.

A skeleton message is decoded (joints mapped to the full skeleton, missing and low-confidence
joints, stated uncertainties) and taken through the one path every measurement takes
(:func:`sara_app.cell.intake.take_measurement`, the simulator's sensors take it too). The history
property test drives :func:`ingest_skeleton` (``tests/test_ingest_history.py``), so what is
tested is what runs. A message that cannot be taken makes its person unseen, never an exception
out of the loop.
"""

from __future__ import annotations

import logging
from collections.abc import Callable

import numpy as np

from sara_app.bus.messages import RetireMsg, SkeletonMsg, TrackerFrameMsg
from sara_app.cell.build import Cell
from sara_app.cell.intake import Track, rewiden, take_measurement, track_for
from sara_app.human.intake import displacement_of
from sara_app.human.skeleton import full_body
from sara_app.runtime.bus_io import CellBus, id_in
from sara_app.runtime.presence import Presence

log = logging.getLogger("sara_app.worker")
RETIRES_PER_CYCLE = 8
"""Retire requests taken per cycle at most (the rest wait in the subscription's queue): a flood
of them could take the worker's every cycle (hostile-user probe, 2026-11-30; 8 a cycle is
4 000 a second at 500 Hz, far above an operator's pace)."""


def ingest_skeleton(cell: Cell, track: Track, msg: SkeletonMsg) -> str | None:
    """Take ``msg`` into ``track``; None when taken, else the contract's reason for refusing
    it (``out_of_range``, ``stamp_not_advancing``, ``tracking_inconsistent``, ``repeated``)."""
    y, v = full_body(*msg.to_arrays())
    missing, low = (a if len(a) == len(y) else np.pad(a, (0, len(y) - len(a)))
                    for a in msg.joint_states())  # fmt: skip
    return take_measurement(
        cell, track, msg.stamp_s, y, v=v, missing=missing, low=low,
        unc_m=msg.position_uncertainty_m, unc_v_mps=msg.velocity_uncertainty_mps,
        legs_measured=msg.kind == "full",
    )  # fmt: skip


class People:
    """Who is in the cell under ``cell`` (``presence``) and the inputs that say so. ``errors``
    logs a failure, rate-limited."""

    def __init__(self, cell: Cell, io: CellBus, errors: Callable[..., None]) -> None:
        self.cell = cell
        self.io = io
        self.errors = errors
        inp = cell.scenario.inputs
        self.presence = Presence(
            tuple(inp.trackers), inp.tracker_timeout_s, inp.max_people, self._new_track
        )
        self.fresh_stamps: dict[str, float] = {}
        """The stamps of the skeletons taken by the last :meth:`drain`, per person (the cycle's
        phase follows them: :mod:`~sara_app.runtime.cadence`)."""

    def _new_track(self, human_id: str) -> Track:
        return track_for(self.cell, human_id)

    def take_skeleton(self, human_id: str, msg: SkeletonMsg, now: float) -> None:
        track = self.presence.known(human_id, msg.stamp_s, now)
        if track is None:
            self.io.drop("too_many_people")
            return
        reason = ingest_skeleton(self.cell, track, msg)
        if reason is not None:
            self.io.drop(reason)

    def drain(self, now: float) -> None:
        """The newest skeleton of every person and the newest frame of every tracker."""
        skel = self.io.skeletons.drain_latest()
        self.fresh_stamps.clear()
        for d in skel.messages:
            if isinstance(d.msg, SkeletonMsg) and d.key.human_id:
                self.fresh_stamps[d.key.human_id] = d.msg.stamp_s
                try:
                    self.take_skeleton(d.key.human_id, d.msg, now)
                except Exception as e:  # noqa: BLE001 - this message only: the person is unseen
                    self.errors("skeleton ingest failed", repr(e), e)
                    self.io.drop("internal")
                    self.presence.refused(d.key.human_id, now)
        for key in skel.refused_keys:
            hid = id_in(key, "skeleton")
            if hid is not None:  # a refused message on a person's key: that person is unseen
                self.presence.refused(hid, now)
        frames = self.io.frames.drain_latest()
        for key in frames.refused_keys:  # out of order (a second publisher?) or malformed
            tid = id_in(key, "tracker_frame")
            if tid is not None:
                self.presence.frame_refused(tid, now)
        for d in frames.messages:
            if isinstance(d.msg, TrackerFrameMsg) and d.key.human_id:
                reason = self.presence.frame(
                    d.key.human_id, d.msg.stamp_s, d.msg.people, now, d.msg.seq
                )
                if reason is not None:
                    self.io.drop(reason)

    def drain_retirements(self, now: float) -> None:
        """An operator's retirement of a person (positive evidence), answered; refused for a
        person not known or still reported (:meth:`Presence.retire`)."""
        for d in self.io.retire.drain(RETIRES_PER_CYCLE).messages:
            if isinstance(d.msg, RetireMsg):
                reason = self.presence.retire(d.msg.human_id, now)
                if not reason:
                    log.warning("human %r retired by %r: %r", d.msg.human_id, d.msg.user,
                                d.msg.reason)  # fmt: skip
                else:  # rate-limited: anyone may send these
                    self.errors("retire refused", reason)
                self.io.answer("retire", d.msg.request_id, d.msg.user, not reason, reason)

    def adopt(self, new: Cell) -> None:
        """Everyone stays known under a new cell, with their measurement and faults; their
        velocity error bounds are re-derived under the new parameters from the next skeleton on
        (until then the acceleration model is unusable for them: infinite bound)."""
        params_changed = new.scenario.human_params != self.cell.scenario.human_params
        self.cell = new
        inp = new.scenario.inputs
        self.presence.configure(
            inp.trackers, inp.tracker_timeout_s, inp.max_people, self._new_track
        )
        p, gate = new.params, inp.gate.intake()
        for t in self.presence.tracks.values():
            t.intake.retune(p.delta_y_m, p.v_max_mps, p.a_max_mps2, gate, p.pelvis_rise_mps,
                            displacement_of(p))  # fmt: skip
            t.state.dv = np.full(len(p.v_max_mps), np.inf)
            rewiden(new, t, params_changed)  # the same message under the new delta_y
