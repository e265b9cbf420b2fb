"""``sara-app serve`` (the whole cell on this machine), ``sara-app worker`` (one cell worker
connected to a running Zenoh router) and ``sara-app controller`` (the reference robot
controller of one cell)."""

from __future__ import annotations

import argparse

from sara_app.options import COUNT, PORT, SECONDS


def _serve(args: argparse.Namespace) -> int:
    from sara_app.ops.compile_notice import compile_notice

    with compile_notice():
        from sara_app.processes.serve import main_for_cli

    return main_for_cli(
        args.scenario, args.cell, args.zenoh_port, args.viewer_port, args.api_port, args.duration,
        api_host=args.api_host, require_token=args.require_token, cells=args.cells,
        log_level=args.log_level, pin_cpus=args.pin_cpus, watch_machine=args.watch_machine,
        idle_poll=args.idle_poll,
    )  # fmt: skip


def _observe(args: argparse.Namespace) -> int:
    import signal

    from sara_app.processes.observe import observe
    from sara_app.processes.serve import _interrupt

    signal.signal(signal.SIGINT, _interrupt)
    signal.signal(signal.SIGTERM, _interrupt)
    return observe(
        args.cell, router_host=args.router_host, zenoh_port=args.zenoh_port,
        credentials=args.credentials, viewer_port=args.viewer_port, api_port=args.api_port,
        api_host=args.api_host, require_token=args.require_token, duration_s=args.duration,
    )  # fmt: skip


def _worker(args: argparse.Namespace) -> int:
    from sara_app.ops.audit import default_audit_path
    from sara_app.ops.compile_notice import compile_notice

    with compile_notice():
        from sara_app.runtime.worker import main

    # what it answers goes to this machine's audit log, as serve's workers' does
    return main([*_process_argv(args), "--audit", str(default_audit_path())])


def _controller(args: argparse.Namespace) -> int:
    from sara_app.peers.controller import main

    return main(_process_argv(args))


def _process_argv(args: argparse.Namespace) -> list[str]:
    argv = ["--cell", args.cell, "--scenario", args.scenario, "--port", str(args.zenoh_port),
            "--router-host", args.router_host]  # fmt: skip
    if args.duration is not None:
        argv += ["--duration", str(args.duration)]
    if args.credentials is not None:
        argv += ["--zenoh-user", args.user, "--zenoh-credentials", args.credentials]
    return [*argv, "--robot-encoding", args.robot_encoding]


def register(sub: argparse._SubParsersAction) -> None:
    from sara_app.processes.defaults import (
        API_PORT,
        DEFAULT_SCENARIO,
        LOG_LEVELS,
        VIEWER_PORT,
        ZENOH_PORT,
    )

    fmt = argparse.ArgumentDefaultsHelpFormatter
    s = sub.add_parser(
        "serve", help="run the dashboard on the built-in demo cell (127.0.0.1)", formatter_class=fmt
    )
    s.add_argument("--scenario", default=DEFAULT_SCENARIO, help="a name in scenarios/ or a file")
    s.add_argument("--cell", default="cell1", help="the cell's name (its key on the bus, its URL)")
    s.add_argument(
        "--cells",
        type=COUNT,
        default=1,
        help="run this many cells (cell1, cell2, ...) on one router",
    )
    s.add_argument("--zenoh-port", type=PORT, default=ZENOH_PORT,
                   help="the zenoh router's port on 127.0.0.1 (the cell's bus)")  # fmt: skip
    s.add_argument("--viewer-port", type=PORT, default=VIEWER_PORT, help="the 3D view's port")
    s.add_argument("--api-port", type=PORT, default=API_PORT,
                   help="the REST service's and landing page's port")  # fmt: skip
    s.add_argument("--duration", type=SECONDS, default=None, help="stop after this many seconds")
    s.add_argument("--pin-cpus", action=argparse.BooleanOptionalAction, default=True,
                   help="each worker on a CPU of its own where there are more CPUs than cells, "
                   "the rest on the others")  # fmt: skip
    s.add_argument("--log-level", choices=LOG_LEVELS, default="info",
                   help="info: URLs, state changes, faults and a health line a minute; debug: "
                   "implementation details too")  # fmt: skip
    s.add_argument(
        "--api-host",
        default="127.0.0.1",
        help="address of the REST service (anything but loopback requires API tokens)",
    )
    s.add_argument(
        "--watch-machine",
        action="store_true",
        help="a witness per CPU (real-time, about 1.5 %% of each) notes the machine's own stalls "
        "of over 1 ms: a line a minute beside the cells' (did the machine hold the cell up?)",
    )
    s.add_argument(
        "--idle-poll",
        action="store_true",
        help="the idle CPUs poll while serve runs, so that they wake at once for the cell (a "
        "CPU latency request of 0 us: write access to /dev/cpu_dma_latency; power and, on a "
        "VM, host CPU)",
    )
    s.add_argument(
        "--require-token",
        action="store_true",
        help="require an API token for every change, also on loopback (tokens file printed)",
    )
    s.set_defaults(run=_serve)

    o = sub.add_parser(
        "observe",
        help="dashboards and API for cells running on another router (no cell here)",
        formatter_class=fmt,
    )
    o.add_argument("--cell", action="append", default=[], help="a cell to show (repeatable)")
    o.add_argument("--router-host", default="127.0.0.1", help="the zenoh router's address")
    o.add_argument("--zenoh-port", type=PORT, default=ZENOH_PORT, help="the router's port")
    o.add_argument("--credentials", default=None, help="the cells' zenoh credentials file")
    o.add_argument("--viewer-port", type=PORT, default=VIEWER_PORT, help="the 3D view's port")
    o.add_argument("--api-port", type=PORT, default=API_PORT, help="the REST service's port")
    o.add_argument("--api-host", default="127.0.0.1", help="address of the REST service")
    o.add_argument("--require-token", action="store_true", help="require an API token always")
    o.add_argument("--duration", type=SECONDS, default=None, help="stop after this many seconds")
    o.set_defaults(run=_observe)

    for name, run, text in (
        ("worker", _worker, "run one cell worker against a running zenoh router"),
        ("controller", _controller, "the reference robot controller of one cell (simulated)"),
    ):
        w = sub.add_parser(name, help=text, formatter_class=fmt)
        w.add_argument("--scenario", default=DEFAULT_SCENARIO, help="a name in scenarios/, a file")
        w.add_argument("--cell", default="cell1", help="the cell's name")
        w.add_argument("--zenoh-port", type=PORT, default=ZENOH_PORT, help="the router's port")
        w.add_argument("--router-host", default="127.0.0.1", help="the zenoh router's address")
        w.add_argument(
            "--duration", type=SECONDS, default=None, help="stop after this many seconds"
        )
        w.add_argument("--credentials", default=None, help="serve's zenoh credentials file")
        w.add_argument("--user", default=name, help="the zenoh user (role) to log in as")
        w.add_argument("--robot-encoding", choices=("compact", "json"), default="compact",
                       help="how it publishes robot commands/states (json: for a peer that "
                       "reads JSON only; it reads both)")  # fmt: skip
        w.set_defaults(run=run)
