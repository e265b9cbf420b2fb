"""``sara-app bench`` rows: SSM and PFL shield cycles with 1, 2, 4 and 8 people.

The PFL benchmark's cell (Panda at full speed, a table, models ACC/VEL/POS) in SSM and in PFL;
the first person stands where :data:`~sara_app.bench.pfl.BENCH_CASES` puts them (clear, slowed,
braking), the others 1.6-2.2 m from the robot's base around its back, where they add work to
every check without deciding it. Every timed cycle restarts from the same state. The note gives
the cost of each person beyond the first.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np

from sara_app.bench import timeit_us
from sara_app.bench.pfl import BENCH_CASES, bench_cell
from sara_app.robot.trajectory import PathFollower
from sara_app.safety.shield import CycleResult, Shield

Row = tuple[str, float, float, str]
PEOPLE = (1, 2, 4, 8)


def others(n: int) -> list[tuple[float, float]]:
    """``n`` places 1.6-2.2 m from the base, behind the robot (x < 0)."""
    angles = np.linspace(0.6 * math.pi, 1.4 * math.pi, max(n, 1))
    return [(r * math.cos(a), r * math.sin(a)) for a, r in zip(angles, np.linspace(1.6, 2.2, n))]


def bench_rows(n: int = 2000) -> list[Row]:
    rows: list[Row] = []
    for mode in ("ssm", "pfl"):
        for case, xy in BENCH_CASES.items():
            one = None
            for H in PEOPLE:
                shield, template, people, t = bench_cell(mode, [xy, *others(H - 1)][:H])

                def cycle(
                    shield: Shield = shield, template: PathFollower = template,
                    people: list[Any] = people, t: float = t,
                ) -> CycleResult:  # fmt: skip
                    shield.follower = template.copy()
                    if hasattr(shield, "cap"):
                        shield.cap, shield._calm = math.inf, 0  # type: ignore[attr-defined]
                    return shield.cycle(t, people, want_distance=False)

                out = cycle()
                med, p99 = timeit_us(cycle, max(n // 4, 20), warmup=10)
                one = med if H == 1 else one
                extra = "" if H == 1 or one is None else f"; +{(med - one) / (H - 1):.0f} us/person"
                rows.append(
                    (
                        f"{mode} cycle, {H} {'person' if H == 1 else 'people'}, {case}",
                        med,
                        p99,
                        f"{out.mode}{extra}",
                    )
                )
    return rows
