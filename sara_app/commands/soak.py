"""``sara-app soak``: the default cell for a long time (and under faults): rate, latency,
command delivery, memory and file descriptors over time, and what the robot executed."""

from __future__ import annotations

import argparse
from pathlib import Path

from sara_app.options import SECONDS, SEED

RECOVERY_GRACE_S = 10.0
"""Faults this close to the end of a run are not held against it (a worker restarts in about
5 s)."""


def _soak(args: argparse.Namespace) -> int:
    from sara_app.bench.soak import run_soak, write

    res = run_soak(
        args.duration,
        chaos=args.chaos,
        chaos_every_s=args.chaos_every,
        sample_s=args.sample,
        scenario=args.scenario,
        seed=args.seed,
    )
    for line in write(res, Path(args.out)):
        print(line)
    print(f"written: {args.out}/soak.md, soak.json, soak.png")
    # a restarted worker loads for a few seconds: the last faults may not have recovered yet
    settled = res.duration_s - RECOVERY_GRACE_S
    unrecovered = [e for e in res.events if e.recovered_s is None and e.t_s < settled]
    bad = bool(res.off_path or res.orphans or unrecovered)
    return 1 if bad else 0


def register(sub: argparse._SubParsersAction) -> None:
    s = sub.add_parser(
        "soak",
        help="the default cell for a long time (--chaos: killing and stopping its processes)",
    )
    s.add_argument("--duration", type=SECONDS, default=1800.0, help="seconds (default 30 min)")
    s.add_argument("--chaos", action="store_true", help="kill -9 or SIGSTOP a random process")
    s.add_argument("--chaos-every", type=SECONDS, default=5.0, help="seconds between faults")
    s.add_argument("--sample", type=SECONDS, default=None, help="seconds between samples")
    s.add_argument("--scenario", default=None, help="scenario (default: serve's default)")
    s.add_argument("--seed", type=SEED, default=0)
    s.add_argument("--out", default="soak", help="folder for soak.md, soak.json, soak.png")
    s.set_defaults(run=_soak)
