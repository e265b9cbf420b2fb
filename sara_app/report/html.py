"""The evidence report as one self-contained HTML page: no external asset, plots embedded as
PNG data URLs (matplotlib, Agg), every value escaped."""

from __future__ import annotations

import base64
import html
import io
import json
import math
from collections.abc import Iterable, Sequence
from typing import Any

from sara_app.human.anatomy import UNMEASURED_LEG_REACH_M
from sara_app.human.sound_record import summary
from sara_app.report.evidence import HORIZONS_S, Evidence
from sara_app.report.stopping import C_M

STYLE = """
body { font-family: sans-serif; max-width: 70em; margin: 2em auto; color: #222; }
h1 { font-size: 1.6em; } h2 { border-bottom: 1px solid #ccc; margin-top: 2em; }
table { border-collapse: collapse; margin: 0.5em 0 1em; font-size: 0.9em; }
th, td { border: 1px solid #bbb; padding: 0.25em 0.6em; text-align: left; }
th { background: #eee; } .bad { color: #b00; font-weight: bold; } .ok { color: #070; }
code, pre { background: #f5f5f5; font-size: 0.85em; } pre { padding: 0.6em; overflow-x: auto; }
.checksum { font-family: monospace; font-size: 1.1em; background: #ffd; padding: 0.2em; }
"""


def _e(x: object) -> str:
    return html.escape(str(x))


def _num(x: Any, fmt: str = ".3f", unit: str = "") -> str:
    if x is None:
        return "n/a"
    if isinstance(x, bool):
        return "yes" if x else "no"
    if isinstance(x, int | float):
        return f"{x:{fmt}}{unit}"
    return _e(x)


def _table(head: Sequence[str], rows: Iterable[Sequence[str]]) -> str:
    """Cells are HTML already (escape values with :func:`_e`)."""
    out = ["<table><tr>" + "".join(f"<th>{_e(h)}</th>" for h in head) + "</tr>"]
    out += ["<tr>" + "".join(f"<td>{c}</td>" for c in r) + "</tr>" for r in rows]
    return "\n".join(out) + "</table>"


def _pyplot() -> Any:
    """matplotlib's pyplot on the Agg backend (no display), imported on use."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt


def _png(fig: Any) -> str:
    """The figure as an embedded PNG ``<img>``; the figure is closed."""
    buf = io.BytesIO()
    fig.savefig(buf, format="png", dpi=90, bbox_inches="tight")
    _pyplot().close(fig)
    data = base64.b64encode(buf.getvalue()).decode()
    return f'<img alt="plot" src="data:image/png;base64,{data}"/>'


def _closed_loop_plot(ev: Evidence) -> str:
    if not ev.closed_loop:
        return ""
    fig, ax = _pyplot().subplots(figsize=(8, 3))
    for run in ev.closed_loop:
        s = run["series"]
        sep = [float("nan") if v is None else v for v in s["separation_m"]]
        ax.plot(s["t_s"], sep, label=run["mode"].upper())
    ax.axhline(0.0, color="k", lw=0.8)
    ax.set_xlabel("time (s)")
    ax.set_ylabel("true separation (m)")
    ax.legend()
    ax.grid(alpha=0.3)
    return _png(fig)


def _containment_plot(ev: Evidence) -> str:
    if not ev.containment:
        return ""
    fig, ax = _pyplot().subplots(figsize=(8, 3))
    models = sorted({r["model"] for r in ev.containment})
    for i, h in enumerate(HORIZONS_S):
        vals = [min((r["share"] for r in ev.containment  # rows of nothing checked have none
                     if r["model"] == m and r["horizon_s"] == h and r["checked"]),
                    default=float("nan"))
                for m in models]  # fmt: skip
        ax.bar([x + 0.25 * i for x in range(len(models))], [100 * v for v in vals], 0.25,
               label=f"{h} s")  # fmt: skip
    ax.set_xticks([x + 0.25 for x in range(len(models))], models)
    ax.set_ylabel("contained (%), worst recording")
    ax.set_ylim(min(90.0, ax.get_ylim()[0]), 100.5)
    ax.legend(title="horizon")
    return _png(fig)


def _configuration(ev: Evidence) -> str:
    sc, ps = ev.scenario, ev.param_set
    joints = _table(
        ("joint", "v_max (m/s)", "a_max (m/s²)"),
        ((_e(j), _num(b["v_max_mps"], ".2f"), _num(b["a_max_mps2"], ".1f"))
         for j, b in ps["joints"].items()),
    )  # fmt: skip
    sources = _table(("what", "source"), ((_e(k), _e(v)) for k, v in ps["sources"].items()))
    record = ps["sound_for"]
    sound = _table(("claim", "on the recordings"), ((_e(k), _e(v)) for k, v in summary(record)))
    raw = _table(("entry", "as recorded"), ((_e(k), _e(v)) for k, v in record.items()))
    return (
        _configuration_head(sc, ps, joints) + f"{_displacement(ps)}{_legs(ps)}"
        f"<h4>Sources</h4>{sources}"
        f"<h4>Sound for (as the set claims; the next section checks it)</h4>{sound}"
        f"<details><summary>The set's record as written</summary>{raw}</details>"
        f"<details><summary>The scenario as validated (JSON)</summary><pre>"
        f"{_e(json.dumps(sc, indent=1))}</pre></details>"
    )


def _displacement(ps: dict) -> str:
    """R_VEL's displacement bound, where the set has one: the table at a few horizons."""
    d = ps.get("displacement")
    if not d:
        return "<p>R_VEL grows by v_max × tau (no displacement bound).</p>"
    step, rows = d["step_s"], d["max_m"]
    cols = [i for i in (4, 9, 19, 29, 49) if i < len(next(iter(rows.values())))]
    table = _table(
        ("joint", *(f"within {(i + 1) * step:g} s (m)" for i in cols)),
        ((_e(j), *(_num(r[i], ".3f") for i in cols)) for j, r in rows.items()),
    )
    return (
        "<h4>Displacement bound (R_VEL grows by the smaller of v_max × tau and this; checked "
        f"by the monitor)</h4>{table}"
    )


