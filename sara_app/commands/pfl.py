"""``sara-app pfl episodes``: randomised adversarial episodes under the PFL shield (counts
harmful contacts); ``sara-app pfl throughput``: time to goal and interventions of the shipped
scenarios under SSM and PFL, as a table."""

from __future__ import annotations

import argparse
import sys


def _episodes(args: argparse.Namespace) -> int:
    from sara_app.sim_episodes import run_episodes

    summary = run_episodes(
        args.n, seed=args.seed, duration_s=args.duration, progress=not args.quiet, mode="pfl"
    )
    print("\n".join(summary.lines()))
    return 1 if summary.harmful else 0


def _throughput(args: argparse.Namespace) -> int:
    from sara_app.scenario import load_scenario, scenario_names
    from sara_app.sim_episodes import compare_modes, throughput_lines

    names = args.scenarios or list(scenario_names())
    results = {}
    for name in names:
        if not args.quiet:
            print(f"running {name} ...", file=sys.stderr, flush=True)
        results[name] = compare_modes(load_scenario(name), tuple(args.modes), args.duration)
    print("\n".join(throughput_lines(results)))
    print(
        "\ntime to goal: until the task's last pass ends (or the horizon: 'not reached'); "
        "intervened: cycles braking or slowed below the admissible speed; harmful: contacts "
        "whose link energy reaches the threshold of the contact's actual class; contacts: "
        "steps touching a moving link (allowed in PFL)."
    )
    harmful = sum(m.harmful_contacts for r in results.values() for m in r.values())
    ssm_hits = sum(r["ssm"].collisions_moving for r in results.values() if "ssm" in r)
    return 1 if harmful or ssm_hits else 0


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("pfl", help="power and force limiting: adversarial episodes, throughput")
    s = p.add_subparsers(dest="pfl_command", required=True)
    e = s.add_parser("episodes", help="randomised adversarial episodes under the PFL shield")
    e.add_argument("--n", type=int, default=200, help="number of episodes")
    e.add_argument("--seed", type=int, default=0)
    e.add_argument("--duration", type=float, default=3.0, help="seconds per episode")
    e.add_argument("--quiet", action="store_true")
    e.set_defaults(run=_episodes)
    t = s.add_parser("throughput", help="SSM versus PFL on the shipped scenarios (a table)")
    t.add_argument("scenarios", nargs="*", help="scenario names (default: all shipped)")
    t.add_argument("--modes", nargs="+", default=["ssm", "pfl"], choices=["ssm", "pfl", "jssa"])
    t.add_argument("--duration", type=float, default=None, help="horizon s (default: scenario's)")
    t.add_argument("--quiet", action="store_true")
    t.set_defaults(run=_throughput)
