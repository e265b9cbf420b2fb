"""Zenoh access control on the router (real sessions on 127.0.0.1, the real worker): a session
without the cell's credentials cannot connect, so it cannot move a person; each role publishes
only its own keys (a tracker cannot publish robot states or parameters, an editor no skeleton).
The spoofing case of the issue: a real person at 0.8 m, a foreign publisher showing them at 5 m."""

from __future__ import annotations

import threading
import time
from pathlib import Path

import numpy as np
import pytest

from sara_app.bus import keys
from sara_app.bus.access import Credentials, client_auth, router_access
from sara_app.bus.heartbeat import Heartbeat
from sara_app.bus.messages import ParamsMsg, RobotStateMsg, SkeletonMsg, VerdictMsg
from sara_app.bus.session import Bus, BusError, free_port
from sara_app.human.scripted import joints, standing
from sara_app.runtime.worker import CellWorker
from sara_app.scenario import load_scenario
from sara_app.sim.motions import measured

CELL = "acl1"


def test_roles_publish_only_their_keys_and_strangers_cannot_connect(tmp_path: Path) -> None:
    creds = Credentials.create(tmp_path / "zenoh_credentials.txt")
    assert (tmp_path / "zenoh_credentials.txt").stat().st_mode & 0o077 == 0
    port = free_port()
    with Bus.router(port, access=router_access([CELL], creds)):
        with pytest.raises(BusError):
            Bus.client(port, timeout_ms=1500)  # no credentials
        bad = {"auth": {"usrpwd": {"user": "tracker", "password": "guess"}}}
        with pytest.raises(BusError):
            Bus.client(port, timeout_ms=1500, auth=bad)
        with Bus.client(port, auth=client_auth("worker", creds)) as w, \
                Bus.client(port, auth=client_auth("tracker", creds)) as t, \
                Bus.client(port, auth=client_auth("editor", creds)) as e:  # fmt: skip
            seen = w.subscribe(keys.cell_keys(CELL), fifo=True, capacity=100)
            time.sleep(0.3)
            y = joints(standing((1.0, 0.0), 0.0))
            sk = SkeletonMsg.from_arrays("full", y, seq=0, stamp_s=time.time())
            state = RobotStateMsg(seq=0, stamp_s=time.time(), q=[0.0] * 7, q_dot=[0.0] * 7)
            params = ParamsMsg(seq=0, stamp_s=time.time(), request_id="x", scenario={})
            t.publisher(keys.skeleton_key(CELL, "p1")).put(sk)  # allowed
            t.publisher(keys.robot_state_key(CELL)).put(state)  # a tracker: no robot state
            t.publisher(keys.params_key(CELL)).put(params)  # nor parameters
            e.publisher(keys.skeleton_key(CELL, "p2")).put(sk)  # an editor: no skeleton
            e.publisher(keys.params_key(CELL)).put(params)  # allowed
            t.publisher(keys.skeleton_key("other", "p1")).put(sk)  # another cell: refused
            time.sleep(0.5)
            got = sorted(str(d.key.kind) + ":" + str(d.key.human_id) for d in seen.drain().messages)
    assert got == ["params:None", "skeleton:p1"]


