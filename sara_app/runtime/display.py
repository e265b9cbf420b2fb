"""What the worker publishes for display: the people's sets and the robot's swept capsules
(:func:`occupancy_msg`), the contact classes and link energies of a PFL cycle (Thumm et al.
2024) or the safety index and critical pair of a JSSA cycle (Liu et al. 2022), the scenario in
force and the cell's status, as bus messages.

PFL results are ``(K, L, P)`` over intervals, robot links and body parts; ``P`` is the usable
humans' body parts, human-major (``part_labels`` gives each one's human id and part name).
"""

from __future__ import annotations

from collections.abc import Callable, Iterable, Sequence
from typing import Any, cast

import numpy as np

from sara_app.bus.messages import (
    CapsulesMsg,
    ContactMsg,
    HumanOccupancyMsg,
    JssaMsg,
    LinkEnergyMsg,
    OccupancyMsg,
    PhaseLockMsg,
    RobotOccupancyMsg,
    ScenarioStateMsg,
    StatusMsg,
)
from sara_app.cell.build import Cell
from sara_app.cell.intake import Track
from sara_app.dashboard.frame import EFFECTIVE
from sara_app.errors import SaraError
from sara_app.human.model_names import MODELS, MOVING_MODELS
from sara_app.human.widening import per_capsule
from sara_app.runtime.cadence import PhaseLock
from sara_app.safety.shield import CycleResult, HumanState
from sara_app.safety.thresholds import link_shapes

__all__ = ["EFFECTIVE", "effective_set", "jssa_state", "part_labels", "pfl_contacts", "pfl_links"]

CLASS_BY_CODE: dict[int, str] = {1: "unconstrained", 2: "env-constrained", 3: "self-constrained"}
"""Contact class codes of :mod:`sara_app.safety.contact` (0: none) as message names."""

MAX_CONTACTS = 64
"""At most this many contacts per message (the lowest-margin ones): a bounded display load."""


def part_labels(human_ids: Sequence[str], part_names: Sequence[str]) -> list[tuple[str, str]]:
    """``(human id, body part)`` of each of the ``len(human_ids) * len(part_names)`` parts."""
    return [(h, p) for h in human_ids for p in part_names]


def effective_set(
    sets: Sequence[tuple[np.ndarray, np.ndarray, np.ndarray]],
) -> tuple[np.ndarray, np.ndarray] | None:
    """What the per-body-part verdict uses, one capsule per body part: of the models' capsules
    for that part (``sets``: per model ``ends (..., C, 2, 3)``, ``radius (..., C)`` (one
    person, or one row per person) and its part -> capsule map ``(P,)``,
    :func:`~sara_app.human.reach.part_capsules`), the one of least volume. Every model's
    capsule of a part contains the part, so the shown capsule contains the intersection the
    verdict proves clear (it is never smaller). Returns ``ends (..., P, 2, 3)``, ``radius
    (..., P)``, or None without any model."""
    best: tuple[np.ndarray, np.ndarray] | None = None
    volume: np.ndarray | None = None
    for ends, radius, part_map in sets:
        e, r = ends[..., part_map, :, :], radius[..., part_map]
        length = np.linalg.norm(e[..., 1, :] - e[..., 0, :], axis=-1)
        v = np.pi * r**2 * (length + 4.0 / 3.0 * r)
        v = np.where(np.isfinite(v), v, np.inf)
        if best is None or volume is None:
            best, volume = (e.copy(), r.copy()), v
            continue
        smaller = v < volume
        best[0][smaller], best[1][smaller], volume[smaller] = e[smaller], r[smaller], v[smaller]
    return best


def _finite_or_none(x: float) -> float | None:
    return float(x) if np.isfinite(x) else None


def pfl_contacts(
    pfl: Any, link_names: Sequence[str], labels: Sequence[tuple[str, str]]
) -> list[ContactMsg]:
    """One message per (link, body part) that can touch over the trajectory: its class at the
    first interval where contact is possible, the largest energy and the smallest threshold."""
    cls = np.asarray(pfl.cls)
    if cls.ndim != 3 or cls.shape[2] != len(labels) or cls.shape[1] != len(link_names):
        return []
    hit = cls > 0
    pairs = np.argwhere(hit.any(axis=0))  # (C, 2): link, part
    if not len(pairs):
        return []
    first_k = hit.argmax(axis=0)  # (L, P)
    E = np.asarray(pfl.energy_J)  # (K, L)
    thr = np.where(hit, np.asarray(pfl.threshold_J), np.inf)
    margin = np.where(hit, np.asarray(pfl.margin_J), np.inf).min(axis=0)
    order = np.argsort(margin[pairs[:, 0], pairs[:, 1]], kind="stable")[:MAX_CONTACTS]
    out = []
    for i, p in pairs[order]:
        k = int(first_k[i, p])
        human, part = labels[p]
        lim = float(thr[:, i, p].min())
        e = float(np.max(np.where(hit[:, i, p], E[:, i], 0.0)))
        out.append(
            ContactMsg(
                human_id=human,
                body_part=part,
                link=link_names[i],
                kind=cast(Any, CLASS_BY_CODE[int(cls[k, i, p])]),
                interval=k,
                energy_j=e if np.isfinite(e) and e >= 0 else None,
                energy_limit_j=_finite_or_none(lim),
            )
        )
    return out


