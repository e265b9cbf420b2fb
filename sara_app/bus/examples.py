"""One valid example message per key kind (cell ``cell1``, human ``h1``): for docs and tests.

``example_messages() -> {kind: (key, msg)}``. ``CONTRACT.md`` shows these payloads; a test checks
that the document's examples still decode.
"""

from __future__ import annotations

import numpy as np

from sara_app.bus import keys
from sara_app.bus.messages import (
    CapsulesMsg,
    ContactMsg,
    ControllerStatusMsg,
    HumanOccupancyMsg,
    Message,
    OccupancyMsg,
    ParamsAckMsg,
    ParamsMsg,
    PhaseLockMsg,
    ReplanMsg,
    RetireMsg,
    RobotCommandMsg,
    RobotOccupancyMsg,
    RobotStateMsg,
    ScenarioStateMsg,
    SkeletonMsg,
    StatusMsg,
    TrackerFrameMsg,
    VerdictMsg,
)

CELL, HUMAN, TRACKER = "cell1", "h1", "main"
STAMP_S = 1767225600.125  # 2026-01-01T00:00:00.125Z

# A standing person 1.2 m in front of the robot base, z up (sara_upper source: 9 joints).
_UPPER_M = {
    "head": [1.2, 0.0, 1.65],
    "neck": [1.2, 0.0, 1.45],
    "pelvis": [1.2, 0.0, 0.95],
    "l_shoulder": [1.2, 0.18, 1.42],
    "r_shoulder": [1.2, -0.18, 1.42],
    "l_elbow": [1.2, 0.22, 1.15],
    "r_elbow": [1.1, -0.22, 1.15],
    "l_wrist": [1.15, 0.24, 0.9],
    "r_wrist": [0.95, -0.22, 1.0],
}


def example_messages() -> dict[str, tuple[str, Message]]:
    """``{kind: (key, message)}`` for every kind of ``sara_app.bus.keys.KINDS``."""
    seq, t = 42, STAMP_S
    q = [0.0, -0.4, 0.0, -2.1, 0.0, 1.7, 0.8]
    skel = SkeletonMsg(
        seq=seq,
        stamp_s=t,
        source="sara_upper",
        joints=_UPPER_M,
        velocities={j: [0.0, 0.0, 0.0] for j in _UPPER_M} | {"r_wrist": [-0.5, 0.0, 0.1]},
        position_uncertainty_m=0.02,
        velocity_uncertainty_mps=0.1,
    )
    one = CapsulesMsg.from_arrays(np.array([[[1.2, 0.0, 0.9], [1.2, 0.0, 1.5]]]), np.array([0.4]))
    robot = CapsulesMsg.from_arrays(
        np.array([[[0.0, 0.0, 0.0], [0.0, 0.0, 0.33]], [[0.0, 0.0, 0.33], [0.0, 0.0, 0.65]]]),
        np.array([0.09, 0.08]),
    )
    msgs: dict[str, Message] = {
        "skeleton": skel,
        "robot_state": RobotStateMsg(seq=seq, stamp_s=t, q=q, q_dot=[0.0] * 7),
        "robot_command": RobotCommandMsg(
            seq=seq,
            stamp_s=t,
            q=q,
            q_dot=[0.0, 0.5] + [0.0] * 5,
            q_ddot=[0.0] * 7,
            mode="intended",
            valid_until_s=t + 0.010,
            failsafe_t_s=[0.004, 0.02, 0.05],
            failsafe_q=[q, [0.0, -0.398] + q[2:], [0.0, -0.397] + q[2:]],
        ),  # fmt: skip
        "verdict": VerdictMsg(
            seq=seq,
            stamp_s=t,
            cell=CELL,
            safety_mode="ssm",
            mode="intended",
            results={"pos": False, "vel": True, "acc": True},
            skeleton_age_s={HUMAN: 0.012},
            min_distance_m=0.31,
            cycle_time_us=410.0,
            faults=[],
            dropped={"out_of_order": 1},
        ),
        "occupancy": OccupancyMsg(
            seq=seq,
            stamp_s=t,
            humans=[
                HumanOccupancyMsg(
                    id=HUMAN,
                    kind="upper",
                    joints_m=[x for p in _UPPER_M.values() for x in p],
                    models={"vel": one},
                )
            ],
            robot=RobotOccupancyMsg(
                link_names=["link1", "link2"], n_intervals=1, capsules=robot, verified=True
            ),
            contacts=[
                ContactMsg(human_id=HUMAN, body_part="r_hand", link="link2", kind="unconstrained")
            ],
        ),
        "params": ParamsMsg(
            seq=seq, stamp_s=t, request_id="edit-7", scenario={"name": "demo", "humans": []}
        ),
        "params_ack": ParamsAckMsg(
            seq=seq, stamp_s=t, request_id="edit-7", accepted=False, reason="robot: unknown 'x'"
        ),
        "status": StatusMsg(
            seq=seq,
            stamp_s=t,
            cell=CELL,
            state="running",
            scenario="demo",
            uptime_s=12.5,
            humans=[HUMAN],
            cycle_time_p50_us=380.0,
            cycle_time_p99_us=900.0,
            phase_lock=PhaseLockMsg(reference=HUMAN, delay_s=0.0012, hits=5120, misses=9),
        ),
        "scenario": ScenarioStateMsg(
            seq=seq, stamp_s=t, cell=CELL, revision=3, scenario={"name": "demo", "humans": []}
        ),
        "tracker_frame": TrackerFrameMsg(seq=seq, stamp_s=t, people=[HUMAN]),
        "controller_status": ControllerStatusMsg(
            seq=seq,
            stamp_s=t,
            cell=CELL,
            commands_received=30_000,
            commands_lost=2,
            commands_late=41,
            commands_expired=0,
            commands_refused=0,
            braking_events=1,
            worker_runs=1,
            braking=False,
            braking_causes={"worker": 1},
        ),
        "retire": RetireMsg(
            seq=seq,
            stamp_s=t,
            request_id="retire-3",
            human_id="h2",
            user="operator",
            reason="left through the door; the tracker lost them",
        ),  # fmt: skip
        "robot_replan": ReplanMsg(
            seq=seq,
            stamp_s=t,
            request_id="replan-4",
            q=[0.0, -0.3, 0.0, -2.2, 0.0, 2.0, 0.79],
            user="operator",
            reason="protective stop reset; the arm stands where the controller says",
        ),  # fmt: skip
    }
    ids = {"skeleton": HUMAN, "tracker_frame": TRACKER}
    return {k: (keys.key(k, CELL, ids.get(k)), m) for k, m in msgs.items()}
