"""``sara-app pfl episodes``: randomised adversarial episodes under the PFL shield (counts
harmful contacts); ``sara-app pfl throughput``: the comparison table of ``sara-app compare``
for SSM and PFL (time to goal, interventions, contacts and harmful contacts); it fails on a
harmful contact, an SSM collision or a mode that could not run."""

from __future__ import annotations

import argparse

from sara_app.options import COUNT, SECONDS, SEED


def _episodes(args: argparse.Namespace) -> int:
    from sara_app.sim.episodes import run_episodes

    summary = run_episodes(
        args.n, seed=args.seed, duration_s=args.duration, progress=not args.quiet, mode="pfl"
    )
    print("\n".join(summary.lines()))
    return 1 if summary.harmful else 0


def _throughput(args: argparse.Namespace) -> int:
    from sara_app.errors import UnknownNameError
    from sara_app.safety.settings import mode_facts
    from sara_app.scenario import scenario_names
    from sara_app.sim.compare import compare, format_table

    valid = scenario_names()
    for n in args.scenarios:
        if n not in valid:
            raise UnknownNameError("scenario", n, valid)
    rows = compare(args.scenarios or None, tuple(args.modes), args.duration, not args.quiet)
    print(format_table(rows))
    failed = [r for r in rows if r.error or r.harmful_contacts]
    failed += [r for r in rows if mode_facts(r.mode).guarantees_separation and r.collisions_moving]
    return 1 if failed else 0


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("pfl", help="power and force limiting: adversarial episodes, throughput")
    s = p.add_subparsers(dest="pfl_command", required=True)
    e = s.add_parser("episodes", help="randomised adversarial episodes under the PFL shield")
    e.add_argument("--n", type=COUNT, default=200, help="number of episodes")
    e.add_argument("--seed", type=SEED, default=0)
    e.add_argument("--duration", type=SECONDS, default=3.0, help="seconds per episode")
    e.add_argument("--quiet", action="store_true")
    e.set_defaults(run=_episodes)
    t = s.add_parser("throughput", help="SSM versus PFL on the shipped scenarios (a table)")
    t.add_argument("scenarios", nargs="*", help="scenario names (default: all shipped)")
    t.add_argument("--modes", nargs="+", default=["ssm", "pfl"], choices=["ssm", "pfl", "jssa"])
    t.add_argument("--duration", type=SECONDS, default=None, help="horizon s (default: scenario's)")
    t.add_argument("--quiet", action="store_true")
    t.set_defaults(run=_throughput)
