"""The measured robot of a live cell: freshness of ``robot/state`` and tracking against the
commanded trajectory at the measurement's time (the contract's controller rules).

The commanded trajectory is the sequence of set points the worker sent: set point ``q_i`` at
``stamp_i + dt``, straight joint-space segments in between, and after the newest set point the
newest command's verified stop (what the contract has a controller do, and the reference
controller does). A state stamped ``t`` is compared with that trajectory at ``t``, so transport and
scheduling delays between worker and controller do not count as tracking errors; a state older
than the oldest remembered set point cannot be checked and is a fault.

A state stream that has tracked the commands once is **bound** to them: from then on a state
that contradicts them is a tracking fault, never a reason to re-anchor the worker's plan where
the state says the robot rests (a hostile-controller probe: a second publisher, or one buggy
controller, reporting the robot at rest 0.3 rad away made the worker re-plan from there and
send an ``intended`` command that jumped the real robot by that much, again and again). Only a
stream not bound yet (the first one a worker sees; one whose publisher restarted, which the
decoder tells by its numbering starting over at least a second after the last state) may
re-anchor the plan, and one silent for a second or more (``UNBIND_GAP_S``: after a router
restart its stamps skip that long; after a router stall the worker hears nothing that long,
then states too old to take, then fresh ones: the controller braked on its own meanwhile and
refuses a set point away from where it rests, so a bound stream there left both waiting on
each other until an operator's re-plan, ``sara-app soak`` probe 2026-12-04). A robot
stopped or moved elsewhere while its controller ran (a protective stop, hand guiding, a
controller that braked on its own) with no second of silence is planned from again only on an
operator's word (``robot/replan``, :meth:`MeasuredRobot.replan_refusal`): the operator
confirms the position the controller reports, and the worker takes it only if the state is
there now, at rest.
"""

from __future__ import annotations

import time
from collections import deque
from collections.abc import Callable

import numpy as np

from sara_app.bus.codec import Decoder
from sara_app.bus.messages import (
    ControllerStatusMsg,
    Message,
    RobotStateMsg,
    position_on_stop,
)
from sara_app.bus.session import Subscription
from sara_app.robot.deviation_kernels import max_abs, max_abs_diff
from sara_app.robot.trajectory import JointState
from sara_app.safety.settings import FUTURE_TOLERANCE_S

UNBIND_GAP_S = 1.0
"""A state stream silent this long is bound no more (as the decoder's restart rule: a second):
after a router restart the controller, which braked on its own meanwhile, rests where the
worker's plan may not, and the plan starts from there again (tests/test_supervision.py)."""
HISTORY = 256
"""Set points remembered for the tracking check (about one second at 250 Hz)."""
STOP_ENDS = 256
"""Distinct ends of the verified stops sent, remembered (about half a second of motion at
500 Hz; a worker in fault sends one stop's end again and again, so they reach back past the
moment its states stopped coming)."""
BRAKING_SAID_S = 2.5
"""How long the controller's word that it brakes on its own (``controller/status``, about once
a second) counts."""
STATES_PER_DRAIN = 64
"""States decoded per cycle at most (a controller publishes one or a few per control period;
each is decoded, so that a second publisher's lies cannot hide the real controller's states as
superseded: they are refused as out of order, which a re-plan counts as evidence)."""
REPLAN_STILL_S = 0.3
"""Planning from where the states say the robot is (an operator's re-plan, or a re-anchor of a
stream not bound) needs them at rest at one position for this long, and no state of the key
refused for this long (a second publisher's states make the controller's out of order)."""
REFUSED_FAULT_S = 0.1
"""A state of the key refused (out of order, invalid, stale, another joint count) is a fault
for this long, even while others are accepted: two publishers on one key are one too many (a
second one that copied the commands hid the real controller: hostile-user probe)."""
MAX_STATE_AGE_S = 0.5
"""A state stamped longer ago than this is refused before it counts for the key's order (one
stamped 10 s ago with a huge ``seq``, then one with ``seq`` 0, faked a controller restart at
once). Below the decoder's restart rule's second, so that a faked restart takes a second of
refused real states, which keeps the stream bound (:meth:`MeasuredRobot.drain`)."""
V_REST = 1e-6
"""A state is at rest when no joint moves faster than this (rad/s or m/s), unless the scenario
says otherwise (``inputs.robot_rest_speed_rad_s``, :attr:`MeasuredRobot.rest_speed`)."""


