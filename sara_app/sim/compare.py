"""The safety modes side by side: every scenario run in closed loop under SSM, PFL and JSSA.

Each run is a :class:`~sara_app.sim.simulator.Simulation` of the scenario with ``shield.mode``
replaced, until the task's goal or the duration. Per run (:class:`ModeRow`):

- minimum true separation while the robot moves (truth robot, true body parts; m);
- time to goal (s; ``None``: not reached);
- share of cycles in which the safety layer intervened (``CycleResult.intervened``: SSM/PFL
  failsafe or fault, PFL slowed, JSSA filter active or braking);
- collisions while moving (simulation steps with a true overlap and the robot moving; PFL
  allows contacts below its energy thresholds, so its count is not a failure by itself) and,
  of those, the harmful contacts (link energy at or above the threshold of the contact's true
  class: a failure in every mode);
- for JSSA: steps with the robot moving and the true distance below ``d_min``, split by whether
  the closest person broke JSSA's constant-velocity assumption (eq. 4) in the last
  ``window_s``: some true joint acceleration above ``acc_tol_mps2`` (second differences of the
  true poses at the simulation step). The true poses are recorded by wrapping the simulation's
  motion sources (:class:`_Recorder`), so the simulator itself is unchanged.

A mode that cannot be built (its module missing or failing) gives a row with ``error`` set.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np

from sara_app.errors import SaraError
from sara_app.safety.settings import mode_facts, models_of_mode
from sara_app.safety.ssm import body_distance
from sara_app.scenario import Scenario, load_scenario, parse_scenario, scenario_names

if TYPE_CHECKING:
    from sara_app.sim.simulator import SimMetrics

MODES = ("ssm", "pfl", "jssa")
ACC_TOL_MPS2 = 0.5
"""True joint acceleration above which a person breaks the constant-velocity assumption."""
WINDOW_S = 0.1
"""How far back a broken assumption counts (covers sensor period, delay and velocity filter)."""
_MOVING_RAD_S = 1e-6  # as the simulator


@dataclass
class ModeRow:
    scenario: str
    mode: str
    cycles: int = 0
    min_sep_moving_m: float = math.inf
    time_to_goal_s: float | None = None
    intervened_share: float = 0.0
    collisions_moving: int = 0
    harmful_contacts: int = 0
    fault_cycles: int = 0
    below_d_min: int | None = None
    below_broken: int | None = None
    below_kept: int | None = None
    cycle_us_p50: float = 0.0
    cycle_us_p99: float = 0.0
    error: str = ""
    metrics: SimMetrics | None = None
    """All the run's metrics (speed scale, contacts, energies, ...)."""


class _Recorder:
    """A motion source that remembers the poses it hands out: ``(t, y (J, 3))`` history."""

    def __init__(self, motion: object) -> None:
        self.motion = motion
        self.t: list[float] = []
        self.y: list[np.ndarray] = []

    def pose(self, t: float, robot_ends: np.ndarray, robot_radius: np.ndarray) -> np.ndarray:
        y = self.motion.pose(t, robot_ends, robot_radius)  # type: ignore[attr-defined]
        self.t.append(t)
        self.y.append(np.array(y, dtype=float))
        return y

    def max_acc(self, window_s: float) -> float:
        """Largest true joint acceleration (m/s^2, second differences) over the last
        ``window_s`` seconds of recorded poses (0 with fewer than three poses)."""
        t = self.t
        k = len(t) - 1
        best = 0.0
        while k >= 2 and t[-1] - t[k - 2] <= window_s + 1e-12:
            h1, h2 = t[k] - t[k - 1], t[k - 1] - t[k - 2]
            if h1 > 0 and h2 > 0:
                v1 = (self.y[k] - self.y[k - 1]) / h1
                v0 = (self.y[k - 1] - self.y[k - 2]) / h2
                a = np.linalg.norm(v1 - v0, axis=1) / (0.5 * (h1 + h2))
                best = max(best, float(a.max()))
            k -= 1
        return best


def with_mode(sc: Scenario, mode: str, jssa_constraints: str | None = None) -> Scenario:
    """The scenario with its safety mode (and optionally JSSA's constraint mode, ``single`` or
    ``multi``) replaced, validated again; models the mode cannot verify with are dropped
    (:func:`~sara_app.safety.settings.models_of_mode`; none left: ``vel``)."""
    data = sc.model_dump(mode="json")
    data["shield"]["mode"] = mode
    data["shield"]["models"] = models_of_mode(mode, data["shield"]["models"]) or ["vel"]
    if jssa_constraints is not None:
        data["shield"]["jssa"]["constraints"] = jssa_constraints
    return parse_scenario(data, f"{sc.name} ({mode})")