def pfl_links(
    pfl: Any,
    link_names: Sequence[str],
    labels: Sequence[tuple[str, str]],
    shapes: Sequence[str],
) -> list[LinkEnergyMsg]:
    """Per link: the largest energy over the trajectory and the contact with the least margin
    (its threshold, body part, human and class); no limit when the link cannot touch anyone."""
    E = np.asarray(pfl.energy_J)  # (K, L)
    allowed = np.asarray(pfl.allowed_J)  # (K, L)
    part = np.asarray(pfl.limiting_part)  # (K, L)
    cls = np.asarray(pfl.cls)
    out = []
    for i, name in enumerate(link_names):
        e_max = float(np.max(E[:, i])) if E.size else 0.0
        msg: dict[str, Any] = {
            "link": name,
            "energy_j": e_max if np.isfinite(e_max) and e_max >= 0 else 0.0,
            "shape": shapes[i],
        }
        margin_k = allowed[:, i] - E[:, i]
        if np.isfinite(allowed[:, i]).any():
            k = int(np.nanargmin(np.where(np.isfinite(allowed[:, i]), margin_k, np.inf)))
            p = int(part[k, i])
            msg["limit_j"] = float(allowed[k, i])
            msg["margin_j"] = _finite_or_none(float(margin_k[k]))
            if 0 <= p < len(labels):
                msg["human_id"], msg["body_part"] = labels[p]
                msg["contact"] = CLASS_BY_CODE.get(int(cls[k, i, p]))
        out.append(LinkEnergyMsg(**msg))
    return out


def _point(x: np.ndarray) -> list[float] | None:
    a = np.asarray(x, dtype=float)
    return a.tolist() if a.shape == (3,) and np.all(np.isfinite(a)) else None


def jssa_state(jssa: Any, link_names: Sequence[str], d_min_m: float) -> JssaMsg:
    """The JSSA cycle's index, activity and critical pair (two surface points)."""
    i = int(jssa.link_index)
    return JssaMsg(
        phi_m2=_finite_or_none(float(jssa.phi)),
        active=bool(jssa.active),
        fallback=bool(jssa.fallback),
        reason=str(jssa.reason)[:200],
        link=link_names[i] if 0 <= i < len(link_names) else None,
        robot_point_m=_point(jssa.robot_point),
        other_point_m=_point(jssa.other_point),
        distance_m=_finite_or_none(float(jssa.distance_m)),
        d_min_m=d_min_m,
    )


def legs_below(leg_cap: np.ndarray | None, tau_s: float) -> float | None:
    """The highest height bound of a person's unmeasured legs ``leg_cap (P, 2)``
    (:func:`~sara_app.human.legs.leg_caps`) ``tau_s`` after the measurement; None: none."""
    if leg_cap is None:
        return None
    z = leg_cap[:, 0] + leg_cap[:, 1] * tau_s
    z = z[np.isfinite(leg_cap[:, 0])]
    return float(z.max()) if z.size and np.isfinite(z).all() else None


def occupancy_msg(
    cell: Cell,
    tracks: Iterable[Track],
    res: CycleResult,
    now: float,
    next_seq: Callable[[], int],
    errors: Callable[..., None],
) -> OccupancyMsg:
    """Human sets over the whole shielded trajectory (one interval from the measurement to
    its end) for every enabled model, widened per body part as verified, their effective set,
    and the robot's interval capsules; with the mode's details (:func:`mode_details`). The sets
    of all the people in one call per model (:meth:`~sara_app.human.reach.HumanReach.
    people_sets`): built person by person, a display of 16 people took 10-14 ms of the
    verification loop's thread every 67 ms (3 control cycles lost at 250 Hz)."""
    states = [t.state for t in tracks if t.state.stamp_s is not None]
    horizon = 0.0 if res.trajectory is None else res.trajectory.duration_s
    humans = [
        HumanOccupancyMsg(id=st.id, kind="full", joints_m=st.y.ravel().tolist(),
                          models=models, legs_below_m=legs_below(st.leg_cap, age + horizon))
        for st, age, models in zip(states, *_people_models(cell, states, now, horizon))
    ]  # fmt: skip
    robot = None
    if res.robot_ends is not None and res.robot_radius is not None:
        robot = RobotOccupancyMsg(
            link_names=list(cell.robot.link_names),
            n_intervals=res.robot_ends.shape[0],
            capsules=CapsulesMsg.from_arrays(res.robot_ends, res.robot_radius),
            verified=res.verified,
        )
    msg = OccupancyMsg(seq=next_seq(), stamp_s=now, humans=humans, robot=robot)
    return mode_details(cell, msg, res, errors)


