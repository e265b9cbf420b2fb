"""The tracking of each person in words: the present state (which joints the gate holds, why,
for how long; the newest flag and how long ago) in the status table, the totals since the
person became known apart, shown on demand (totals grow in normal operation: a count is not a
state an operator can act on).

Status entries read here (built by :func:`sara_app.dashboard.from_messages.verdict_status`):
``tracking_now``: human id -> ``{"held": [{"joint", "flag", "for_s"}], "last_flag": {"joint",
"flag", "ago_s"} or None}``; ``tracking``: human id -> flag -> joint-frames flagged.
"""

from __future__ import annotations

from typing import Any

from sara_app.bus.messages import VerdictMsg

WHY_HELD = {
    "jump": "jumped",
    "bone": "bone length off",
    "frozen": "frozen",
    "missing": "not measured",
}
"""Why the gate holds a joint, per flag, in words."""


def tracking_now_status(v: VerdictMsg) -> dict[str, dict[str, Any]]:
    """The verdict's present tracking state with ages in seconds at the verdict's stamp."""
    out: dict[str, dict[str, Any]] = {}
    for h, n in v.tracking_now.items():
        held = [{"joint": f.joint, "flag": f.flag, "for_s": max(0.0, v.stamp_s - f.stamp_s)}
                for f in n.held]  # fmt: skip
        last = n.last_flag
        out[h] = {"held": held, "last_flag": None if last is None else {
            "joint": last.joint, "flag": last.flag, "ago_s": max(0.0, v.stamp_s - last.stamp_s)
        }}  # fmt: skip
    return out


def tracking_rows(status: dict[str, Any]) -> list[tuple[str, str]]:
    """``("Tracking <id>", sentence)`` per person ever flagged; one row saying all is trusted
    when nobody was; none when the status says nothing of tracking."""
    now = status.get("tracking_now")
    if not isinstance(now, dict):
        return []
    if not now:
        return [("Tracking", "every joint trusted, no flag")]
    return [(f"Tracking {md_cell(str(h))}", _person(p)) for h, p in list(now.items())[:8]
            if isinstance(p, dict)]  # fmt: skip


def _person(p: dict[str, Any]) -> str:
    held = [f for f in p.get("held") or [] if isinstance(f, dict)]
    if held:
        joints = ", ".join(
            f"{md_cell(str(f.get('joint')))} ({WHY_HELD.get(str(f.get('flag')), 'flagged')}, "
            f"{_seconds(f.get('for_s'))})"
            for f in held[:4]
        )
        more = f" and {len(held) - 4} more" if len(held) > 4 else ""
        return f"**held**: {joints}{more}; their last trusted positions, grown, stand in"
    last = p.get("last_flag")
    if isinstance(last, dict):
        return (
            f"all joints trusted; last flag {md_cell(str(last.get('flag')))} at "
            f"{md_cell(str(last.get('joint')))} {_seconds(last.get('ago_s'))} ago"
        )
    return "all joints trusted"


def totals_markdown(status: dict[str, Any]) -> str:
    """The flag totals per person since they became known (a table), or a line saying none."""
    tracking = status.get("tracking")
    if not isinstance(tracking, dict) or not tracking:
        return "No tracking flag since the people became known."
    rows = [
        f"| {md_cell(str(h))} | " + ", ".join(f"{md_cell(str(k))} {v}" for k, v in c.items()) + " |"
        for h, c in tracking.items()
        if isinstance(c, dict)
    ]
    return "| person | joint-frames flagged |\n|---|---|\n" + "\n".join(rows)


def _seconds(value: Any) -> str:
    try:
        s = float(value)
    except (TypeError, ValueError):
        return "n/a"
    return f"{s:.1f} s" if s < 60 else f"{s / 60:.0f} min"


def md_cell(text: str) -> str:
    """Plain text for a markdown table cell (no HTML, no column breaks)."""
    return text.replace("&", "&amp;").replace("<", "&lt;").replace(">", "&gt;").replace("|", "\\|")
