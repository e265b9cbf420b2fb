"""The cell worker's side of the bus: its subscriptions (skeletons, tracker frames, the robot's
state, scenario edits, retirements), its publishers (command, verdict, occupancy, acks, the
scenario in force, status) and one set of drop counters for every input (the contract's reasons,
``dropped`` in the verdicts)."""

from __future__ import annotations

import time
from collections.abc import Callable

import numpy as np

from sara_app.bus import keys
from sara_app.bus.codec import Decoder
from sara_app.bus.messages import ParamsAckMsg
from sara_app.bus.request_queue import requests
from sara_app.bus.session import Bus, Publisher
from sara_app.errors import SaraError
from sara_app.runtime import robot_link
from sara_app.runtime.ledger import AnswerLedger
from sara_app.safety.settings import FUTURE_TOLERANCE_S

EDIT_QUEUE = 64
"""Scenario edits waiting for the loop, at most (the other requests: the queues' default
:data:`~sara_app.bus.request_queue.REQUEST_CAPACITY`): an edit may be megabytes, and the
queue's ring holds twice this many; waiting, they take at most
:data:`~sara_app.bus.request_queue.REQUEST_BYTES`."""
SKELETON_QUEUE = 4096
"""Skeleton samples queued between two drains (all people); each drain decodes only the newest
of each key, so a flood on one key cannot crowd out another person's newest message."""


class CellBus:
    """The keys of cell ``cell`` on ``bus``. ``status`` is opened by the worker before it builds
    its cell (it says ``starting`` meanwhile); the rest is declared here, after the build."""

    def __init__(
        self, bus: Bus, cell: str, status: Publisher, v_max_of: Callable[[], np.ndarray]
    ) -> None:
        """``v_max_of``: the velocity limits ``(n,)`` of the robot in force (its states' check,
        :func:`~sara_app.runtime.robot_link.decoder`)."""
        self.decoder = d = Decoder(max_future_s=FUTURE_TOLERANCE_S)
        self.skeletons = bus.subscribe(keys.skeleton_keys(cell), d, capacity=SKELETON_QUEUE)
        self.frames = bus.subscribe(keys.tracker_frame_keys(cell), d)
        self.robot_decoder = robot_link.decoder(v_max_of)  # the robot's states: their own
        self.robot_state = bus.subscribe(keys.robot_state_key(cell), self.robot_decoder)
        # whether the controller brakes on its own (about once a second): the newest counts
        self.controller_status = bus.subscribe(keys.controller_status_key(cell), d, capacity=8)
        self.params = requests(bus, keys.params_key(cell), d, EDIT_QUEUE)  # a flood: counted
        self.retire = requests(bus, keys.retire_key(cell), d)
        self.replan = requests(bus, keys.robot_replan_key(cell), d)
        self.command = bus.publisher(keys.robot_command_key(cell))
        self.verdict = bus.publisher(keys.verdict_key(cell))
        self.occupancy = bus.publisher(keys.occupancy_key(cell))  # batched: keys.BATCHED_KINDS
        self.acks = bus.publisher(keys.params_ack_key(cell))
        self.scenario = bus.publisher(keys.scenario_key(cell))
        self.status = status
        self.ledger: AnswerLedger | None = None
        """Where the answered requests are recorded (the worker sets it; None: nowhere)."""

    def drop(self, reason: str) -> None:
        """Count one input refused for ``reason`` (a contract reason)."""
        self.decoder.count(reason)

    def dropped(self) -> dict[str, int]:
        out = dict(self.decoder.counts)
        for reason, n in self.robot_decoder.counts.items():
            out[reason] = out.get(reason, 0) + n
        return out

    def answer(
        self, request: str, request_id: str, user: str, ok: bool, reason: str,
        confirmed: bool = False, recorded: str | None = None,
    ) -> None:  # fmt: skip
        """Answer a scenario edit, a retirement or a re-plan (``request``: edit, retire,
        replan) on ``params/ack``, and record it in the audit log when the worker keeps one
        (``ledger``, :mod:`~sara_app.runtime.ledger`): whoever sent it, with ``recorded`` as
        its reason (None: the answer's). Call it once the answer has taken effect (the
        checksum recorded is the one in force)."""
        if self.ledger is not None:
            said = reason if recorded is None else recorded
            self.ledger.note(request, request_id, user, ok, said, confirmed)
        self.acks.put(
            ParamsAckMsg(
                seq=self.acks.next_seq(),
                stamp_s=time.time(),
                request_id=request_id,
                accepted=ok,
                reason=reason,
            )
        )


def id_in(key_expr: str, kind: str) -> str | None:
    """The id in a key of ``kind`` (a refused message's key), or None when it is not one."""
    try:
        k = keys.parse_key(key_expr)
    except SaraError:
        return None
    return k.human_id if k.kind == kind else None
