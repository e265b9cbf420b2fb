"""Randomised adversarial episodes: the shield against people who chase the robot at the models'
bounds. Each episode draws a robot task (random waypoints inside the joint limits), a person's
start position and heading, a strategy, and the models the shield uses (only models the
strategy respects: a 'limbs' adversary stretches its limbs, so R_POS and the arm model are off).

``mode="pfl"`` runs the same draws with the PFL shield and a table in front of the robot (so
clamping against the environment is possible); contacts are then allowed and the count that
must stay zero is ``harmful`` (energy at or above the threshold of the contact's actual class,
:class:`sara_app.sim.simulator.ContactTruth`).
"""

from __future__ import annotations

import sys
from dataclasses import dataclass, field

import numpy as np

from sara_app.robot.model import load_robot
from sara_app.safety.settings import mode_facts
from sara_app.scenario import Scenario, parse_scenario
from sara_app.sim.simulator import SimMetrics, Simulation

TABLE = {"name": "table", "center_m": [0.65, 0.0, 0.1], "size_m": [0.5, 1.6, 0.2]}


def episode_scenario(
    rng: np.random.Generator, index: int, duration_s: float, mode: str = "ssm"
) -> Scenario:
    robot = load_robot("panda")
    lim = robot.limits
    lo = lim.q_min + 0.25 * (lim.q_max - lim.q_min)
    hi = lim.q_max - 0.25 * (lim.q_max - lim.q_min)
    wps = rng.uniform(lo, hi, size=(int(rng.integers(2, 4)), robot.n_dof))
    strategy = str(rng.choice(["rigid", "limbs"]))
    models = ["acc", "vel", "pos"] if strategy == "rigid" else ["acc", "vel"]
    ang = rng.uniform(-np.pi, np.pi)
    dist = rng.uniform(0.9, 1.6)
    return parse_scenario(
        {
            "name": f"adversarial_{index:04d}",
            "robot": {"name": "panda"},
            "task": {"waypoints_rad": wps.tolist(), "cycles": 4},
            "humans": [
                {
                    "id": "adv",
                    "type": "adversarial",
                    "strategy": strategy,
                    "position_m": [dist * np.cos(ang), dist * np.sin(ang)],
                    "seed": int(rng.integers(1 << 30)),
                    "start_s": float(rng.uniform(0.0, 0.5)),
                    "sensor": {"rate_hz": float(rng.choice([60.0, 100.0, 120.0]))},
                }
            ],
            "environment": [TABLE] if mode_facts(mode).contact_allowed else [],
            "shield": {"models": models, "mode": mode},
            # the adversary moves at the set's bounds: the paper's, so episodes stay comparable
            "human_params": "schepp2022_table1",
            "sim": {"duration_s": duration_s, "seed": int(rng.integers(1 << 30))},
        },
        f"episode {index}",
    )


@dataclass
class EpisodeSummary:
    episodes: int
    collisions: int
    colliding: list[str] = field(default_factory=list)
    min_separation_moving_m: float = float("inf")
    failsafe_share: float = 0.0
    metrics: list[SimMetrics] = field(default_factory=list)
    mode: str = "ssm"
    harmful: int = 0
    harmful_in: list[str] = field(default_factory=list)
    contacts: int = 0
    clamped: int = 0
    max_energy_ratio: float = 0.0
    intervened_share: float = 0.0

    def lines(self) -> list[str]:
        out = [
            f"episodes                 {self.episodes} ({self.mode})",
            f"collisions while moving  {self.collisions}"
            + (f" in {', '.join(self.colliding)}" if self.colliding else ""),
            f"min separation moving    {self.min_separation_moving_m:.3f} m",
            f"mean failsafe share      {100 * self.failsafe_share:.1f} %",
        ]
        if mode_facts(self.mode).contact_allowed:
            out[1] = f"contacts while moving    {self.contacts} ({self.clamped} clamped)"
            out += [
                f"harmful contacts         {self.harmful}"
                + (f" in {', '.join(self.harmful_in)}" if self.harmful_in else ""),
                f"largest energy/threshold {self.max_energy_ratio:.3f}",
                f"mean intervened share    {100 * self.intervened_share:.1f} %",
            ]
        return out


def run_episodes(
    n: int, *, seed: int = 0, duration_s: float = 3.0, progress: bool = False, mode: str = "ssm"
) -> EpisodeSummary:
    rng = np.random.default_rng(seed)
    out = EpisodeSummary(n, 0, mode=mode)
    shares, intervened = [], []
    for i in range(n):
        sc = episode_scenario(rng, i, duration_s, mode)
        m = Simulation(sc).run()
        out.metrics.append(m)
        out.collisions += m.collisions_moving
        if m.collisions_moving:
            out.colliding.append(sc.name)
        out.harmful += m.harmful_contacts
        if m.harmful_contacts:
            out.harmful_in.append(sc.name)
        out.contacts += m.contacts_moving
        out.clamped += m.clamped_contacts
        out.max_energy_ratio = max(out.max_energy_ratio, m.max_energy_ratio)
        out.min_separation_moving_m = min(out.min_separation_moving_m, m.min_separation_moving_m)
        shares.append(m.failsafe_share)
        intervened.append(m.intervened_share)
        if progress:
            allowed = mode_facts(mode).contact_allowed
            count = f"harmful {out.harmful}" if allowed else f"collisions {out.collisions}"
            print(f"\repisode {i + 1}/{n}  {count}", end="", file=sys.stderr)
    if progress:
        print(file=sys.stderr)
    out.failsafe_share = float(np.mean(shares)) if shares else 0.0
    out.intervened_share = float(np.mean(intervened)) if intervened else 0.0
    return out
