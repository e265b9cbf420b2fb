"""Everything the evidence report says about one cell, gathered from the real components.

Sections (each a plain, JSON-ready structure in :class:`Evidence`):

- configuration: the scenario, its human parameter set (bounds and sources, what it claims to be
  sound for) and the configuration checksum (:mod:`sara_app.cell.checksum`);
- containment: per recording, model and horizon, the share of future joint positions inside
  the model's set (:func:`~sara_app.human.analysis.containment`), and what the tracking gate and
  the conformance monitor say about the recording under this set
  (:func:`~sara_app.human.intake.screen`);
- thresholds: the energies in force beside their sources and the ISO/TS 15066 Annex A values
  (:func:`~sara_app.ops.threshold_edit.threshold_view`) and the threshold audit log of the cell;
- stops: the robot's stopping times and distances beside ISO 13855 (:mod:`.stopping`);
- closed loop: the scenario simulated in each safety mode (time to goal, interventions,
  separation, collisions, harmful contacts; a separation series for the plot) and randomised
  adversarial episodes per mode (:func:`~sara_app.sim.episodes.run_episodes`).
"""

from __future__ import annotations

import datetime as dt
import platform
from collections.abc import Callable, Sequence
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from sara_app import __version__
from sara_app.cell.build import build_cell
from sara_app.cell.checksum import code_digest
from sara_app.human.analysis import containment
from sara_app.human.intake import screen_recording
from sara_app.human.params import ParamSet, to_reach_params
from sara_app.human.reach import HumanReach
from sara_app.human.recordings import load_recording, require_frames
from sara_app.ops.audit import AuditLog
from sara_app.ops.threshold_edit import threshold_view
from sara_app.report.stopping import stop_rows
from sara_app.scenario import RecordingHuman, Scenario
from sara_app.sim.closed_loop import run_closed_loop
from sara_app.sim.compare import with_mode
from sara_app.sim.episodes import run_episodes

HORIZONS_S = (0.1, 0.3, 0.5)
SHIPPED_RECORDINGS = ("02_01",)
"""Recordings that ship with the package (the CMU walk), checked in every report, besides the
recordings the scenario's people replay."""
MODES = ("ssm", "pfl", "jssa")

Progress = Callable[[float, str], None]


@dataclass
class Settings:
    """What the report runs: ``recordings`` (names or paths, besides the shipped ones),
    ``modes``, ``duration_s`` of each closed loop (None: the scenario's), ``episodes`` per
    mode (0: none), ``audit_path`` (None: no audit section), ``cell`` name for the audit;
    ``source``: what the scenario is, said on the report's first line (a running cell's, or a
    file that is not a running cell)."""

    recordings: Sequence[str] = ()
    modes: Sequence[str] = MODES
    duration_s: float | None = None
    episodes: int = 5
    audit_path: Path | None = None
    cell: str | None = None
    source: str = "a scenario given to the report, not a running cell"


@dataclass
class Evidence:
    generated_utc: str
    machine: str
    version: str
    code_sha256: str
    checksum: str
    scenario: dict[str, Any]
    param_set: dict[str, Any]
    containment: list[dict[str, Any]] = field(default_factory=list)
    thresholds: dict[str, Any] = field(default_factory=dict)
    audit: list[dict[str, Any]] | None = None
    worker_answers: list[dict[str, Any]] | None = None
    """The requests the cell's worker answered (edits, retirements, re-plans), newest first;
    None without an audit log or a cell."""
    stops: list[dict[str, Any]] = field(default_factory=list)
    closed_loop: list[dict[str, Any]] = field(default_factory=list)
    adversarial: list[dict[str, Any]] = field(default_factory=list)
    source: str = ""

    def to_dict(self) -> dict[str, Any]:
        return asdict(self)