def test_a_foreign_publisher_cannot_move_a_person(tmp_path: Path) -> None:
    """The real tracker shows a person at 0.8 m; a stranger publishes the same id at 5 m with
    higher seq numbers. Without credentials the stranger never connects: the robot keeps
    braking for the real person."""
    creds = Credentials.create(tmp_path / "zenoh_credentials.txt")
    port = free_port()
    sc = load_scenario("standing_beside_path")
    with Bus.router(port, access=router_access([CELL], creds)), \
            Bus.client(port, auth=client_auth("worker", creds)) as wb, \
            Bus.client(port, auth=client_auth("tracker", creds)) as tb, \
            Bus.client(port, auth=client_auth("editor", creds)) as eb:  # fmt: skip
        worker = CellWorker(CELL, sc, wb)
        verdicts = eb.subscribe(keys.verdict_key(CELL), fifo=True, capacity=20000)
        thread = threading.Thread(target=worker.run, daemon=True)
        thread.start()
        near, far = joints(standing((0.8, 0.0), np.pi)), joints(standing((5.0, 0.0), np.pi))
        rng = np.random.default_rng(0)
        pub = tb.publisher(keys.skeleton_key(CELL, "p1"))
        stop = threading.Event()

        def real() -> None:
            while not stop.wait(1 / 60):
                y = measured(near, 0.002, rng)  # a real tracker's noise
                pub.put(SkeletonMsg.from_arrays("full", y, seq=pub.next_seq(),
                                                stamp_s=time.time()))  # fmt: skip

        def stranger() -> None:
            try:
                with Bus.client(port, timeout_ms=1000) as sb:  # no credentials
                    p = sb.publisher(keys.skeleton_key(CELL, "p1"))
                    for i in range(300):
                        msg = SkeletonMsg.from_arrays("full", far, seq=10**9 + i,
                                                      stamp_s=time.time())  # fmt: skip
                        p.put(msg)
                        time.sleep(1 / 200)
            except BusError:
                refused.append(True)

        refused: list[bool] = []
        try:
            with Heartbeat(tb, CELL) as hb:
                hb.people = {"p1"}
                threads = [threading.Thread(target=f, daemon=True) for f in (real, stranger)]
                for th in threads:
                    th.start()
                time.sleep(0.5)
                verdicts.drain()
                time.sleep(1.5)
                got = [d.msg for d in verdicts.drain().messages if isinstance(d.msg, VerdictMsg)]
                stop.set()
                for th in threads:
                    th.join(10)
        finally:
            worker.stop_event.set()
            thread.join(10)
    assert refused == [True]
    assert len(got) > 200
    # the person stays where the real tracker sees them (at 5 m the distance would be > 4 m)
    dist = [v.min_distance_m for v in got]
    assert all(d is not None and d < 1.0 for d in dist), max(d or 9.0 for d in dist)


def test_one_worker_per_cell_holds_under_access_control(tmp_path: Path) -> None:
    from sara_app.bus.ownership import CellTakenError, claim_cell

    creds = Credentials.create(tmp_path / "zenoh_credentials.txt")
    port = free_port()
    with Bus.router(port, access=router_access([CELL], creds)), \
            Bus.client(port, auth=client_auth("worker", creds)) as a, \
            Bus.client(port, auth=client_auth("worker", creds)) as b:  # fmt: skip
        token = claim_cell(a, CELL)
        time.sleep(0.2)
        with pytest.raises(CellTakenError, match="already served"):
            claim_cell(b, CELL)
        token.undeclare()
        time.sleep(0.2)
        claim_cell(b, CELL).undeclare()  # free again


def test_the_contracts_example_tracker_logs_in_and_publishes(tmp_path: Path) -> None:
    """``example_publisher.py --credentials`` (the contract's tracker, as an integrator runs it
    against ``sara-app serve``) logs in as the tracker and its skeletons arrive; without the
    credentials it cannot connect."""
    import subprocess
    import sys

    script = Path(__file__).resolve().parents[1] / "sara_app" / "bus" / "example_publisher.py"
    creds = Credentials.create(tmp_path / "zenoh_credentials.txt")
    port = free_port()
    args = [sys.executable, str(script), "--connect", f"tcp/127.0.0.1:{port}", "--cell", CELL,
            "--count", "40", "--rate", "100"]  # fmt: skip
    with Bus.router(port, access=router_access([CELL], creds)), \
            Bus.client(port, auth=client_auth("worker", creds)) as w:  # fmt: skip
        sub = w.subscribe(keys.skeleton_keys(CELL), fifo=True)
        time.sleep(0.3)  # the subscription known at the router before the tracker puts
        ok = subprocess.run([*args, "--credentials", str(creds.path)], capture_output=True,
                            text=True, timeout=60)  # fmt: skip
        assert ok.returncode == 0, ok.stderr
        got: list = []
        t_end = time.monotonic() + 5
        while not (got and got[-1].msg.seq == 39) and time.monotonic() < t_end:
            got += sub.drain().messages
            time.sleep(0.01)
        seqs = [d.msg.seq for d in got]  # all, from when the router knew the subscription
        assert seqs and seqs == list(range(seqs[0], 40)) and seqs[0] < 35, seqs
        refused = subprocess.run(args, capture_output=True, text=True, timeout=60)
        assert refused.returncode != 0
