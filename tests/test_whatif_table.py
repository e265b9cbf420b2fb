"""A what-if's table (``sara_app.sim.whatif_table``): every compared number in words, side by
side. (That the API, which shows it, starts without the simulator:
``tests/test_process_starts.py``.)"""

from __future__ import annotations

from sara_app.sim.whatif_table import COMPARED, table_markdown


def test_the_table_says_every_number_of_both_runs() -> None:
    cur = {"time_to_goal_s": 3.456, "intervened_share": 0.25, "failsafe_share": 0.0,
           "min_separation_m": 0.12345, "collisions_moving": 0, "harmful_contacts": 2}  # fmt: skip
    new = {"time_to_goal_s": None, "intervened_share": 1.0}  # not reached; the rest missing
    rows = table_markdown({"current": cur, "edited": new}).splitlines()
    assert rows[:2] == ["| | in force | edited |", "|---|---|---|"]
    assert len(rows) == 2 + len(COMPARED)
    by_label = {r.split(" | ")[0].lstrip("| "): r for r in rows[2:]}
    assert by_label["time to goal (s)"] == "| time to goal (s) | 3.46 | not reached |"
    assert by_label["cycles intervening"] == "| cycles intervening | 25.0 % | 100.0 % |"
    assert by_label["min. separation (m)"] == "| min. separation (m) | 0.123 | n/a |"
    assert by_label["harmful contacts"] == "| harmful contacts | 2 | n/a |"
