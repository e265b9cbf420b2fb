"""What-if runs: the cell's scenario with an edit (parameters, thresholds, safety mode, people)
run offline beside the scenario in force, so the safety engineer sees what the edit does to
safety and throughput before applying it.

Both runs are the same closed loop (:func:`~sara_app.sim.closed_loop.run_closed_loop`, same seed,
same duration); the edited one keeps frames to scrub through in the dashboard. Runs happen in a
background process at the lowest CPU priority (:mod:`sara_app.ops.jobs`), never in the worker.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

from sara_app.human.params import to_reach_params
from sara_app.scenario import Scenario
from sara_app.sim.closed_loop import run_closed_loop


def compare(
    current: Scenario,
    edited: Scenario,
    duration_s: float | None = None,
    progress: Callable[[float, str], None] | None = None,
) -> dict[str, Any]:
    """``{"current": run, "edited": run}`` (run summaries, the edited one with frames); the
    duration is the longer of the two scenarios' unless given."""
    say = progress or (lambda _f, _w: None)
    T = duration_s if duration_s is not None else max(current.sim.duration_s, edited.sim.duration_s)
    # the same people in both runs: scripted ones move within the set in force; an edited
    # human model changes what the cell assumes, not how fast the people are (generated from
    # the edited set, a smaller set made its people slower and looked safe)
    moves = to_reach_params(current.param_set(), "full")
    say(0.0, "running the settings in force")
    now = run_closed_loop(current, T, lambda f: say(0.5 * f, "running the settings in force"),
                          motion_params=moves)  # fmt: skip
    say(0.5, "running the edited settings")
    new = run_closed_loop(edited, T, lambda f: say(0.5 + 0.5 * f, "running the edited settings"),
                          frames=True, motion_params=moves)  # fmt: skip
    say(1.0, "done")
    return {"current": now, "edited": new}