STATE_SPEED_FACTOR = 2.0
"""A state that says a joint moves faster than this many times its velocity limit is refused
(``out_of_range``): no drive turns a joint at twice its rated speed, so the state is wrong (a
unit error, a corrupted value; one at 1e300 rad/s was taken, hostile-controller probe). ASSUMES
a driver whose reported speeds are within this factor of the truth (a measured speed is a
difference of encoder readings, whose noise is far below its rated speed)."""


class StateRules:
    """The worker's own rules for a ``robot/state`` message (the :class:`Decoder`'s ``check``),
    judged before it counts for the key's order: another number of joints than the robot's
    velocity limits ``v_max_of() (n,)`` (rad/s or m/s, of the robot in force: an edit may change
    them) is ``wrong_dof`` (one with a huge ``seq`` held the real controller's states back as
    out of order for a second); a joint faster than ``STATE_SPEED_FACTOR`` times its limit is
    ``out_of_range``; so is a state stamped more than ``MAX_STATE_AGE_S`` ago, counted apart in
    :attr:`late`: a transport delay, not a second publisher (:meth:`MeasuredRobot.drain`)."""

    def __init__(self, v_max_of: Callable[[], np.ndarray]) -> None:
        self.v_max_of = v_max_of
        self.late = 0
        """States refused as stamped too long ago, since the decoder was made."""

    def __call__(self, msg: Message) -> tuple[str, str] | None:
        if isinstance(msg, RobotStateMsg):
            v_max = self.v_max_of()
            if len(msg.q) != len(v_max):
                return "wrong_dof", f"{len(msg.q)} joints received, robot has {len(v_max)}"
            for j, (v, m) in enumerate(zip(msg.q_dot, v_max)):
                if not abs(v) <= STATE_SPEED_FACTOR * m:
                    return "out_of_range", (
                        f"joint {j} moves at {float(v):.4g} rad/s, more than "
                        f"{STATE_SPEED_FACTOR:g} times its velocity limit {float(m):.4g} rad/s"
                    )
        age = time.time() - msg.stamp_s
        if not age <= MAX_STATE_AGE_S:
            self.late += 1
            return "out_of_range", f"stamped {age:.3g} s ago (at most {MAX_STATE_AGE_S} s)"
        return None


def decoder(v_max_of: Callable[[], np.ndarray]) -> Decoder:
    """The decoder of one cell's ``robot/state`` key: its own (a publisher restart on another
    key must not count as the controller's: a retire's restart re-anchored the plan, hostile-
    user probe 2026-11-30), with :class:`StateRules` as its check."""
    return Decoder(max_future_s=FUTURE_TOLERANCE_S, check=StateRules(v_max_of))  # restarts: 1 s


def _late_count(sub: Subscription) -> int:
    """States the subscription's decoder refused as stamped too long ago (0: not its rules)."""
    rules = sub.decoder.check
    return rules.late if isinstance(rules, StateRules) else 0


def outside_limits(q: np.ndarray, q_min: np.ndarray, q_max: np.ndarray) -> str | None:
    """The first joint of ``q (n,)`` outside ``q_min``/``q_max (n,)`` (rad), its position and
    its limits, or None: no plan starts from there (the robot model refuses it)."""
    out = np.flatnonzero(~((q >= q_min) & (q <= q_max)))  # NaN too
    if not out.size:
        return None
    j = int(out[0])
    return f"joint {j} at {q[j]:.4f} rad is outside its limits [{q_min[j]:.4f}, {q_max[j]:.4f}] rad"