def _legs(ps: dict) -> str:
    """The height bound of unmeasured legs, where the set has one (ASSUMED: see its source)."""
    reach = ", ".join(f"{j} {r:g}" for j, r in UNMEASURED_LEG_REACH_M.items())
    head = (
        "<p>Legs an upper-body tracker does not measure: within their reach of the pelvis "
        f"({reach} m)"
    )
    legs = ps.get("legs_unmeasured")
    if not legs:
        return f"{head}, no bound on their height.</p>"
    parts = ", ".join(f"{_e(p)} {v:+.2f} m" for p, v in legs["above_pelvis_m"].items())
    return (
        f"{head} and at most the fitted heights above the pelvis ({parts}; ASSUMED for the "
        f"activity, not checked live); the pelvis rises at most {legs['rise_max_mps']:g} m/s "
        "(checked by the monitor).</p>"
    )


def _configuration_head(sc: dict, ps: dict, joints: str) -> str:
    return (
        f"<h2>1. Configuration</h2><p>Scenario <b>{_e(sc['name'])}</b>: {_e(sc['description'])}"
        f"</p><p>Robot {_e(sc['robot']['name'])}, safety mode "
        f"{_e(sc['shield']['mode']).upper()}, models {_e(', '.join(sc['shield']['models']))}."
        f"</p><h3>Human parameter set <code>{_e(ps['name'])}</code></h3><p>"
        f"{_e(ps['description'])}</p><p>delta_y {ps['delta_y_m']} m, delta_v "
        f"{ps['delta_v_mps']} m/s, delay {ps['delay_s']} s.</p>{joints}"
    )


