"""zenoh's I/O threads per process (sara_app.bus.io_threads), in subprocesses (the layout is read
once per process, with its first session): one thread carries a router and a client's messages,
an operator's layout is kept, a FIFO subscription is refused where it would block the only
thread, and where the one thread was not asked for everything is as before."""

from __future__ import annotations

import json
import os
import subprocess
import sys
import textwrap

import pytest

from sara_app.bus.io_threads import ONE_IO_THREAD, ZENOH_RUNTIME_ENV

# Prints a JSON line: whether the one thread was asked for, the zenoh threads by role (the
# prefix of their names: rx-0, tx-0, app-0, ...), the message received over a router and a
# client, and whether a FIFO subscription was refused.
_PROBE = textwrap.dedent(
    """
    import json, os, sys, time
    from sara_app.bus import io_threads
    from sara_app.bus.session import Bus, free_port
    from sara_app.errors import SaraError

    asked = io_threads.use_one_io_thread() if sys.argv[1] == "ask" else None
    port = free_port()
    with Bus.router(port) as router, Bus.client(port) as client:
        sub = client.subscribe("sara/probe/**")
        pub = router.session.declare_publisher("sara/probe/x")
        got = []
        for _ in range(100):
            pub.put(b"hello")
            time.sleep(0.05)
            got = [s.payload.to_bytes().decode() for s in iter(sub._handler.try_recv, None)]
            if got:
                break
        try:
            client.subscribe("sara/probe/fifo", fifo=True)
            fifo = "allowed"
        except SaraError as e:
            fifo = str(e)
        roles = sorted({open(f"/proc/self/task/{t}/comm").read().strip().rsplit("-", 1)[0]
                        for t in os.listdir("/proc/self/task")} & {"rx", "tx", "app", "net", "acc"})
        late = io_threads.use_one_io_thread()
    print(json.dumps({"asked": asked, "roles": roles, "got": got[:1], "fifo": fifo,
                      "env": os.environ.get("ZENOH_RUNTIME"), "late": late}))
    """
)


def _probe(mode: str, env_layout: str | None = None) -> dict:
    env = {k: v for k, v in os.environ.items() if k != ZENOH_RUNTIME_ENV}
    if env_layout is not None:
        env[ZENOH_RUNTIME_ENV] = env_layout
    out = subprocess.run([sys.executable, "-c", _PROBE, mode], capture_output=True, text=True,
                         timeout=120, env=env)  # fmt: skip
    assert out.returncode == 0, out.stderr[-3000:]
    return dict(json.loads(out.stdout.strip().splitlines()[-1]))


@pytest.mark.skipif(sys.platform != "linux", reason="threads are read from /proc")
def test_one_thread_carries_the_messages_and_refuses_a_fifo() -> None:
    r = _probe("ask")
    assert r["asked"] is True and r["env"] == ONE_IO_THREAD
    assert r["roles"] == ["app"], r  # no receiving, sending, network or accepting thread apart
    assert r["got"] == ["hello"]
    assert "FIFO subscription to 'sara/probe/fifo'" in r["fifo"], r["fifo"]
    assert r["late"] is False  # the layout is set: asking again changes nothing


@pytest.mark.skipif(sys.platform != "linux", reason="threads are read from /proc")
def test_without_asking_zenoh_keeps_its_threads_and_fifo_works() -> None:
    r = _probe("none")
    assert r["asked"] is None and r["env"] is None
    assert {"rx", "tx"} <= set(r["roles"]), r  # zenoh's default: a runtime per role
    assert r["got"] == ["hello"] and r["fifo"] == "allowed"
    assert r["late"] is False and r["env"] is None  # after the first session: too late to ask


@pytest.mark.skipif(sys.platform != "linux", reason="threads are read from /proc")
def test_an_operators_layout_is_kept() -> None:
    theirs = "(app: (worker_threads: 2))"
    r = _probe("ask", theirs)
    assert r["asked"] is False and r["env"] == theirs
    assert r["got"] == ["hello"] and r["fifo"] == "allowed"  # not the one-thread layout
