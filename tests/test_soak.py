"""``sara-app soak --chaos`` for 60 s, as CI runs it: the default cell's processes killed
(SIGKILL) or stopped (SIGSTOP / SIGCONT) every few seconds while the replayed person works
next to the robot. From what the controller executed: the robot only moved along commands the
worker verified; no process is left after the run; the cell recovered from every fault that
had time to recover; the table and the plot are written."""

from __future__ import annotations

from pathlib import Path

import pytest

from sara_app.bench.soak import run_soak, why_faulted, write
from sara_app.commands.soak import RECOVERY_GRACE_S


@pytest.mark.exclusive
@pytest.mark.usefixtures("idle_cpus_poll")
@pytest.mark.slow
def test_chaos_never_moves_the_robot_off_a_verified_command(tmp_path: Path, monkeypatch) -> None:
    """45 s with a process killed or the router stopped every 3 s (15 faults, as a minute at
    one every 4 s: more of them overlap). The run's data folder (its bus password file) goes
    with it, and this process's data folder is its own again."""
    import os
    import tempfile

    runs = tmp_path / "runs"
    runs.mkdir()
    monkeypatch.setattr(tempfile, "tempdir", str(runs))
    data_before = os.environ.get("SARA_APP_DATA")
    res = run_soak(45.0, chaos=True, chaos_every_s=3.0, sample_s=1.5, seed=1, progress=False)
    assert list(runs.iterdir()) == [] and os.environ.get("SARA_APP_DATA") == data_before
    assert len(res.samples) >= 25 and len(res.events) >= 12
    assert {e.target for e in res.events} >= {"router", "worker", "controller", "replayer"}
    assert res.commands > 5000 and res.states_checked > 5000
    assert res.off_path == [], res.off_path[:5]
    assert res.orphans == []
    # a worker restarts in a few seconds (it loads its kernels): faults near the end may not
    late = 45.0 - RECOVERY_GRACE_S
    missed = [e for e in res.events if e.recovered_s is None and e.t_s < late]
    assert missed == [], [(e, why_faulted(e)) for e in missed]
    lines = write(res, tmp_path)
    assert (tmp_path / "soak.png").stat().st_size > 10_000
    assert any(line.startswith("| RSS worker (MB)") for line in lines)
    assert any(line.startswith("recovery (s)") for line in lines)


def test_the_path_check_accepts_a_commands_path_and_its_stop_only() -> None:
    """A state on the segment to a set point or on its verified stop is on the path; one
    beside it, or ahead of any command, is not."""
    import numpy as np

    from sara_app.bench.soak import ON_PATH_TOL_RAD, PathCheck
    from sara_app.bus.messages import RobotCommandMsg

    check = PathCheck()
    for k in range(3):  # set points 0.0, 0.1, 0.2 rad on joint 0; each stop ends 0.05 further
        q = [0.1 * k, 0.0]
        check.command(RobotCommandMsg(
            seq=k, stamp_s=10.0 + 0.01 * k, q=q, q_dot=[1.0, 0.0], q_ddot=[0.0, 0.0],
            valid_until_s=10.0 + 0.01 * k + 0.02, mode="intended",
            failsafe_q=[q, [0.1 * k + 0.05, 0.0]], failsafe_t_s=[0.01, 0.1],
        ))  # fmt: skip
    assert check.distance(10.025, np.array([0.15, 0.0])) <= ON_PATH_TOL_RAD  # segment 0.1->0.2
    assert check.distance(10.025, np.array([0.24, 0.0])) <= ON_PATH_TOL_RAD  # the last stop
    assert check.distance(10.025, np.array([0.15, 0.01])) > ON_PATH_TOL_RAD  # beside it
    assert check.distance(10.025, np.array([0.4, 0.0])) > ON_PATH_TOL_RAD  # beyond every stop
    # the router was down for 10 s: the robot rests at the end of the last stop it had
    assert check.distance(20.0, np.array([0.25, 0.0])) <= ON_PATH_TOL_RAD


def test_an_event_keeps_the_reasons_of_the_faults_after_it_until_the_cell_recovers() -> None:
    """Fault verdicts after the event's end are tallied by reason (their numbers written #,
    at most MAX_REASONS of them); the first verdict that is not a fault recovers the event and
    ends the tally; verdicts before its end count for nothing."""
    from sara_app.bench.soak import MAX_REASONS, Event, _after
    from sara_app.bus.messages import VerdictMsg

    def verdict(stamp_s: float, mode: str, *faults: str) -> VerdictMsg:
        return VerdictMsg(seq=0, stamp_s=stamp_s, cell="c", safety_mode="ssm", mode=mode,
                          cycle_time_us=100.0, faults=list(faults))  # fmt: skip

    ev = Event(3.0, "router", "stop 1.6 s", end_s=10.0)
    for stamp, age in ((10.1, "1.234"), (10.2, "0.75")):
        _after(ev, verdict(stamp, "fault", f"robot state {age} s old > 0.1", "tracker 'a': ok 3"))
    assert ev.recovered_s is None
    assert ev.faults_after == {"robot state # s old > #": 2, "tracker 'a': ok #": 2}
    assert why_faulted(ev, top=1) == "2 x 'robot state # s old > #'"
    for k in range(2 * MAX_REASONS):  # new reasons beyond the cap are not kept
        _after(ev, verdict(10.3, "fault", f"reason {chr(97 + k % 26)}{k // 26 * 'x'}"))
    assert len(ev.faults_after) == MAX_REASONS
    _after(ev, verdict(10.5, "intended"))
    assert ev.recovered_s == pytest.approx(0.5)
    assert why_faulted(Event(0.0, "worker", "kill -9", 1.0)) == "no verdict since"


def test_a_kill_ends_when_its_process_is_restarted_and_no_verdict_before_recovers_it() -> None:
    """A controller killed a moment ago leaves a fresh enough robot state, so the next verdict
    is not a fault: that is no recovery. The kill's fault ends when the supervisor restarted
    the process; only a verdict after that counts."""
    from types import SimpleNamespace

    from sara_app.bench.soak import Event, _after, _restarted
    from sara_app.bus.messages import VerdictMsg

    def verdict(stamp_s: float, mode: str) -> VerdictMsg:
        return VerdictMsg(seq=0, stamp_s=stamp_s, cell="c", safety_mode="ssm", mode=mode,
                          cycle_time_us=100.0, faults=["robot state 0.2 s old > 0.1"])  # fmt: skip

    ctl = SimpleNamespace(name="controller", restarts=2)
    sup = SimpleNamespace(children=[SimpleNamespace(name="worker", restarts=5), ctl])
    ev = Event(24.0, "controller", "kill -9", end_s=100.0, restarted_from=2)
    for stamp in (100.01, 100.3):
        _restarted([ev], sup, stamp)
        if ev.restarted_from is None:
            _after(ev, verdict(stamp, "intended"))
    assert ev.recovered_s is None and ev.end_s == 100.0
    ctl.restarts = 3  # the supervisor restarted it at 100.5
    _restarted([ev], sup, 100.5)
    assert ev.restarted_from is None and ev.end_s == 100.5
    _after(ev, verdict(101.0, "fault"))
    _after(ev, verdict(101.7, "intended"))
    assert ev.recovered_s == pytest.approx(1.2)
    assert ev.faults_after == {"robot state # s old > #": 1}
