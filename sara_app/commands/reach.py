"""Offline human-reach commands: ``reach``, ``volumes``, ``calibrate``."""

from __future__ import annotations

import argparse
from collections.abc import Callable
from pathlib import Path
from typing import TYPE_CHECKING

from sara_app.human.model_names import MODELS
from sara_app.options import SECONDS, real

if TYPE_CHECKING:
    from sara_app.human.failures import Ceilings
    from sara_app.human.recording import Recording


def _models(text: str) -> list[str]:
    names = [m.strip() for m in text.split(",") if m.strip()]
    bad = [m for m in names if m not in MODELS]
    if bad:
        raise argparse.ArgumentTypeError(f"unknown model {bad[0]!r}; valid: {', '.join(MODELS)}")
    return names


def _horizons(text: str) -> list[float]:
    """``--horizons``: comma-separated seconds, each as :data:`SECONDS` takes it."""
    out = []
    for h in text.split(","):
        try:
            out.append(SECONDS(h))
        except argparse.ArgumentTypeError:
            raise argparse.ArgumentTypeError(
                f"horizon {h.strip()!r}; expected comma-separated seconds, each finite and > 0 "
                "(for example 0.1,0.2,0.5)"
            ) from None
    return out


def _load(args: argparse.Namespace) -> Callable[[str], Recording]:
    """The recording reader with the user's BVH unit and up axis."""
    from functools import partial

    from sara_app.human.recordings import load_recording

    return partial(load_recording, unit=args.unit, up=args.up)


def _reach(args: argparse.Namespace) -> None:
    from sara_app.human.report import reach_command

    reach_command(args.recording, args.horizon, args.params, args.out, args.models, _load(args))


def _volumes(args: argparse.Namespace) -> None:
    from sara_app.human.report import volume_table

    volume_table(args.recording, args.params, args.horizons, args.png, load=_load(args))


def _calibrate(args: argparse.Namespace) -> None:
    from sara_app.human.report import calibrate_command

    calibrate_command(args.recordings, args.horizon, args.base, args.name, args.out, args.delta_y,
                      args.leave_one_out, _load(args), _ceilings(args), args.walking,
                      not args.no_widen)  # fmt: skip


def _legs(args: argparse.Namespace) -> None:
    from sara_app.human.report import legs_command

    legs_command(args.recordings, args.params, args.out, load=_load(args))


def _displacement(args: argparse.Namespace) -> None:
    from sara_app.human.displacement import Shaping
    from sara_app.human.report import displacement_command
    from sara_app.human.skeleton import FULL_JOINTS, UPPER_JOINTS

    joints = FULL_JOINTS if args.with_legs else UPPER_JOINTS
    shaping = Shaping(joints, args.margin, args.floor_speed)
    displacement_command(args.recordings, args.params, args.out, _load(args), _ceilings(args),
                         shaping)  # fmt: skip


def _ceilings(args: argparse.Namespace) -> Ceilings | None:
    from sara_app.errors import ParameterError
    from sara_app.human.failures import Ceilings

    given = (args.max_speed is not None, args.max_acc is not None)
    if given == (False, False):
        return None
    if not all(given):
        raise ParameterError("--max-speed and --max-acc go together: give both or neither")
    return Ceilings(args.max_speed, args.max_acc)


def _recording_options(p: argparse.ArgumentParser) -> None:
    p.add_argument("--unit", default=None,
                   help="a BVH file's length unit: m, cm, mm, inch or cmu (default: from the "
                   "upper arm's length)")  # fmt: skip
    p.add_argument("--up", default=None,
                   help="a BVH file's up axis: +x, -x, +y, -y, +z or -z (default: from the "
                   "rest pose)")  # fmt: skip


