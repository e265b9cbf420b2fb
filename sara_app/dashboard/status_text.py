"""The dashboard's status in words: the verdict banner, the Status tab's table (mode, cycle
times, the phase lock, drops, the people's tracking and bounds, JSSA), the robot's reported
position, the PFL link-energy table with its margins, and the colour legend of the 3D view."""

from __future__ import annotations

from html import escape as html_escape
from typing import Any

import numpy as np

from sara_app.dashboard.frame import (
    CONTACT_ENV,
    CONTACT_SELF,
    CONTACT_UNCONSTRAINED,
    MODEL_NAMES,
    LinkEnergy,
)
from sara_app.dashboard.scene import (
    CONTACT_RGB,
    CRITICAL_ACTIVE_RGB,
    CRITICAL_IDLE_RGB,
    MODEL_COLORS,
    UNVERIFIED_RGB,
    VERIFIED_RGB,
)
from sara_app.dashboard.tracking_text import md_cell, tracking_rows

SMALL_MARGIN = 0.1
"""A PFL margin below this fraction of its threshold is shown amber (negative: red)."""
MARGIN_RGB = {"ok": (20, 150, 50), "small": (220, 130, 0), "negative": (210, 0, 0)}


def _swatch(rgb: tuple[int, int, int], text: str) -> str:
    r, g, b = rgb
    return f'<span style="color:rgb({r},{g},{b})">&#9632;</span> {text}'


LEGEND_MD = (
    "**Robot occupancy** (per interval and link): "
    + ", ".join(
        (
            _swatch(VERIFIED_RGB, "verified, no contact possible"),
            _swatch(UNVERIFIED_RGB, "failsafe / unverified"),
        )
    )
    + "<br/>**Contact class** (PFL, colours the capsule where a contact is first possible and "
    "the body part): "
    + ", ".join(
        (
            _swatch(CONTACT_RGB[CONTACT_UNCONSTRAINED], "unconstrained (free collision)"),
            _swatch(CONTACT_RGB[CONTACT_ENV], "clamped against the environment"),
            _swatch(CONTACT_RGB[CONTACT_SELF], "clamped between robot links"),
        )
    )
    + "<br/>**Human sets** (by default each person's effective set, what the verdict uses; the "
    "models' own sets on demand under View (this browser); the sets of legs the tracker does "
    "not measure end flat at their height bound, where the check cuts them): "
    + ", ".join(_swatch(MODEL_COLORS[m], m) for m in MODEL_NAMES)
    + "<br/>**JSSA critical pair** (robot point to human point): "
    + ", ".join(
        (_swatch(CRITICAL_ACTIVE_RGB, "JSSA active"), _swatch(CRITICAL_IDLE_RGB, "inactive"))
    )
)


def _fmt(value: Any, fmt: str, unit: str = "") -> str:
    if isinstance(value, dict):
        return ", ".join(f"{k}: {_fmt(v, fmt, unit)}" for k, v in value.items()) or "none"
    try:
        x = float(value)
    except (TypeError, ValueError):
        return "n/a"
    return f"{x:{fmt}}{unit}" if np.isfinite(x) else ("inf" if x > 0 else "n/a")


def banner_html(status: dict[str, Any]) -> str:
    """The verdict in words (``verdict_text``, ``verdict_state``, ``verdict_colour`` of the
    status: :mod:`sara_app.bus.verdict_words`) as a coloured banner; no verdict yet: a grey
    one saying so."""
    state = html_escape(str(status.get("verdict_state", "offline")))
    colour = str(status.get("verdict_colour", "#6b7280"))
    if not (colour.startswith("#") and len(colour) == 7 and colour[1:].isalnum()):
        colour = "#6b7280"
    text = html_escape(str(status.get("verdict_text", "No verdict from the cell yet")))
    style = f"background:{colour};color:#fff;padding:8px 10px;border-radius:6px;font-weight:600"
    return f'<div class="sara-verdict" data-state="{state}" style="{style}">{text}</div>'


def drops_text(dropped: Any) -> str:
    """Messages the cell refused or lost, by reason; ``superseded`` ones (a newer message of the
    same key replaced them before the cycle read it: the newest is used) are normal operation,
    not a drop, and are left out."""
    if not isinstance(dropped, dict):
        return _fmt(dropped, ".0f")
    real = {k: v for k, v in dropped.items() if k != "superseded" and v}
    return _fmt(real, ".0f") if real else "none"


def robot_q_markdown(q_rad: Any) -> str:
    """Where the controller reports the robot (joint positions, rad), as the Status tab shows
    and the re-plan confirms it."""
    if not isinstance(q_rad, list | tuple) or not q_rad:
        return "No robot position reported (no controller state yet)."
    joints = ", ".join(f"{as_float(x):.4f}" for x in q_rad)
    return f"The controller reports the robot at: [{joints}] rad"