def _people_models(
    cell: Cell, states: Sequence[HumanState], now: float, horizon_s: float
) -> tuple[list[float], list[dict[str, CapsulesMsg]]]:
    """Per person of ``states`` (each stamped): the age of their measurement and their capsules
    per enabled model, widened per body part as verified, and the effective set. A model a
    person's inputs do not allow (joints not finite; velocities or their bounds not known yet,
    for :data:`~sara_app.human.model_names.MOVING_MODELS`), or whose capsules of a person are
    not all finite, is left out for that person (display only)."""
    H = len(states)
    ages = [max(now - float(st.stamp_s), 0.0) for st in states]  # type: ignore[arg-type]
    age = np.array(ages)
    models: list[dict[str, CapsulesMsg]] = [{} for _ in range(H)]
    if H == 0:
        return ages, models
    y, v, dv = (np.stack([getattr(st, a) for st in states]) for a in ("y", "v", "dv"))
    cut_p = part_cuts([st.leg_cap for st in states], age + horizon_s)
    ok_y = np.isfinite(y).all(axis=(1, 2))
    ok_v = ok_y & np.isfinite(v).all(axis=(1, 2)) & np.isfinite(dv).all(axis=1) & (dv >= 0).all(1)
    per_part: list[tuple[np.ndarray, np.ndarray, np.ndarray]] = []
    for name, part_map in zip(cell.shield.verifier.models, cell.shield.verifier.part_maps):
        use = np.flatnonzero(ok_v if name in MOVING_MODELS else ok_y)
        if not use.size:
            continue
        try:
            e, r = cell.shield.reach.people_sets(name, y[use], v[use], dv[use],
                                                 age[use], horizon_s)  # fmt: skip
        except SaraError:
            continue
        rows = np.array([_widen_row(states[h], MODELS.index(name), part_map) for h in use.tolist()])
        r = r + per_capsule(rows, part_map, r.shape[1])
        ends, radius = np.zeros((H, *e.shape[1:])), np.full((H, r.shape[1]), np.inf)
        ends[use], radius[use] = e, r
        finite = np.asarray(np.isfinite(radius).all(axis=1))
        cut_c = capsule_cuts(cut_p, part_map, r.shape[1])
        for h in np.flatnonzero(finite).tolist():
            models[h][name] = CapsulesMsg.from_arrays(ends[h], radius[h], cut_c[h])
        per_part.append((ends, np.where(finite[:, None], radius, np.inf), part_map))
    eff = effective_set(per_part)
    cut_eff = cut_p if eff is not None and cut_p.shape[1] == eff[1].shape[1] else None
    for i in range(H):
        if eff is not None and models[i]:
            cut = None if cut_eff is None else cut_eff[i]
            models[i][EFFECTIVE] = CapsulesMsg.from_arrays(eff[0][i], eff[1][i], cut)
    return ages, models


def part_cuts(leg_caps: Sequence[np.ndarray | None], tau_s: np.ndarray) -> np.ndarray:
    """``(H, P)``: the height each person's body parts are cut at over ``tau_s (H,)`` after
    their measurements, from their height bounds ``leg_caps`` (each ``(P, 2)`` of
    :func:`~sara_app.human.legs.leg_caps` or None); ``inf``: uncut. The bound at the
    horizon's end, the highest over it: the SSM check cuts interval ``k``'s set at the
    bound at that interval's end (:mod:`sara_app.safety.ssm_kernels`)."""
    P = max((c.shape[0] for c in leg_caps if c is not None), default=0)
    out = np.full((len(leg_caps), P), np.inf)
    for h, c in enumerate(leg_caps):
        if c is not None:
            z = c[:, 0] + c[:, 1] * tau_s[h]
            out[h] = np.where(np.isnan(z), np.inf, z)
    return out