class MeasuredRobot:
    """The newest ``robot/state`` and its faults (once a controller has spoken, a state older
    than the timeout, a refused one or one that tracks the commands worse than the tolerance is
    a fault, which clears when fresh valid states resume)."""

    def __init__(self) -> None:
        self.state: JointState | None = None
        self.stamp_s: float | None = None
        self.commanded: deque[tuple[float, np.ndarray, tuple[np.ndarray, np.ndarray]]] = deque(
            maxlen=HISTORY
        )
        """The commands sent: ``(set point time, set point, its verified stop's arrays)``
        (:meth:`RobotCommandMsg.stop_arrays`), oldest first."""
        self.bound = False
        """The state stream has tracked the commands (see the module notes)."""
        self.stop_ends: deque[np.ndarray] = deque(maxlen=STOP_ENDS)
        """Where the verified stops sent end ``(n,)``, distinct ones, oldest first: where a
        controller that braked on its own comes to rest (:meth:`at_rest_elsewhere`)."""
        self.braking_said_s = -np.inf
        """When (the worker's clock) the controller's newest status, received then, said it
        brakes on its own (-inf: the newest said it does not, or none came)."""
        self._restarts = 0  # the decoder's count of restarted publishers, last seen
        self.still_since_s: float | None = None
        """Since when (state stamps) every state was at rest within the tolerance of the first
        of them, ``_still_q`` (None: the newest is not at rest)."""
        self._still_q: np.ndarray | None = None
        self.refused_s = -np.inf
        """When (the worker's clock) a state of the key was last refused."""
        self.disputed_s = -np.inf
        """When (the worker's clock) a state of the key was last refused for anything but its
        age: what a second publisher on the key causes (a late state is a transport delay)."""
        self.heard_s: float | None = None
        """When (the worker's clock) a state was last accepted."""
        self._late = 0  # the decoder's count of states refused as late, last seen
        self.rest_speed = V_REST
        """A state is at rest when no joint's reported speed exceeds this (rad/s or m/s; the
        worker sets the scenario's ``inputs.robot_rest_speed_rad_s``)."""

    def drain(self, sub: Subscription, now_s: float, tol_rad: float) -> None:
        """The ``robot/state`` messages off ``sub`` (its decoder its own, :func:`decoder`: its
        restarts are this key's alone), in order, the newest kept; a refused one is a fault for
        ``REFUSED_FAULT_S``. ``tol_rad``: how far apart two states may be and still stand at one
        position. The stream is bound no more after a restart of its publisher or a second of
        silence (stamps a second apart, or a second without a state taken), unless a state of
        the key was refused for anything but its age in the second before: a second publisher
        with a huge ``seq`` makes the real controller's states out of order for a second, then
        look like a restart (hostile-user probe, 2026-11-30); states refused as too old are
        what a stalled router delivers when it resumes."""
        got = sub.drain(STATES_PER_DRAIN)
        late_total = _late_count(sub)
        late, self._late = late_total - self._late, late_total
        if got.refused_keys:
            self.refused_s = now_s
        if got.rejected > late:
            self.disputed_s = now_s
        quiet = now_s - self.disputed_s >= UNBIND_GAP_S  # none disputed in the last second
        restarts = sub.decoder.restarts
        if restarts > self._restarts and quiet:  # a restarted controller: a new stream
            self.bound = False
        self._restarts = restarts
        for d in got.messages:
            if not isinstance(d.msg, RobotStateMsg):
                continue
            gap = self.stamp_s is not None and d.msg.stamp_s - self.stamp_s >= UNBIND_GAP_S
            unheard = self.heard_s is not None and now_s - self.heard_s >= UNBIND_GAP_S
            if (gap or unheard) and quiet:
                self.bound = False  # no evidence for a second or more (a router restarted)
            self.heard_s = now_s
            self._still(np.asarray(d.msg.q), np.asarray(d.msg.q_dot), d.msg.stamp_s, tol_rad)
            self.state = JointState(
                q=np.asarray(d.msg.q), v=np.asarray(d.msg.q_dot), a=np.zeros(len(d.msg.q))
            )
            self.stamp_s = d.msg.stamp_s

    def _still(self, q: np.ndarray, v: np.ndarray, stamp_s: float, tol_rad: float) -> None:
        """Update since when the robot stands still (the state ``q``, ``v (n,)``)."""
        if not max_abs(v) <= self.rest_speed:
            self.still_since_s = self._still_q = None
        elif self._still_q is None or not max_abs_diff(q, self._still_q) <= tol_rad:
            self.still_since_s, self._still_q = stamp_s, q

    def sent(self, t_point_s: float, q: np.ndarray, stop: tuple[np.ndarray, np.ndarray]) -> None:
        """The worker sent a command whose set point ``q (n,)`` is for time ``t_point_s`` and
        whose verified stop is ``stop`` (:meth:`RobotCommandMsg.stop_arrays`)."""
        if self.commanded and t_point_s <= self.commanded[-1][0]:
            self.forget_commands()  # time went back (a restarted clock): start afresh
        self.commanded.append((t_point_s, q, stop))
        end = stop[1][-1]
        if not self.stop_ends or not max_abs_diff(end, self.stop_ends[-1]) <= 1e-12:
            self.stop_ends.append(end)

    def forget_commands(self) -> None:
        """The plan starts afresh (re-anchored, re-planned, a restarted clock): the commands
        sent before say nothing about where the robot may rest or be."""
        self.commanded.clear()
        self.stop_ends.clear()

    def hear_controller(self, sub: Subscription, now_s: float) -> None:
        """The controller's newest status off ``sub`` (``controller/status``): whether it
        brakes on its own now."""
        for d in sub.drain_latest().messages:
            if isinstance(d.msg, ControllerStatusMsg):
                self.braking_said_s = now_s if d.msg.braking else -np.inf

    def _braked_to_a_stop_end(self, q: np.ndarray, now_s: float, tol_rad: float) -> bool:
        """The controller said lately that it brakes on its own, and ``q (n,)`` is within
        ``tol_rad`` of where one of the remembered stops ends."""
        if not now_s - self.braking_said_s <= BRAKING_SAID_S:
            return False
        return any(max_abs_diff(q, end) <= tol_rad for end in reversed(self.stop_ends))

    def expected(self, t_s: float) -> tuple[np.ndarray, float] | None:
        """The commanded position at ``t_s`` and the slack the contract allows there (None:
        before the remembered set points). Slack: between two set points a controller that has
        not received the newer command yet follows the older command's verified stop (sound),
        then heads for the newer set point; it is at most as far from the straight segment as
        that stop is at ``t_s``."""
        c = self.commanded
        if not c or t_s < c[0][0]:
            return None
        if t_s >= c[-1][0]:  # past the newest set point: on its command's verified stop
            return position_on_stop(*c[-1][2], t_s)[0], 0.0
        k = len(c) - 2  # c[k].t <= t_s < c[k+1].t; states come near the newest: from the end
        while c[k][0] > t_s:
            k -= 1
        (ta, qa, older), (tb, qb, _) = c[k], c[k + 1]
        q = qa + (qb - qa) * ((t_s - ta) / (tb - ta))
        slack = max_abs_diff(position_on_stop(*older, t_s)[0], q)
        return q, slack

    def faults(self, now_s: float, timeout_s: float, tol_rad: float) -> list[str]:
        if now_s - self.refused_s < REFUSED_FAULT_S:
            return [
                "robot state: a state was refused on its key (see dropped: out of order, "
                "invalid, stale or another joint count; two publishers?)"
            ]
        if self.stamp_s is None or self.state is None:
            return []
        age = now_s - self.stamp_s
        if age > timeout_s:
            return [f"robot state {age:.3f} s old > {timeout_s}"]
        want = self.expected(self.stamp_s)
        if want is None:
            return []  # nothing commanded yet at that time: the worker has just started
        err = max_abs_diff(self.state.q, want[0])
        if not err <= tol_rad + want[1]:  # NaN too
            bound = (
                "; this controller's states tracked the commands before: the plan is not moved "
                "to where they say the robot is (restart the controller if it was moved)"
                if self.bound else ""
            )  # fmt: skip
            return [
                f"tracking error {err:.4f} rad > tolerance {tol_rad} rad "
                f"(+ {want[1]:.4f} rad on the stop before the next command){bound}"
            ]
        self.bound = True
        return []

    def replan_refusal(
        self, q_seen: np.ndarray, now_s: float, timeout_s: float, tol_rad: float,
        q_min: np.ndarray, q_max: np.ndarray,
    ) -> str | None:  # fmt: skip
        """Why the plan may not start from the measured state an operator confirmed as
        ``q_seen (n,)`` (None: it may): the state must be fresh (younger than ``timeout_s``),
        valid, at rest, within ``tol_rad`` of ``q_seen`` and within the joint limits
        ``q_min``/``q_max (n,)``; the states must have stood still there for
        ``REPLAN_STILL_S``, with none of the key refused meanwhile (a second publisher's lies
        make the real controller's states out of order: hostile-user probe, 2026-11-30). The
        worker's own plan must be at rest too (its caller)."""
        why = self._evidence(now_s, timeout_s)
        s = self.state
        if why is not None or s is None:
            return why or "no robot state"
        off = max_abs_diff(s.q, q_seen)
        if not off <= tol_rad:
            said = ", ".join(f"{x:.4f}" for x in s.q)
            return (
                f"the controller reports the robot at [{said}] rad, {off:.4f} rad from the "
                f"position confirmed (tolerance {tol_rad} rad)"
            )
        return outside_limits(s.q, q_min, q_max)

    def _evidence(self, now_s: float, timeout_s: float) -> str | None:
        """Why the states are not evidence enough to plan from where they say the robot is
        (None: they are): the newest must be fresh (younger than ``timeout_s``) and at rest,
        the states must have stood still for ``REPLAN_STILL_S`` and none of the key have been
        refused meanwhile."""
        s = self.state
        if s is None or self.stamp_s is None:
            return "no robot state received: the worker plans from its own model of the robot"
        age = now_s - self.stamp_s
        if not age <= timeout_s:
            return f"the newest robot state is {age:.3f} s old (at most {timeout_s} s)"
        speed = max_abs(s.v)
        if not speed <= self.rest_speed:
            return (
                f"the robot is not at rest (joint speed up to {speed:.3g} rad/s; at rest: at "
                f"most {self.rest_speed:.3g}, the scenario's inputs.robot_rest_speed_rad_s)"
            )
        if now_s - self.refused_s < REPLAN_STILL_S:
            return (
                "robot states were refused on its key in the last "
                f"{REPLAN_STILL_S} s (out of order or invalid: a second publisher?)"
            )
        still = None if self.still_since_s is None else self.stamp_s - self.still_since_s
        if still is None or not still >= REPLAN_STILL_S:
            return (
                f"the robot has stood still for {0.0 if still is None else still:.2f} s "
                f"(at least {REPLAN_STILL_S} s)"
            )
        return None

    def at_rest_elsewhere(
        self, q: np.ndarray, now_s: float, timeout_s: float, tol_rad: float
    ) -> bool:
        """Fresh states at rest, standing still farther than ``tol_rad`` from ``q (n,)``, from
        a stream not bound to the commands: the robot stands somewhere else than the worker's
        follower (a restarted worker or controller), with the evidence an operator's re-plan
        needs (:meth:`_evidence`). A bound stream's is a tracking fault only (module notes),
        unless the controller says it brakes on its own and the robot rests where one of the
        stops the worker sent ends: the contract's controller, its commands expired, brakes
        along the newest stop it has, which a late or lost newer command leaves older than the
        worker's own (its plan then rests elsewhere, and the controller takes no set point away
        from where it rests: a router stall of 0.7 s left both waiting on each other, ``sara-app
        soak`` probe 2026-12-04). Resting at a stop's end alone is no such evidence: a robot
        moved by hand along its back-and-forth path rested at one
        (``test_another_keys_restart_never_moves_the_plan_to_a_robot_moved_by_hand``)."""
        s = self.state
        return (  # the stops' ends last: called every cycle the follower rests
            s is not None
            and max_abs_diff(s.q, q) > tol_rad
            and self._evidence(now_s, timeout_s) is None
            and (not self.bound or self._braked_to_a_stop_end(s.q, now_s, tol_rad))
        )