def _containment_rows(
    ps: ParamSet, models: tuple[str, ...], names: Sequence[str]
) -> list[dict[str, Any]]:
    """Per recording of ``names``, model and horizon, under ``ps`` for the recording's skeleton
    (an upper-body recording gets the upper-body sets)."""
    rows = []
    for name in names:
        rec = require_frames(load_recording(name))
        reach = HumanReach(to_reach_params(ps, rec.kind))
        scr = screen_recording(reach.params, rec)
        for h in HORIZONS_S:
            res = containment(reach, rec.times_s, rec.positions_m, h, models, faulted=scr.faulted)
            for m, c in res.items():
                rows.append({
                    "recording": rec.name, "model": m, "horizon_s": h, "checked": c.checked,
                    "contained": c.contained, "share": c.share, "unflagged": c.unflagged,
                    "misses_per_joint": dict(c.misses_per_joint),
                    "worst_m": max((w.excess_m for w in c.worst), default=0.0),
                    "monitor_violations": len(scr.violations),
                    "gate_flags": {k: int(v) for k, v in scr.counts.items()},
                })  # fmt: skip
    return rows


def scenario_recordings(sc: Scenario) -> list[str]:
    """The recordings the scenario's people replay (each ships with the package or is named by
    the scenario's author), in the order of its people."""
    return [h.recording for h in sc.humans if isinstance(h, RecordingHuman)]


def gather(sc: Scenario, settings: Settings, progress: Progress | None = None) -> Evidence:
    """Run every section for scenario ``sc``; ``progress(fraction, what)`` is told along."""
    say = progress or (lambda _f, _w: None)
    modes = [m for m in settings.modes if m in MODES]
    steps = 3 + len(modes) + (len(modes) if settings.episodes else 0)
    done = 0

    def step(what: str) -> None:
        nonlocal done
        say(done / steps, what)
        done += 1

    step("building the cell")
    cell = build_cell(sc)
    ps = cell.param_set
    ev = Evidence(
        generated_utc=dt.datetime.now(dt.UTC).strftime("%Y-%m-%d %H:%M:%S UTC"),
        machine=f"{platform.platform()}, Python {platform.python_version()}",
        version=__version__,
        code_sha256=code_digest(),
        checksum=cell.checksum,
        scenario=sc.model_dump(mode="json"),
        param_set=ps.model_dump(mode="json"),
        source=settings.source,
    )
    step("containment on recordings")
    names = list(
        dict.fromkeys([*SHIPPED_RECORDINGS, *scenario_recordings(sc), *settings.recordings])
    )
    models = tuple(sc.shield.models)
    ev.containment = _containment_rows(ps, models, names)
    step("thresholds, audit log and stops")
    ev.thresholds = threshold_view(sc)
    if settings.audit_path is not None:
        log = AuditLog(settings.audit_path)
        ev.audit = [e.to_dict() for e in log.entries(settings.cell, limit=500)]
        if settings.cell is not None:
            ev.worker_answers = log.worker_answers(settings.cell, limit=500)
    wps = np.asarray(sc.task.waypoints_rad, dtype=float)
    rows = stop_rows(cell.robot, cell.limits, wps, cell.params.delay_s, cell.shield.settings.dt_s)
    ev.stops = [asdict(r) for r in rows]
    for mode in modes:
        step(f"closed loop in {mode.upper()}")
        ev.closed_loop.append(run_closed_loop(with_mode(sc, mode), settings.duration_s))
    if settings.episodes:
        for mode in modes:
            step(f"{settings.episodes} adversarial episodes in {mode.upper()}")
            s = run_episodes(settings.episodes, seed=0, mode=mode)
            ev.adversarial.append({
                "mode": mode, "episodes": s.episodes, "collisions": s.collisions,
                "harmful": s.harmful, "contacts": s.contacts,
                "min_separation_moving_m": s.min_separation_moving_m
                if np.isfinite(s.min_separation_moving_m) else None,
                "failsafe_share": s.failsafe_share,
            })  # fmt: skip
    say(1.0, "done")
    return ev
