"""A what-if's two runs side by side (:func:`sara_app.sim.whatif.compare`'s result) as the
dashboard and the API show them. Plain formatting, apart from the simulator: the API and the
dashboard show tables without loading the closed loop (and with it every compiled kernel) at
their start; the runs themselves happen in a job's process (:mod:`sara_app.ops.jobs`).
"""

from __future__ import annotations

from typing import Any

COMPARED: tuple[tuple[str, str], ...] = (
    ("time_to_goal_s", "time to goal (s)"),
    ("intervened_share", "cycles intervening"),
    ("failsafe_share", "cycles on the failsafe"),
    ("min_separation_m", "min. separation (m)"),
    ("collisions_moving", "collisions while moving"),
    ("harmful_contacts", "harmful contacts"),
)
"""The numbers shown side by side: key of the run summary and label."""


def table_markdown(result: dict[str, Any]) -> str:
    """The two runs side by side as a markdown table."""

    def fmt(key: str, v: Any) -> str:
        if v is None:
            return "not reached" if key == "time_to_goal_s" else "n/a"
        if key.endswith("_share"):
            return f"{100 * v:.1f} %"
        if isinstance(v, float):
            return f"{v:.3f}" if key.endswith("_m") else f"{v:.2f}"
        return str(v)

    cur, new = result["current"], result["edited"]
    rows = ["| | in force | edited |", "|---|---|---|"]
    rows += [f"| {label} | {fmt(k, cur.get(k))} | {fmt(k, new.get(k))} |" for k, label in COMPARED]
    return "\n".join(rows)
