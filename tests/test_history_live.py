"""Issue "No input history may hide a person", end to end: a router, ``sara-app worker`` and
``sara-app controller`` as processes of their own (scenario ``punches``, default models) and a
tracker declared as ``main`` in this test. A person stands at P, close to the robot: measured
there from the start (a fresh person) the robot gets no ``intended`` command. The same person
reaching P by a 2.5 m jump between two frames, or by a whole-skeleton freeze (a stalled
tracker republishing the old pose with fresh stamps) followed by recovery at P, must get none
either, from the moment they are measured at P."""

from __future__ import annotations

import contextlib
import subprocess
import sys
import time
from collections.abc import Callable, Iterator

import numpy as np
import pytest

from sara_app.bus import keys
from sara_app.bus.messages import RobotCommandMsg, SkeletonMsg, TrackerFrameMsg
from sara_app.bus.session import Bus, free_port
from sara_app.human.scripted import joints, standing
from sara_app.ops.supervisor import stop_processes
from sara_app.sim.motions import measured

# live cells whose rates and timings the assertions read: no other test runs beside them
pytestmark = [pytest.mark.exclusive, pytest.mark.usefixtures("idle_cpus_poll")]

CELL = "hist"
P_X_M = 0.3  # in front of the robot base, facing it: a fresh person there stops the robot
LATENCY_S = 0.02
"""Commands stamped this soon after a skeleton's publication may have been decided before it
arrived (transport, the 2 ms control period, scheduling on a loaded test machine)."""
FAR_X_M = 3.0


class Tracker:
    """The cell's ``main`` tracker at 60 Hz: ``pose(t)`` gives the skeleton to send (None: the
    tracker sees nobody); the commands the controller receives are collected."""

    def __init__(self, bus: Bus) -> None:
        self.pub = bus.publisher(keys.skeleton_key(CELL, "p1"))
        self.frame = bus.publisher(keys.tracker_frame_key(CELL, "main"))
        self.commands = bus.subscribe(keys.robot_command_key(CELL), fifo=True, capacity=100000)
        self.rng = np.random.default_rng(0)
        self.sent: list[float] = []
        """When each skeleton of the last :meth:`run` was published (s since its start)."""

    def run(
        self, seconds: float, pose: Callable[[float], np.ndarray | None]
    ) -> list[tuple[float, RobotCommandMsg]]:
        """Publish for ``seconds``; returns ``(time since start, command)`` received."""
        self.commands.drain()
        self.sent = []
        out: list[tuple[float, RobotCommandMsg]] = []
        t0 = time.time()
        while (t := time.time()) - t0 < seconds:
            y = pose(t - t0)
            if y is not None:
                msg = SkeletonMsg.from_arrays("full", y, seq=self.pub.next_seq(), stamp_s=t)
                self.pub.put(msg)
                self.sent.append(t - t0)
            seen = [] if y is None else ["p1"]
            self.frame.put(TrackerFrameMsg(seq=self.frame.next_seq(), stamp_s=t, people=seen))
            out += [(d.msg.stamp_s - t0, d.msg) for d in self.commands.drain().messages
                    if isinstance(d.msg, RobotCommandMsg)]  # fmt: skip
            time.sleep(max(0.0, 1 / 60 - (time.time() - t)))
        return out

    def noisy(self, x_m: float) -> np.ndarray:
        return measured(joints(standing((x_m, 0.0), np.pi)), 0.002, self.rng)


@contextlib.contextmanager
def _cell() -> Iterator[Tracker]:
    port = free_port()
    procs: list[subprocess.Popen[bytes]] = []
    with Bus.router(port), Bus.client(port) as bus:
        try:
            for prog in ("runtime.worker", "peers.controller"):
                procs.append(subprocess.Popen([sys.executable, "-m", f"sara_app.{prog}",
                                               "--cell", CELL, "--scenario", "punches",
                                               "--port", str(port)]))  # fmt: skip
            tracker = Tracker(bus)
            t_end = time.monotonic() + 120
            while not tracker.commands.drain().messages:
                assert all(p.poll() is None for p in procs), "a process died"
                assert time.monotonic() < t_end, "the worker never commanded"
                time.sleep(0.1)
            yield tracker
        finally:
            stop_processes(procs)


def _intended(cmds: list[tuple[float, RobotCommandMsg]], after_s: float) -> int:
    return sum(c.mode == "intended" for t, c in cmds if t >= after_s)


@pytest.mark.slow
def test_no_history_lets_the_robot_move_at_a_person_a_fresh_one_stops() -> None:
    with _cell() as tr:
        # a fresh person at P: measured there from the start, no intended command
        fresh = tr.run(2.0, lambda t: tr.noisy(P_X_M))
        assert len(fresh) > 300
        assert _intended(fresh, 0.2) == 0, "the chosen P does not stop a fresh person"
        # nobody for 2 s: the robot works again
        free = tr.run(2.0, lambda t: None)
        assert _intended(free, 1.0) > 100

        # far for 1 s, then 2.5 m closer from one frame to the next, standing there
        jump = tr.run(3.0, lambda t: tr.noisy(FAR_X_M if t < 1.0 else P_X_M))
        assert _intended(jump, 0.3) > 0  # it worked while the person stood far
        at_p = min(t for t in tr.sent if t >= 1.0) + LATENCY_S
        assert _intended(jump, at_p) == 0, [(t, c.mode) for t, c in jump if t >= at_p][:5]

        tr.run(2.0, lambda t: None)
        # far, then the tracker stalls (the last pose repeated with fresh stamps) for 1 s while
        # the person walks in, then recovers with the person at P
        frozen: dict[str, np.ndarray] = {}

        def stall(t: float) -> np.ndarray:
            if t < 1.0:
                frozen["y"] = tr.noisy(FAR_X_M)
                return frozen["y"]
            return frozen["y"] if t < 2.0 else tr.noisy(P_X_M)

        stalled = tr.run(3.5, stall)
        assert _intended(stalled, 0.3) > 0
        # a stale tracker ages the person: no intended command once the pose has repeated for
        # the 0.1 s stale limit (from its first publication), nor after the recovery at P
        stale = max(t for t in tr.sent if t < 1.0) + 0.1 + LATENCY_S
        assert _intended(stalled, stale) == 0, [(t, c.mode) for t, c in stalled if t >= stale][:5]
