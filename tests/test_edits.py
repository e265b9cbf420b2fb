"""The worker's scenario edits off the bus (sara_app.runtime.edits) on a real zenoh session on
127.0.0.1: a cycle decodes at most ``EDITS_PER_CYCLE`` of the edits waiting (an edit may be
megabytes of JSON; a flood decoded at once held all of them in memory together), the others
wait in their request queue, and every one is built, in the order sent."""

from __future__ import annotations

import time

import numpy as np

from sara_app.bus import keys
from sara_app.bus.messages import ParamsMsg
from sara_app.bus.session import Bus, free_port
from sara_app.runtime.bus_io import CellBus
from sara_app.runtime.edits import EDITS_PER_CYCLE, LiveEdits
from sara_app.scenario import load_scenario

CELL = "c1"


def test_a_cycle_decodes_one_edit_and_the_others_wait_their_turn_in_order() -> None:
    data = load_scenario("standing_beside_path").model_dump(mode="json")
    with Bus.router(free_port()) as bus:
        io = CellBus(bus, CELL, bus.publisher(keys.status_key(CELL)), lambda: np.ones(7))
        edits = LiveEdits(CELL, "standing_beside_path", None, errors=lambda *a: None)
        try:
            pub = bus.publisher(keys.params_key(CELL))
            for i in range(3):
                pub.put(ParamsMsg(seq=i + 1, stamp_s=time.time(), request_id=f"e{i}",
                                  scenario=data))  # fmt: skip
            deadline = time.monotonic() + 10.0
            while io.params.waiting() < 3:  # all three taken into the queue, none decoded
                assert time.monotonic() < deadline, io.params.waiting()
                io.params.drain(0)
                time.sleep(0.01)
            edits.drain(io)
            assert io.params.waiting() == 3 - EDITS_PER_CYCLE
            built: list[str] = []
            deadline = time.monotonic() + 30.0
            while len(built) < 3:
                assert time.monotonic() < deadline, built
                edits.drain(io)
                edits.take(lambda b: built.append(b.request_id) is None)
                time.sleep(0.01)
            assert built == ["e0", "e1", "e2"]
        finally:
            edits.close()
