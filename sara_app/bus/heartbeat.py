"""A tracker's heartbeat from a thread: frames on ``sara/<cell>/tracker/<id>/frame`` listing a
set of people the caller keeps up to date (for a Python tracker, the benchmarks and tests).
The contract's rule: frames at the tracker's rate, also when nobody is in view."""

from __future__ import annotations

import threading
import time

from sara_app.bus import keys
from sara_app.bus.messages import TrackerFrameMsg
from sara_app.bus.session import Bus
from sara_app.errors import ParameterError


class Heartbeat:
    """``with Heartbeat(bus, cell) as hb: hb.people = {"p1"}``; frames at ``rate_hz``."""

    def __init__(self, bus: Bus, cell: str, tracker: str = "main", rate_hz: float = 100.0) -> None:
        self.pub = bus.publisher(keys.tracker_frame_key(cell, tracker))
        if not rate_hz > 0:
            raise ParameterError(f"heartbeat rate {rate_hz!r} Hz; expected > 0")
        self.people: set[str] = set()
        self.period_s = 1.0 / rate_hz
        self.sent = 0
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, daemon=True)

    def _run(self) -> None:
        while not self._stop.wait(self.period_s):
            msg = TrackerFrameMsg(
                seq=self.pub.next_seq(), stamp_s=time.time(), people=sorted(self.people)
            )
            self.sent += self.pub.put(msg)

    def start(self) -> Heartbeat:
        self._thread.start()
        return self

    def stop(self) -> None:
        self._stop.set()
        if self._thread.is_alive():
            self._thread.join(5)

    def __enter__(self) -> Heartbeat:
        return self.start()

    def __exit__(self, *exc: object) -> None:
        self.stop()