def capsule_cuts(part_cut: np.ndarray, part_map: np.ndarray, C: int) -> np.ndarray:
    """``(H, C)``: each capsule's cut from its parts' ``part_cut (H, P)`` (``part_map (P,)``
    the capsule of each part): the highest of the parts it holds, ``inf`` (uncut) for a
    capsule no part maps to or when no person's parts are cut (``P = 0``)."""
    H = part_cut.shape[0]
    if part_cut.shape[1] != len(part_map):
        return np.full((H, C), np.inf)
    out = np.full((H, C), -np.inf)
    np.maximum.at(out, (np.arange(H)[:, None], np.asarray(part_map)[None, :]), part_cut)
    return np.where(out == -np.inf, np.inf, out)


def _widen_row(st: HumanState, row: int, part_map: np.ndarray) -> np.ndarray:
    """``(P,)`` person ``st``'s widening per body part of model row ``row`` (zeros: none)."""
    return np.zeros(len(part_map)) if st.widen_m is None else st.widen_m[row]


def mode_details(
    cell: Cell, msg: OccupancyMsg, res: CycleResult, errors: Callable[..., None]
) -> OccupancyMsg:
    """``msg`` with the PFL contacts and link energies, or the JSSA state, of the cycle (what
    the cycle's result carries; display only: a detail that cannot be built is left out)."""
    links = cell.robot.link_names
    sc = cell.scenario
    extra: dict[str, Any] = {}
    try:
        if res.pfl is not None:
            pfl = res.pfl
            if res.trajectory is not None:
                pfl = cell.shield.with_energies(pfl, res.trajectory)  # skipped when clear
            labels = part_labels(res.human_ids, cell.shield.reach.skeleton.parts)
            shapes = link_shapes(links, sc.shield.pfl.link_shapes)
            extra["contacts"] = pfl_contacts(pfl, links, labels)
            extra["links"] = pfl_links(pfl, links, labels, shapes)
        if res.jssa is not None:
            extra["jssa"] = jssa_state(res.jssa, links, sc.shield.jssa.d_min_m)
    except (SaraError, ValueError, IndexError) as e:  # display only: never stop the loop
        errors("display details dropped", str(e))
        return msg
    return msg.model_copy(update=extra) if extra else msg


def scenario_msg(name: str, cell: Cell, revision: int, now: float, seq: int) -> ScenarioStateMsg:
    """The scenario in force of cell ``name`` at edit ``revision``."""
    return ScenarioStateMsg(
        seq=seq,
        stamp_s=now,
        cell=name,
        revision=revision,
        scenario=cell.scenario.model_dump(mode="json"),
    )


def status_msg(
    name: str,
    cell: Cell,
    state: str,
    now: float,
    seq: int,
    *,
    uptime_s: float,
    humans: Iterable[str],
    cycle_us: Sequence[float],
    loop_us: Sequence[float] = (),
    overruns: int = 0,
    robot_q: Sequence[float] | None = None,
    phase: PhaseLock | None = None,
) -> StatusMsg:
    """The status of cell ``name``: its state, scenario, people, cycle times (the shield's
    ``cycle_us``, the whole step's ``loop_us``), missed periods, the measured robot's
    ``robot_q``, checksum and the cycle phase's lock (``phase``; None: not locked)."""
    cu = np.array(cycle_us) if len(cycle_us) else None
    lu = np.array(loop_us) if len(loop_us) else None
    return StatusMsg(
        seq=seq,
        stamp_s=now,
        cell=name,
        state=state,  # type: ignore[arg-type]
        scenario=cell.scenario.name,
        uptime_s=max(uptime_s, 0.0),
        humans=sorted(humans),
        cycle_time_p50_us=None if cu is None else float(np.median(cu)),
        cycle_time_p99_us=None if cu is None else float(np.percentile(cu, 99)),
        loop_time_p50_us=None if lu is None else float(np.median(lu)),
        loop_time_p99_us=None if lu is None else float(np.percentile(lu, 99)),
        overruns=overruns,
        robot_q_measured=None if robot_q is None else [float(x) for x in robot_q],
        config_sha256=cell.checksum,
        phase_lock=None if phase is None else phase_lock_msg(phase),
    )


def phase_lock_msg(phase: PhaseLock) -> PhaseLockMsg:
    """The status's view of the cycle phase's lock (the reference's id is a person id the
    worker accepted, so a valid name)."""
    return PhaseLockMsg(
        reference=phase.reference, delay_s=float(phase.tau_s), hits=phase.hits,
        misses=phase.misses,
    )  # fmt: skip
