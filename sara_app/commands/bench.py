"""``sara-app bench``: median and p99 of the hot-path stages."""

from __future__ import annotations

import argparse


def _bench(args: argparse.Namespace) -> None:
    from sara_app import bench

    bench.run(args.n)


def register(sub: argparse._SubParsersAction) -> None:
    b = sub.add_parser("bench", help="median and p99 of the hot-path stages")
    b.add_argument("-n", type=int, default=2000, help="calls per stage")
    b.set_defaults(run=_bench)