def run_mode(
    sc: Scenario,
    mode: str,
    duration_s: float | None = None,
    *,
    acc_tol_mps2: float = ACC_TOL_MPS2,
    window_s: float = WINDOW_S,
    jssa_constraints: str | None = None,
) -> ModeRow:
    """One closed-loop run of ``sc`` under ``mode`` (until the goal or the duration)."""
    from sara_app.sim.simulator import Simulation

    row = ModeRow(sc.name, mode)
    try:
        sim = Simulation(with_mode(sc, mode, jssa_constraints))
    except (SaraError, ImportError) as e:
        row.error = f"{type(e).__name__}: {e}"
        return row
    rec = [_Recorder(m) for m in sim.motions]
    sim.motions = rec  # type: ignore[assignment]
    d_min = sc.shield.jssa.d_min_m if mode_facts(mode).safety_index else None
    below = {"broken": 0, "kept": 0}
    parts, half_th = sim.shield.reach.skeleton.part_joints, sim.params.half_thickness_m
    T = sc.sim.duration_s if duration_s is None else duration_s
    intervened = 0
    for _ in range(int(round(T / sim.dt))):
        q, v = sim.shield.robot_state.q, sim.shield.robot_state.v
        sim.step()
        res = sim.last
        intervened += bool(res is not None and res.intervened)
        if d_min is not None and rec and float(np.max(np.abs(v))) > _MOVING_RAD_S:
            kind = _below(sim, rec, q, parts, half_th, d_min, acc_tol_mps2, window_s)
            if kind:
                below[kind] += 1
        if sim.time_to_goal_s is not None:
            break
    m = sim.metrics()
    row.cycles = m.cycles
    row.min_sep_moving_m = m.min_separation_moving_m
    row.time_to_goal_s = m.time_to_goal_s
    row.intervened_share = intervened / max(m.cycles, 1)
    row.collisions_moving = m.collisions_moving
    row.harmful_contacts = m.harmful_contacts
    row.metrics = m
    row.fault_cycles = m.fault_cycles
    row.cycle_us_p50, row.cycle_us_p99 = m.cycle_us_p50, m.cycle_us_p99
    if d_min is not None:
        row.below_broken, row.below_kept = below["broken"], below["kept"]
        row.below_d_min = row.below_broken + row.below_kept
    return row


def _below(
    sim: object,
    rec: list[_Recorder],
    q: np.ndarray,
    parts: np.ndarray,
    half_th: np.ndarray,
    d_min: float,
    acc_tol: float,
    window_s: float,
) -> str:
    """``"broken"`` / ``"kept"`` when the true distance (robot at ``q``, poses just recorded)
    is below ``d_min`` and the closest person did / did not accelerate lately; else ``""``."""
    ends, rad = sim.truth_robot.link_capsules(q)  # type: ignore[attr-defined]
    d = [body_distance(r.y[-1], parts, half_th, ends, rad) for r in rec]
    i = int(np.argmin(d))
    if d[i] >= d_min:
        return ""
    return "broken" if rec[i].max_acc(window_s) > acc_tol else "kept"


def compare(
    names: list[str] | tuple[str, ...] | None = None,
    modes: tuple[str, ...] = MODES,
    duration_s: float | None = None,
    progress: bool = False,
    jssa_constraints: str | None = None,
) -> list[ModeRow]:
    """Rows for every scenario (default: the shipped ones) and mode, scenario-major;
    ``jssa_constraints`` overrides the scenarios' JSSA constraint mode."""
    import sys

    rows = []
    for name in names or scenario_names():
        sc = load_scenario(name)
        for mode in modes:
            if progress:
                print(f"{name} / {mode} ...", file=sys.stderr, flush=True)
            rows.append(run_mode(sc, mode, duration_s, jssa_constraints=jssa_constraints))
    return rows


def _f(x: float | None, fmt: str, none: str = "-") -> str:
    if x is None:
        return none
    return "inf" if math.isinf(x) else format(x, fmt)


def format_table(rows: list[ModeRow]) -> str:
    """One line per (scenario, mode); JSSA's ``< d_min`` steps as ``total (broken/kept)``."""
    head = (
        f"{'scenario':22s} {'mode':5s} {'min sep m':>9s} {'goal s':>7s} {'interv %':>8s} "
        f"{'coll':>5s} {'harm':>5s} {'faults':>6s} {'<d_min (cv broken/kept)':>24s} {'p50 us':>7s} "
        f"{'p99 us':>7s}"
    )
    lines = [head, "-" * len(head)]
    for r in rows:
        if r.error:
            lines.append(f"{r.scenario:22s} {r.mode:5s} not available: {r.error[:80]}")
            continue
        below = (
            "-" if r.below_d_min is None else f"{r.below_d_min} ({r.below_broken}/{r.below_kept})"
        )
        lines.append(
            f"{r.scenario:22s} {r.mode:5s} {_f(r.min_sep_moving_m, '.3f'):>9s} "
            f"{_f(r.time_to_goal_s, '.2f', 'no'):>7s} {100 * r.intervened_share:8.1f} "
            f"{r.collisions_moving:5d} {r.harmful_contacts:5d} {r.fault_cycles:6d} {below:>24s} "
            f"{r.cycle_us_p50:7.0f} {r.cycle_us_p99:7.0f}"
        )
    lines += [
        "min sep: true separation while moving (inf: no person); goal: time to goal (no: not "
        "reached in the run); interv: cycles the layer changed the motion; coll: steps with a "
        "true overlap while moving (PFL allows contacts under its energy limits); harm: contacts "
        "whose link energy reaches the threshold of the contact's true class; <d_min: JSSA "
        f"steps moving closer than d_min, closest person accelerating > {ACC_TOL_MPS2} m/s^2 "
        f"within {WINDOW_S} s (broke constant velocity) or not (kept)",
    ]
    return "\n".join(lines)
