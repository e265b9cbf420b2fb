"""One closed-loop run of a scenario, summarised for people: the evidence report's per-mode
runs and the dashboard's what-if runs.

A run steps :class:`~sara_app.sim.simulator.Simulation` (the real shield, sensor delay and noise,
ground-truth collision and contact checks) and returns the metrics a safety engineer compares:
time to goal, share of cycles the shield intervened or held the failsafe, the smallest true
separation, collisions while moving and harmful contacts; plus a series (separation, verdict)
for plots and, on request, frames (robot joints and skeletons) to scrub through in the 3D view.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import numpy as np

from sara_app.human.params import ReachParams
from sara_app.scenario import Scenario
from sara_app.sim.simulator import Simulation

SERIES_STEP = 5
"""Every this many cycles a point of the series (50 Hz at the shipped 250 Hz cycle)."""
FRAME_STEP = 10
"""Every this many cycles a frame to scrub through (25 Hz)."""


def run_closed_loop(
    sc: Scenario,
    duration_s: float | None = None,
    progress: Callable[[float], None] | None = None,
    frames: bool = False,
    motion_params: ReachParams | None = None,
) -> dict[str, Any]:
    """Run ``sc`` for ``duration_s`` (None: the scenario's) and summarise it (JSON-ready;
    ``frames``: also ``t_s``, ``q`` ``(n,)`` and every person's joints ``(J, 3)`` at 25 Hz;
    ``motion_params``: the bounds the scripted people move within, :class:`Simulation`)."""
    sim = Simulation(sc, motion_params)
    T = sc.sim.duration_s if duration_s is None else duration_s
    n = int(round(T / sim.dt))
    t, sep, intended = [], [], []
    shots: list[dict[str, Any]] = []
    for k in range(n):
        sim.step()
        res = sim.last
        if k % SERIES_STEP == 0 and res is not None:
            t.append(round(sim.t, 4))
            sep.append(float(sim.separation_m) if np.isfinite(sim.separation_m) else None)
            intended.append(res.mode == "intended")
        if frames and k % FRAME_STEP == 0:
            shots.append({
                "t_s": round(sim.t - sim.dt, 4), "q": sim.shield.robot_state.q.tolist(),
                "humans": [y.tolist() for y in sim.poses],
                "mode": None if res is None else res.mode,
            })  # fmt: skip
        if progress is not None and k % 50 == 0:
            progress(k / n)
    m = sim.metrics()
    out: dict[str, Any] = {
        "scenario": sc.name,
        "mode": sc.shield.mode,
        "duration_s": m.duration_s,
        "time_to_goal_s": m.time_to_goal_s,
        "collisions_moving": m.collisions_moving,
        "harmful_contacts": m.harmful_contacts,
        "min_separation_m": m.min_separation_m if np.isfinite(m.min_separation_m) else None,
        "failsafe_share": m.failsafe_share,
        "intervened_share": m.intervened_share,
        "fault_cycles": m.fault_cycles,
        "cycle_us_p99": m.cycle_us_p99,
        "series": {"t_s": t, "separation_m": sep, "intended": intended},
    }
    if frames:
        out["frames"] = shots
    return out