def _containment(ev: Evidence) -> str:
    rows = []
    for r in ev.containment:
        ok = r["contained"] == r["checked"] > 0  # a share of nothing is no containment
        if not r["checked"]:
            share = "nothing checked"
        else:
            share = "100 %" if ok else f"{math.floor(100_000 * r['share']) / 1000:.3f} %"
        misses = ", ".join(f"{j} {n}" for j, n in r["misses_per_joint"].items()) or "none"
        rows.append((
            _e(r["recording"]), _e(r["model"]), _num(r["horizon_s"], ".1f", " s"),
            f'<span class="{"ok" if ok else "bad"}">{share}</span>',
            str(r["checked"]), _e(misses), _num(r["worst_m"], ".3f", " m"),
            str(r["monitor_violations"]),
            "" if r.get("unflagged") is None else str(r["unflagged"]),
        ))  # fmt: skip
    table = _table(("recording", "model", "horizon", "contained", "checked", "misses per joint",
                    "worst excess", "monitor violations", "unflagged misses"), rows)  # fmt: skip
    return (
        "<h2>2. Containment on recordings</h2><p>Each future joint position of the recording "
        "(every frame pair up to the horizon, at its real time difference) against the model's "
        "set from the measurement: 100 % means the set parameters hold for that motion. The "
        "conformance monitor's violations say whether the motion keeps to the set's bounds "
        "(0: the live cell would not fault this person). The <b>effective</b> row is what the "
        "verdict relies on: a body part is cleared when any model's set for it is free, so a "
        "position counts as contained only when every model in use contains it. Its "
        "<b>unflagged misses</b> are the positions outside it at a measurement the monitor had "
        "not faulted the person for: the residual risk.</p>"
        f"{_containment_plot(ev)}{table}"
    )


def _thresholds(ev: Evidence) -> str:
    tv = ev.thresholds
    rows = []
    for e in tv.get("entries", []):
        iso = "; ".join(f"{_e(i['iso_region'])} {i['energy_J']:.2f} J"
                        for i in e["iso_reference"]) or "n/a"  # fmt: skip
        value = f"<b>{e['energy_J']:g}</b>" if e["overridden"] else f"{e['energy_J']:g}"
        rows.append((_e(e["region"]), _e(e["contact"]), _e(e["shape"]), value,
                     f"{e['source_energy_J']:g}", _e(e["source_key"]), iso))  # fmt: skip
    table = _table(("region", "contact", "shape", "in force (J)", "source (J)", "source key",
                    "ISO/TS 15066 Annex A"), rows)  # fmt: skip
    sources = _table(("key", "source"), ((_e(k), _e(v)) for k, v in tv.get("sources", {}).items()))
    audit = "<p>No audit log was given (<code>--audit</code>).</p>"
    if ev.audit == []:
        audit = "<p>The audit log has no threshold change for this cell.</p>"
    elif ev.audit is not None:
        audit = _table(
            ("time (UTC)", "entry", "old (J)", "new (J)", "outcome", "user", "via", "reason"),
            ((_e(a["time_utc"]), _e(f"{a['region']}/{a['contact']}/{a['shape']}"),
              _num(a["old_energy_J"], "g"), _num(a["new_energy_J"], "g"), _e(a["outcome"]),
              _e(a["user"]), _e(a["via"]), _e(a["reason"])) for a in ev.audit),
        )  # fmt: skip
    return (
        f"<h2>3. Contact energy thresholds</h2><p>Set <code>{_e(tv.get('thresholds'))}</code>; "
        "edited values in bold. ISO/TS 15066 values are for reference (E = F²/2k; transient: "
        f"2F).</p>{table}<h4>Sources</h4>{sources}<h3>Audit log</h3>{audit}" + _worker_answers(ev)
    )


def _worker_answers(ev: Evidence) -> str:
    """The requests the cell's worker answered, whoever sent them; the configuration each left
    in force, marked where it is the one this report describes."""
    rows = ev.worker_answers
    if rows is None:
        return ""
    head = (
        "<h3>Requests the cell's worker answered</h3><p>Every scenario edit, retirement and "
        "re-plan that reached the worker, from the API, the dashboard or any other editor on the "
        "bus, as the worker recorded it, newest first; the checksum is the configuration in "
        "force after it (<b>bold</b>: this report's).</p>"
    )
    if not rows:
        return head + "<p>None recorded for this cell.</p>"
    lost = sum(int(a["lost_before"]) for a in rows)
    note = f"<p><b>{lost} answered requests could not be recorded</b> (see the worker's log).</p>"
    return head + (note if lost else "") + _table(
        ("time (UTC)", "request", "id", "user", "confirmed", "outcome", "reason", "checksum"),
        ((_e(a["time_utc"]), _e(a["request"]), _e(a["request_id"]), _e(a["user"]),
          "yes" if a["confirmed"] else "no", _e(a["outcome"]), _e(a["reason"]),
          f"<b>{_e(a['checksum'][:12])}</b>" if a["checksum"] == ev.checksum
          else _e(a["checksum"][:12])) for a in rows),
    )  # fmt: skip