def status_markdown(status: dict[str, Any]) -> str:
    """Markdown table of a frame's status dict (keys documented on ``DisplayFrame``)."""
    rows = [
        ("Mode", str(status.get("mode", "n/a"))),
        ("Safety mode", str(status.get("safety_mode", "n/a"))),
        ("Min. distance", _fmt(status.get("min_distance_m"), ".3f", " m")),
        (
            "Cycle p50 / p99",
            f"{_fmt(status.get('cycle_p50_us'), '.0f')} / "
            f"{_fmt(status.get('cycle_p99_us'), '.0f', ' us')}",
        ),
        (
            "Worker step p99 / periods missed",
            f"{_fmt(status.get('loop_p99_us'), '.0f', ' us')} / "
            f"{_fmt(status.get('overruns'), '.0f')}",
        ),
        ("Skeleton age", _fmt(status.get("skeleton_age_ms"), ".1f", " ms")),
        ("Dropped messages", drops_text(status.get("dropped"))),
    ]
    lock = status.get("phase_lock")
    if lock is not None:  # inputs.cycle_phase_lock on
        rows.append(
            ("Phase lock: delay / taken in time / a period late",
             f"{1e3 * lock.delay_s:.2f} ms / {lock.hits} / {lock.misses}")
        )  # fmt: skip
    if "intervened" in status:
        rows.append(("Intervening", "yes" if status["intervened"] else "no"))
    if status.get("speed_scale") is not None:
        # SSM and PFL both scale the intended step's path speed (ModeFacts.scales_speed)
        rows.append(("Speed scale", _fmt(100.0 * as_float(status["speed_scale"]), ".0f", " %")))
    rows += _people_rows(status)
    jssa = status.get("jssa")
    if isinstance(jssa, dict):
        rows += _jssa_rows(jssa)
    return "| | |\n|---|---|\n" + "\n".join(f"| {k} | {v} |" for k, v in rows)


_UNIT = {
    "speed": "m/s",
    "acceleration": "m/s²",
    "rise": "m/s",
    "displacement": "m",
    "stated_velocity": "m/s",
}


def _people_rows(status: dict[str, Any]) -> list[tuple[str, str]]:
    """The tracking now (held joints, the newest flag), whose legs are not measured and held
    below a height (their sets end there), and who breaks the bounds."""
    rows = tracking_rows(status)
    legs = status.get("legs_below_m")
    if isinstance(legs, dict):
        for who, z in list(legs.items())[:4]:
            rows.append((
                "Legs not measured",
                f"**{md_cell(str(who))}**: held below {_fmt(z, '.2f', ' m')} (assumed: "
                "standing work, feet on the floor; the pelvis's rise is monitored)",
            ))  # fmt: skip
    for v in (status.get("violations") or [])[:4]:
        if isinstance(v, dict):
            unit = _UNIT.get(str(v.get("quantity")), "")
            rows.append((
                "**Beyond bounds**",
                f"**{md_cell(str(v.get('human_id')))}** {md_cell(str(v.get('joint')))} "
                f"{md_cell(str(v.get('quantity')))} {_fmt(v.get('value'), '.2f')} > "
                f"{_fmt(v.get('bound'), '.2f', ' ' + unit)}: failsafe",
            ))  # fmt: skip
    return rows


def _jssa_rows(jssa: dict[str, Any]) -> list[tuple[str, str]]:
    if jssa.get("fallback"):
        state = f"**fallback (braking)**: {md_cell(str(jssa.get('reason', '')))}"
    else:
        state = "**active**" if jssa.get("active") else "inactive"
    rows = [("JSSA", state), ("JSSA phi", _fmt(jssa.get("phi_m2"), ".4f", " m²"))]
    if jssa.get("link") is not None:
        rows.append(("JSSA critical link", md_cell(str(jssa["link"]))))
    rows.append(
        (
            "JSSA distance / d_min",
            f"{_fmt(jssa.get('distance_m'), '.3f')} / {_fmt(jssa.get('d_min_m'), '.3f', ' m')}",
        )
    )
    return rows


def margin_level(margin_j: float | None, limit_j: float | None) -> str | None:
    """``'negative'``, ``'small'`` (below :data:`SMALL_MARGIN` of the limit) or ``'ok'``; None
    when the link cannot touch anybody."""
    if limit_j is None or margin_j is None or not np.isfinite(margin_j):
        return None
    if margin_j < 0.0:
        return "negative"
    return "small" if margin_j < SMALL_MARGIN * limit_j else "ok"


def link_energy_markdown(links: list[LinkEnergy]) -> str:
    """Markdown table of each link's energy, threshold and margin [J] (margin coloured), and
    the body part, human, contact class and shape that set the threshold (one narrow column)."""
    if not links:
        return "*No link energies (shown in PFL mode).*"
    head = "| Link | E [J] | Limit [J] | Margin [J] | Set by |\n|---|---|---|---|---|\n"
    rows = []
    for e in links:
        level = margin_level(e.margin_j, e.limit_j)
        if level is None:
            limit = margin = "—"
            who = "no contact possible"
        else:
            r, g, b = MARGIN_RGB[level]
            limit = _fmt(e.limit_j, ".3f")
            margin = f'<b style="color:rgb({r},{g},{b})">{_fmt(e.margin_j, "+.3f")}</b>'
            who = (
                md_cell(f"{e.body_part or '?'} ({e.human_id or '?'})")
                + "<br/>"
                + md_cell(f"{e.contact or '?'}, {e.shape}")
            )
        rows.append(
            f"| {md_cell(e.link)} | {_fmt(e.energy_j, '.3f')} | {limit} | {margin} | {who} |"
        )
    return head + "\n".join(rows)


def as_float(value: Any) -> float:
    try:
        return float(value)
    except (TypeError, ValueError):
        return float("nan")
