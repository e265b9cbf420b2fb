"""JSSA commands: ``jssa-study`` (Liu et al. 2022 Sec. 4 reproduction) and ``jssa-feasibility``."""

from __future__ import annotations

import argparse
from pathlib import Path

from sara_app.options import COUNT, FRACTION, SECONDS, SEED, real


def _params(args: argparse.Namespace, **over: object):  # -> JssaParams
    from sara_app.safety.jssa import make_params

    kw = dict(
        d_min_m=args.d_min,
        lambda_1=args.lambda_1,
        lambda_2=args.lambda_2,
        mode=args.mode,
        jerk_scale=args.jerk_scale,
    )
    kw.update(over)
    return make_params(**kw)


def _study(args: argparse.Namespace) -> int:
    import numpy as np

    from sara_app.safety.jssa import JssaController
    from sara_app.studies import jssa_study as st

    sc = st.seed_scenario()
    sc.duration_s = args.duration
    params = _params(args)
    tr = st.run_episode(sc, JssaController(sc.robot, params))
    print(f"JSSA profile (lambda_1={params.lambda_1}, lambda_2={params.lambda_2}, "
          f"mode={params.mode}, jerk bounds x{params.jerk_scale})")  # fmt: skip
    print(st.format_trace(tr))
    s = st.summarize(tr)
    print(f"summary: {s}")
    if args.out:
        args.out.mkdir(parents=True, exist_ok=True)
        st.plot_trace(tr, str(args.out / "jssa_profile.png"), "JSSA", params.d_min_m)
    values = tuple(float(v) for v in args.lambdas.split(","))
    print("\nSensitivity (Liu et al. 2022 Table 1 format)")
    print(st.format_table(st.sensitivity_table(sc, values, params)))
    for scale in sorted({params.jerk_scale, args.paper_jerk_scale}, reverse=True):
        res = st.compare_ssa(sc, params.model_copy(update={"jerk_scale": scale}))
        print(f"\nJSSA vs SSA (lambda_1 = 3 for SSA), jerk bounds x{scale}")
        print(st.format_comparison(res))
        if args.out:
            for name, (_, trace) in res.items():
                png = args.out / f"{name.lower()}_jerk{scale:g}.png"
                st.plot_trace(trace, str(png), f"{name}, jerk x{scale:g}", params.d_min_m)
    if args.out:
        print(f"\nPNG files in {args.out}")
    return 0 if np.isfinite(s.min_distance_m) else 1


def _feasibility(args: argparse.Namespace) -> int:
    from sara_app.robot.model import load_robot
    from sara_app.studies.jssa_feasibility import check_feasibility

    robot = load_robot(args.robot)
    params = _params(args)
    rep = check_feasibility(
        robot, params, args.samples, args.seed, args.dt, args.human_speed, args.state_fraction
    )
    print(
        f"eq. 7 on {robot.name}: lambda_1={params.lambda_1}, lambda_2={params.lambda_2}, "
        f"jerk bounds x{params.jerk_scale}, {rep.n_states} boundary states from "
        f"{args.samples} samples"
    )
    print(f"violations: {rep.n_violations}; worst min_u phi' = {rep.worst_phi_rate:.4g} "
          f"(<= 0 required) at {rep.worst_state}")  # fmt: skip
    return 0 if rep.n_violations == 0 else 1


def _common(p: argparse.ArgumentParser) -> None:
    p.add_argument("--d-min", type=real(low=0.0), default=0.05, help="d_min in m (seed: 0.05)")
    p.add_argument("--lambda-1", type=real(above=0.0), default=3.0)
    p.add_argument("--lambda-2", type=real(above=0.0), default=1.0)
    p.add_argument("--mode", choices=("single", "multi"), default="single")
    p.add_argument("--jerk-scale", type=FRACTION, default=1.0, help="fraction of the jerk limits")


def register(sub: argparse._SubParsersAction) -> None:
    s = sub.add_parser(
        "jssa-study", help="Liu et al. 2022 simulation study: profile, Table 1, vs SSA"
    )
    _common(s)
    s.add_argument("--duration", type=SECONDS, default=7.0, help="seconds (default 7)")
    s.add_argument("--lambdas", default="6,7,8", help="values for the sensitivity table")
    s.add_argument(
        "--paper-jerk-scale",
        type=FRACTION,
        default=0.01,
        help="jerk scale for the paper-like JSSA/SSA comparison (0.01: Panda bounds ~ FANUC's)",
    )
    s.add_argument("--out", type=Path, default=None, help="folder for the PNG plots")
    s.set_defaults(run=_study)

    f = sub.add_parser("jssa-feasibility", help="check Liu et al. 2022 eq. 7 by sampling states")
    _common(f)
    f.add_argument("--robot", default="panda")
    f.add_argument("--samples", type=COUNT, default=2000)
    f.add_argument("--seed", type=SEED, default=0)
    f.add_argument("--dt", type=SECONDS, default=0.008, help="control cycle in s")
    f.add_argument("--human-speed", type=real(low=0.0), default=1.6, help="m/s")
    f.add_argument(
        "--state-fraction", type=real(low=0.0, high=1.0), default=0.5, help="of v_max and a_max"
    )
    f.set_defaults(run=_feasibility)