def _stops(ev: Evidence) -> str:
    rows = ((str(s["waypoint"]), _num(s["stop_time_s"], ".3f", " s"),
             _num(s["stop_distance_m"], ".3f", " m"), _num(s["response_time_s"], ".3f", " s"),
             _num(s["iso_separation_m"], ".3f", " m")) for s in ev.stops)  # fmt: skip
    return (
        "<h2>4. Robot stops and ISO 13855</h2><p>Every joint at its velocity limit at each "
        "waypoint, stopped by the failsafe's joint stop at the acceleration and jerk limits; the "
        "distance is the longest path of any capsule end point. Response time = sensor delay + "
        f"one cycle + stop; ISO 13855 S = K T + C with C = {C_M * 1000:.0f} mm.</p>"
        + _table(("waypoint", "stop time", "stop distance", "response time", "ISO 13855 S"), rows)
    )


def _closed(ev: Evidence) -> str:
    rows = ((_e(r["mode"].upper()), _num(r["time_to_goal_s"], ".2f", " s")
             if r["time_to_goal_s"] is not None else "not reached",
             f"{100 * r['intervened_share']:.1f} %", f"{100 * r['failsafe_share']:.1f} %",
             _num(r["min_separation_m"], ".3f", " m"), str(r["collisions_moving"]),
             str(r["harmful_contacts"]), _num(r["cycle_us_p99"], ".0f", " us"))
            for r in ev.closed_loop)  # fmt: skip
    adv = ((_e(a["mode"].upper()), str(a["episodes"]), str(a["collisions"]), str(a["harmful"]),
            _num(a["min_separation_moving_m"], ".3f", " m"), f"{100 * a['failsafe_share']:.1f} %")
           for a in ev.adversarial)  # fmt: skip
    return (
        "<h2>5. Closed loop per safety mode</h2><p>The scenario simulated with the real shield "
        "(sensor delay and noise, ground-truth collision and contact checks). SSM must never "
        "touch while moving; PFL must never exceed the threshold of a contact's real class.</p>"
        + _table(
            (
                "mode",
                "time to goal",
                "intervening",
                "failsafe",
                "min separation",
                "collisions moving",
                "harmful contacts",
                "cycle p99",
            ),
            rows,
        )  # fmt: skip
        + _closed_loop_plot(ev)
        + "<h3>Adversarial episodes</h3>"
        + (
            _table(
                (
                    "mode",
                    "episodes",
                    "collisions moving",
                    "harmful contacts",
                    "min separation moving",
                    "failsafe",
                ),
                adv,
            )  # fmt: skip
            if ev.adversarial
            else "<p>Not run (<code>--episodes 0</code>).</p>"
        )
    )


def render(ev: Evidence) -> str:
    """The whole page."""
    name = ev.scenario["name"]
    return (
        "<!DOCTYPE html><html><head><meta charset='utf-8'><title>SaRA cell evidence: "
        f"{_e(name)}</title><style>{STYLE}</style></head><body>"
        f'<p class="source" id="source">This report describes {_e(ev.source)}.</p>'
        f"<h1>SaRA cell: evidence report for <code>{_e(name)}</code></h1>"
        f"<p>Configuration checksum (scenario, parameter and threshold sets, code): "
        f'<span class="checksum" id="checksum">{_e(ev.checksum)}</span></p>'
        "<p>A running worker reports the same value in its status (<code>config_sha256</code>, "
        "shown on the landing page and by <code>GET /api/cells</code>): equal values mean the "
        "running cell is the one this report describes.</p>"
        f"<p>Generated {_e(ev.generated_utc)} on {_e(ev.machine)}; sara-app {_e(ev.version)}, "
        f"code SHA-256 <code>{_e(ev.code_sha256)}</code>.</p>"
        + _configuration(ev)
        + _containment(ev)
        + _thresholds(ev)
        + _stops(ev)
        + _closed(ev)
        + "</body></html>"
    )
