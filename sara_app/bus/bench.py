"""Bus costs for ``sara-app bench``: encode/decode per message kind, in-process put -> drain."""

from __future__ import annotations

from typing import cast

import numpy as np

from sara_app.bench import timeit_us
from sara_app.bus import keys
from sara_app.bus.codec import Decoder
from sara_app.bus.examples import example_messages
from sara_app.bus.messages import (
    CapsulesMsg,
    HumanOccupancyMsg,
    OccupancyMsg,
    RobotOccupancyMsg,
    SkeletonMsg,
    encode,
)

Row = tuple[str, float, float, str]


def _big_occupancy(n_models: int = 5, n_parts: int = 14, k: int = 10, n_links: int = 8) -> bytes:
    """One human with ``n_models`` sets of ``n_parts * k`` capsules, robot ``k * n_links``."""
    rng = np.random.default_rng(0)

    def caps(c: int) -> CapsulesMsg:
        return CapsulesMsg.from_arrays(rng.normal(size=(c, 2, 3)), rng.uniform(0.1, 1, size=c))

    human = HumanOccupancyMsg(
        id="h1",
        kind="full",
        joints_m=rng.normal(size=45).tolist(),
        models={f"m{i}": caps(n_parts * k) for i in range(n_models)},
    )
    links = [f"link{i}" for i in range(n_links)]
    robot = RobotOccupancyMsg(
        link_names=links, n_intervals=k, capsules=caps(k * n_links), verified=True
    )
    return encode(OccupancyMsg(seq=0, stamp_s=1.0, humans=[human], robot=robot))


def _decode_row(name: str, key: str, payload: bytes, n: int) -> Row:
    dec = Decoder()

    def run() -> object:
        dec.reset()
        return dec.decode(key, payload)

    med, p99 = timeit_us(run, n=n, warmup=min(n, 50))
    return name, med, p99, f"{len(payload)} B"


def _loopback_row(n: int) -> Row:
    from sara_app.bus.session import Bus, free_port  # imports zenoh

    with Bus.router(free_port()) as bus:
        sub = bus.subscribe(keys.skeleton_keys("bench"), capacity=16)
        pub = bus.publisher(keys.skeleton_key("bench", "h1"))
        y = np.zeros((15, 3))

        def round_trip() -> None:
            pub.put(SkeletonMsg.from_arrays("full", y, seq=pub.next_seq(), stamp_s=1.0))
            while not sub.drain().messages:
                pass

        med, p99 = timeit_us(round_trip, n=n, warmup=min(n, 50))
    return "bus: skeleton build+put+drain, one session", med, p99, "in-process zenoh"


def bench_rows(n: int = 2000) -> list[Row]:
    """Median and p99 microseconds of the bus stages."""
    ex = example_messages()
    skel_key, skel = ex["skeleton"]
    full = SkeletonMsg.from_arrays("full", np.zeros((15, 3)), seq=0, stamp_s=1.0)
    verdict = ex["verdict"][1]
    occ_key = ex["occupancy"][0]
    rows = [
        _decode_row("bus: decode skeleton, 15 joints", skel_key, encode(full), n),
        _decode_row("bus: decode skeleton, 9 joints + vel", skel_key, encode(skel), n),
        _decode_row("bus: decode occupancy, 780 capsules", occ_key, _big_occupancy(), n // 10),
    ]
    med, p99 = timeit_us(lambda: encode(verdict), n=n)
    rows.append(("bus: encode verdict", med, p99, f"{len(encode(verdict))} B"))
    skel = cast(SkeletonMsg, skel)
    med, p99 = timeit_us(skel.to_arrays, n=n)
    rows.append(("bus: skeleton message -> (J, 3) arrays", med, p99, "9 joints + velocities"))
    rows.append(_loopback_row(n))
    return rows