def register(sub: argparse._SubParsersAction) -> None:
    r = sub.add_parser("reach", help="reachable capsules per frame of a recording (JSONL) + report")
    r.add_argument(
        "recording",
        help="a .amc (with its .asf beside it), a .bvh, a .csv, or a name like 02_01 or 62_03",
    )
    r.add_argument(
        "--horizon", type=SECONDS, default=0.3, help="seconds after each frame (default 0.3)"
    )
    r.add_argument("--params", default="bench_work", help="parameter set name or JSON path")
    r.add_argument("--models", type=_models, default=list(MODELS), help="comma-separated")
    r.add_argument("--out", type=Path, default=None, help="JSONL file of capsules")
    _recording_options(r)
    r.set_defaults(run=_reach)

    v = sub.add_parser("volumes", help="set volume per model vs horizon (table + PNG)")
    v.add_argument("recording")
    v.add_argument("--params", default="bench_work")
    v.add_argument("--horizons", type=_horizons, default="0.05,0.1,0.15,0.2,0.3,0.4,0.5",
                   help="comma-separated seconds")  # fmt: skip
    v.add_argument("--png", type=Path, default=None)
    _recording_options(v)
    v.set_defaults(run=_volumes)

    c = sub.add_parser("calibrate", help="fit per-joint bounds so the models contain recordings")
    c.add_argument("recordings", nargs="+")
    c.add_argument("--horizon", type=SECONDS, default=0.5)
    c.add_argument("--base", default="schepp2022_table1")
    c.add_argument("--name", default="calibrated")
    c.add_argument(
        "--delta-y",
        type=real(low=0.0),
        default=None,
        help="the tracker's noise bound in m (default: the base set's); fitted apart from the "
        "bounds: the report shows each joint's one-frame chord deviation to choose it",
    )
    c.add_argument(
        "--leave-one-out",
        action="store_true",
        help="validate: check each recording against the set fitted on the others, and widen "
        "the written set by the margin that derives",
    )
    c.add_argument(
        "--no-widen",
        action="store_true",
        help="with --leave-one-out: record the margin in the set's record as declined instead of "
        "widening by it (the set stays as fitted; its left-out rows say how it fares on "
        "recordings it was not fitted to)",
    )
    c.add_argument(
        "--max-speed",
        type=real(above=0.0),
        default=None,
        help="ceiling of a person's joint speed in m/s (with --max-acc): reconstruction "
        "failures beyond it are split off the recordings before fitting, and listed",
    )
    c.add_argument(
        "--max-acc",
        type=real(above=0.0),
        default=None,
        help="ceiling of a joint's one-frame acceleration in m/s^2 beyond the tracker noise "
        "(with --max-speed)",
    )
    c.add_argument(
        "--walking",
        action="store_true",
        help="fit and validate on the walking pieces of each recording only (the pelvis over the "
        "floor at 0.6 m/s or more for 0.6 s or more); recordings without any are left out. "
        "One recording's walking pieces alone: name it NAME@walking",
    )
    c.add_argument("--out", type=Path, required=True)
    _recording_options(c)
    c.set_defaults(run=_calibrate)

    g = sub.add_parser(
        "legs",
        help="fit the height bound of legs an upper-body tracker does not measure (full-body "
        "recordings of the activity; leave-one-out validated) into a parameter set",
    )
    g.add_argument(
        "recordings",
        nargs="+",
        help="full-body recordings (names or files); NAME@walking: that recording's walking "
        "pieces alone",
    )
    g.add_argument("--params", default="bench_work", help="the parameter set to add it to")
    g.add_argument("--out", type=Path, required=True, help="the parameter set written (JSON)")
    _recording_options(g)
    g.set_defaults(run=_legs)

    d = sub.add_parser(
        "displacement",
        help="fit how far each joint gets within a time (R_VEL's displacement bound, "
        "leave-one-out validated) into a parameter set",
    )
    d.add_argument("recordings", nargs="+", help="recordings of the activity (names or files); "
                   "NAME@walking: that recording's walking pieces alone")  # fmt: skip
    d.add_argument("--params", default="bench_work", help="the parameter set to add it to")
    d.add_argument("--margin", type=real(low=1.0), default=1.0,
                   help="factor on the fitted table (>= 1; default 1: as fitted)")  # fmt: skip
    d.add_argument("--floor-speed", type=real(low=0.0, high=20.0), default=2.0,
                   help="m/s: every bounded joint may keep up at least this speed (default 2.0, "
                   "ISO 13855's approach speed: the CMU walk 02_01 stays within it)")  # fmt: skip
    d.add_argument("--with-legs", action="store_true",
                   help="bound the legs too (default: the upper body only; standing work moves "
                   "the legs little, so a walk past would be a violation)")  # fmt: skip
    d.add_argument("--max-speed", type=real(above=0.0), default=None,
                   help="with --max-acc: reconstruction failures beyond these ceilings are "
                   "split off first (as for calibrate)")  # fmt: skip
    d.add_argument("--max-acc", type=real(above=0.0), default=None)
    d.add_argument("--out", type=Path, required=True, help="the parameter set written (JSON)")
    _recording_options(d)
    d.set_defaults(run=_displacement)
