"""Publish skeletons from your own tracking system to a SaRA cell: plain eclipse-zenoh + json.

    pip install eclipse-zenoh
    python example_publisher.py --connect tcp/127.0.0.1:7447 --cell cell1 --human h1

Replace ``read_tracker`` with your tracker: named joints in metres, world frame (z up). Every
frame also goes out as a tracker heartbeat listing the people in view (here: one), on
``sara/<cell>/tracker/<tracker>/frame``: the robot moves only while it arrives.
"""

import argparse
import itertools
import json
import math
import time

import zenoh

STANDING = {  # the 15 joints of source "sara_full": a person 1.5 m in front of the robot
    "head": (1.5, 0, 1.65), "neck": (1.5, 0, 1.45), "pelvis": (1.5, 0, 0.95),
    "l_shoulder": (1.5, 0.18, 1.42), "r_shoulder": (1.5, -0.18, 1.42),
    "l_elbow": (1.5, 0.22, 1.15), "r_elbow": (1.5, -0.22, 1.15),
    "l_wrist": (1.5, 0.24, 0.9), "r_wrist": (1.5, -0.24, 0.9),
    "l_hip": (1.5, 0.1, 0.92), "r_hip": (1.5, -0.1, 0.92), "l_knee": (1.5, 0.1, 0.5),
    "r_knee": (1.5, -0.1, 0.5), "l_ankle": (1.5, 0.1, 0.08), "r_ankle": (1.5, -0.1, 0.08),
}  # fmt: skip


def read_tracker(t: float) -> dict[str, list[float]]:
    """Your tracking system goes here: {joint name: [x, y, z]} in metres, world frame."""
    return {n: [x + 0.2 * math.sin(t), y, z] for n, (x, y, z) in STANDING.items()}


def _number(cast, low: float, above: bool):  # type: ignore[no-untyped-def]
    """An option's type: a finite number (``cast``: float or int) above ``low`` (or at least
    ``low``); anything else is refused where it is given, naming the option."""

    def parse(text: str):  # type: ignore[no-untyped-def]
        try:
            v = cast(text)
        except ValueError:
            v = math.nan
        if not (math.isfinite(v) and (v > low if above else v >= low)):
            kind = "a whole number" if cast is int else "a finite number"
            rule = ">" if above else ">="
            raise argparse.ArgumentTypeError(f"{text!r}; expected {kind} {rule} {low:g}")
        return v

    return parse


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--connect", default="tcp/127.0.0.1:7447", help="zenoh endpoint of the cell")
    ap.add_argument("--cell", default="cell1")
    ap.add_argument("--human", default="h1")
    ap.add_argument("--tracker", default="main", help="this tracker's id in the scenario")
    ap.add_argument("--rate", type=_number(float, 0, above=True), default=60.0, help="Hz")
    ap.add_argument("--count", type=_number(int, 0, above=False), default=0,
                    help="messages to send; 0: until Ctrl-C")  # fmt: skip
    ap.add_argument("--credentials", help="the cell's zenoh credentials file (user:password)")
    ap.add_argument("--user", default="tracker", help="the zenoh user (role) to log in as")
    args = ap.parse_args()
    # a backlog of up to 16 batches (zenoh keeps 2) when this process waits for a CPU
    queue = {"size": {"data_high": 16}}
    conf: dict = {"mode": "client", "connect": {"endpoints": [args.connect]},
                  "transport": {"link": {"tx": {"queue": queue}}}}  # fmt: skip
    if args.credentials:  # a router with access control (sara-app serve) needs a login
        with open(args.credentials) as fh:
            pw = dict(ln.strip().split(":", 1) for ln in fh if ":" in ln)[args.user]
        conf["transport"]["auth"] = {"usrpwd": {"user": args.user, "password": pw}}
    with zenoh.open(zenoh.Config.from_json5(json.dumps(conf))) as session:
        lane = zenoh.Priority.DATA_HIGH  # the evidence of people: see CONTRACT.md
        pub = session.declare_publisher(
            f"sara/{args.cell}/human/{args.human}/skeleton", priority=lane
        )
        beat = session.declare_publisher(
            f"sara/{args.cell}/tracker/{args.tracker}/frame", priority=lane
        )
        for seq in itertools.islice(itertools.count(), args.count or None):
            t = time.time()  # the measurement time, shared wall clock
            msg = {"schema_version": 1, "seq": seq, "stamp_s": t, "frame": "world",
                   "source": "sara_full", "joints": read_tracker(t)}  # fmt: skip
            pub.put(json.dumps(msg).encode())
            frame = {"schema_version": 1, "seq": seq, "stamp_s": t, "people": [args.human]}
            beat.put(json.dumps(frame).encode())
            time.sleep(1.0 / args.rate)


if __name__ == "__main__":
    main()
