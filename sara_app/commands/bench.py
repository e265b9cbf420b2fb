"""``sara-app bench``: median and p99 of the hot-path stages."""

from __future__ import annotations

import argparse

from sara_app.options import COUNT, SECONDS, real, whole


def _bench(args: argparse.Namespace) -> None:
    from sara_app import bench

    if args.sse:
        from sara_app.bench.sse import bench_sse_load

        bench.print_rows(bench_sse_load(args.clients))
        return
    if args.live:
        from sara_app.bench.cost import bench_live, report

        loads = bench_live(args.scenario, tuple(args.people), args.seconds, args.runs,
                           args.pin_cpus, args.robot_encoding, args.phase_lock,
                           args.idle_poll)  # fmt: skip
        print(report(loads))
        return
    if args.machine:
        from sara_app.bench.machine import report as stalls_report
        from sara_app.bench.machine import witnessed

        print(stalls_report(witnessed(args.seconds, args.idle_poll)))
        return
    if args.lanes:
        from sara_app.bench.lanes import bench_lanes, default_hogs
        from sara_app.bench.lanes import report as lanes_report

        hogs = default_hogs() if args.hogs is None else args.hogs
        losses = bench_lanes(args.lane_rounds, hogs=hogs, runs=args.runs)
        print(lanes_report(losses, args.lane_rounds, hogs))
        return
    if args.cells:
        from sara_app.bench.cells import bench_cells

        bench.print_rows(bench_cells(rate_hz=args.rate))
        return
    if args.view:
        from sara_app.bench.live import bench_view_load

        bench.print_rows(bench_view_load(args.scenario, args.phase_s, args.rounds, args.pin_cpus))
        return
    bench.run(args.n)


def register(sub: argparse._SubParsersAction) -> None:
    b = sub.add_parser("bench", help="median and p99 of the hot-path stages")
    b.add_argument("-n", type=COUNT, default=2000, help="calls per stage")
    b.add_argument(
        "--view",
        action="store_true",
        help="instead: the live worker's cycle time without and with the dashboard + browser",
    )
    b.add_argument(
        "--sse",
        action="store_true",
        help="instead: verdict delivery and command loss at a bus subscriber, idle and with "
        "many API event streams",
    )
    b.add_argument(
        "--cells",
        action="store_true",
        help="instead: many cells on one router, cells x people at --rate: latency and rate",
    )
    b.add_argument(
        "--live",
        action="store_true",
        help="instead: what the live cell (router, controller, worker, replayer) costs per "
        "control cycle: CPU, context switches, messages and bytes per key, latency",
    )
    b.add_argument(
        "--machine",
        action="store_true",
        help="instead: the machine's own stalls over --seconds (a witness per CPU above a "
        "cell's processes: is this machine fit for a 500 Hz cell?)",
    )
    b.add_argument(
        "--lanes",
        action="store_true",
        help="instead: messages a loaded machine loses per key of a worker's cycle, every key "
        "in one zenoh priority and in the contract's lanes",
    )
    b.add_argument(
        "--hogs",
        type=whole(0),
        default=None,
        help="--lanes: busy processes beside the publisher (default: 2 per CPU)",
    )
    b.add_argument("--lane-rounds", type=COUNT, default=2000, help="--lanes: cycles per run")
    b.add_argument("--people", type=COUNT, nargs="+", default=[1, 4], help="loads of --live")
    b.add_argument(
        "--seconds", type=SECONDS, default=10.0, help="seconds per --live phase; of --machine"
    )
    b.add_argument("--runs", type=COUNT, default=3, help="runs per --live load (and of --lanes)")
    b.add_argument("--pin-cpus", action=argparse.BooleanOptionalAction, default=True,
                   help="--live, --view: CPUs as serve places them")  # fmt: skip
    b.add_argument("--robot-encoding", choices=("compact", "json"), default="compact",
                   help="--live: how the robot states and commands are sent")  # fmt: skip
    b.add_argument("--phase-lock", action=argparse.BooleanOptionalAction, default=False,
                   help="--live: the worker's cycles locked to the skeletons' phase (the "
                   "scenario's inputs.cycle_phase_lock, off by default)")  # fmt: skip
    b.add_argument(
        "--idle-poll",
        action="store_true",
        help="--live, --machine: the idle CPUs poll instead of halting while it measures (a "
        "CPU latency request of 0 us: write access to /dev/cpu_dma_latency)",
    )
    b.add_argument(
        "--rate", type=real(above=0.0), default=120.0, help="skeletons per second of --cells"
    )
    b.add_argument("--clients", type=COUNT, default=50, help="event streams of --sse")
    b.add_argument("--scenario", default="punches", help="scenario of --view and --live")
    b.add_argument("--phase-s", type=SECONDS, default=6.0, help="seconds per --view phase")
    b.add_argument("--rounds", type=COUNT, default=2, help="off/on rounds of --view")
    b.set_defaults(run=_bench)
