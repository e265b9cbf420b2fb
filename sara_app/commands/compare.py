"""``sara-app compare``: the safety modes (SSM, PFL, JSSA) side by side over scenarios."""

from __future__ import annotations

import argparse

from sara_app.options import SECONDS


def _compare(args: argparse.Namespace) -> int:
    from sara_app.errors import UnknownNameError
    from sara_app.scenario import scenario_names
    from sara_app.sim.compare import MODES, compare, format_table

    names = args.scenarios or list(scenario_names())
    valid = scenario_names()
    for n in names:
        if n not in valid:
            raise UnknownNameError("scenario", n, valid)
    modes = tuple(args.modes or MODES)
    for m in modes:
        if m not in MODES:
            raise UnknownNameError("safety mode", m, MODES)
    rows = compare(
        names, modes, args.duration, progress=not args.quiet, jssa_constraints=args.jssa_constraints
    )
    print(format_table(rows))
    return 0


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser(
        "compare",
        help="run scenarios under SSM, PFL and JSSA and print a comparison table",
    )
    p.add_argument("--scenarios", nargs="+", default=None, help="names (default: all shipped)")
    p.add_argument("--modes", nargs="+", default=None, help="subset of: ssm pfl jssa")
    p.add_argument(
        "--duration",
        type=SECONDS,
        default=None,
        help="seconds per run (default: each scenario's duration); a run ends at the goal",
    )
    p.add_argument(
        "--jssa-constraints",
        choices=("single", "multi"),
        default=None,
        help="JSSA constraint mode for every scenario (default: each scenario's own)",
    )
    p.add_argument("--quiet", action="store_true", help="no progress lines")
    p.set_defaults(run=_compare)
