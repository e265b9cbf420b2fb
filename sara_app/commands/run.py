"""``sara-app run SCENARIO``: the closed loop headless, with metrics and an optional time series;
``sara-app adversarial``: many randomised adversarial episodes."""

from __future__ import annotations

import argparse
import json
from pathlib import Path

from sara_app.options import COUNT, SECONDS, SEED


def _run(args: argparse.Namespace) -> int:
    from sara_app.safety.settings import mode_facts
    from sara_app.scenario import load_scenario, scenario_names
    from sara_app.sim.simulator import Simulation

    names = scenario_names() if args.scenario == "all" else [args.scenario]
    worst = 0
    for name in names:
        sc = load_scenario(name)
        sim = Simulation(sc)
        series = open(args.series, "w") if args.series and len(names) == 1 else None
        try:
            if series is None:
                m = sim.run(args.duration, progress=not args.quiet)
            else:
                T = sc.sim.duration_s if args.duration is None else args.duration
                for _ in range(int(round(T / sim.dt))):
                    sim.step()
                    res = sim.last
                    if res is None:
                        continue
                    row = {
                        "t_s": round(res.t_s, 6),
                        "mode": res.mode,
                        "q": [round(float(x), 6) for x in res.command.q],
                        "min_separation_m": sim.min_sep,
                        "models": res.model_free,
                        "cycle_us": round(res.cycle_time_us, 1),
                    }
                    series.write(json.dumps(row) + "\n")
                m = sim.metrics()
        finally:
            if series is not None:
                series.close()
        print("\n".join(m.lines()))
        print()
        # what each mode must never do: SSM touch anybody while moving; PFL exceed the energy
        # threshold of a contact's actual class (contacts below it are allowed); JSSA has no
        # such guarantee, a collision is reported all the same
        allowed = mode_facts(sc.shield.mode).contact_allowed
        bad = m.harmful_contacts if allowed else m.collisions_moving
        worst = max(worst, bad)
    return 1 if worst else 0


def _adversarial(args: argparse.Namespace) -> int:
    from sara_app.sim.episodes import run_episodes

    summary = run_episodes(
        args.episodes, seed=args.seed, duration_s=args.duration, progress=not args.quiet
    )
    print("\n".join(summary.lines()))
    return 1 if summary.collisions else 0


def register(sub: argparse._SubParsersAction) -> None:
    r = sub.add_parser("run", help="run a scenario in closed-loop simulation and print metrics")
    r.add_argument("scenario", help="a name in scenarios/ (or 'all'), or a scenario file path")
    r.add_argument("--duration", type=SECONDS, default=None, help="seconds (default: scenario's)")
    r.add_argument("--series", type=Path, default=None, help="write a JSONL time series")
    r.add_argument("--quiet", action="store_true", help="no progress bar")
    r.set_defaults(run=_run)

    a = sub.add_parser("adversarial", help="randomised adversarial episodes; counts collisions")
    a.add_argument("--episodes", type=COUNT, default=200)
    a.add_argument("--seed", type=SEED, default=0)
    a.add_argument("--duration", type=SECONDS, default=3.0, help="seconds per episode")
    a.add_argument("--quiet", action="store_true")
    a.set_defaults(run=_adversarial)
