"""Randomised adversarial episodes: the shield against people who chase the robot at the models'
bounds. Each episode draws a robot task (random waypoints inside the joint limits), a person's
start position and heading, a strategy, and the models the shield uses (only models the
strategy respects: a 'limbs' adversary stretches its limbs, so R_POS and the arm model are off).
"""

from __future__ import annotations

import sys
from dataclasses import dataclass, field

import numpy as np

from sara_app.robot.model import load_robot
from sara_app.scenario import Scenario, parse_scenario
from sara_app.sim import SimMetrics, Simulation


def episode_scenario(rng: np.random.Generator, index: int, duration_s: float) -> Scenario:
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
            "shield": {"models": models},
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

    def lines(self) -> list[str]:
        return [
            f"episodes                 {self.episodes}",
            f"collisions while moving  {self.collisions}"
            + (f" in {', '.join(self.colliding)}" if self.colliding else ""),
            f"min separation moving    {self.min_separation_moving_m:.3f} m",
            f"mean failsafe share      {100 * self.failsafe_share:.1f} %",
        ]


def run_episodes(
    n: int, *, seed: int = 0, duration_s: float = 3.0, progress: bool = False
) -> EpisodeSummary:
    rng = np.random.default_rng(seed)
    out = EpisodeSummary(n, 0)
    shares = []
    for i in range(n):
        sc = episode_scenario(rng, i, duration_s)
        m = Simulation(sc).run()
        out.metrics.append(m)
        out.collisions += m.collisions_moving
        if m.collisions_moving:
            out.colliding.append(sc.name)
        out.min_separation_moving_m = min(out.min_separation_moving_m, m.min_separation_moving_m)
        shares.append(m.failsafe_share)
        if progress:
            print(f"\repisode {i + 1}/{n}  collisions {out.collisions}", end="", file=sys.stderr)
    if progress:
        print(file=sys.stderr)
    out.failsafe_share = float(np.mean(shares)) if shares else 0.0
    return out
