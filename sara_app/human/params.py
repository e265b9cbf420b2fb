"""Human-model parameter sets: the validated file format and the plain arrays the core uses.

A parameter set is keyed by joint and body-part *name* and must be complete: a missing or unknown
name is an error that names it (a known pitfall matched parameter vectors to body parts by map
order). Sets ship as JSON files in ``sara_app/params/``; ``load_param_set`` reads one by name or
path. ``ReachParams`` is the plain, per-skeleton-kind array form the reach models take.
"""

from __future__ import annotations

import json
from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Annotated

import numpy as np
from pydantic import Field, ValidationError, field_validator

from sara_app.errors import ParameterError, UnknownNameError, describe_validation
from sara_app.human.skeleton import FULL_BODY_PARTS, FULL_JOINTS, UPPER_JOINTS, skeleton
from sara_app.settings import Strict

PARAM_DIR = Path(__file__).resolve().parent.parent / "params"
RENAMED = {"seed001_table1": "schepp2022_table1"}
"""Shipped set names before 2026-11-25: scenarios and saved cell states that still name them
load the renamed set."""

Pos = Annotated[float, Field(gt=0.0, allow_inf_nan=False)]
NonNeg = Annotated[float, Field(ge=0.0, allow_inf_nan=False)]


class JointBound(Strict):
    """Bounds of one joint's Cartesian motion."""

    v_max_mps: Pos
    a_max_mps2: Pos


class BodyPartGeometry(Strict):
    """Size of one body part: thickness is a diameter (Schepp et al. 2022); iso radius per Pereira &
    Althoff 2016."""

    thickness_m: Pos
    iso_radius_m: Pos


class ArmModelParams(Strict):
    """Pereira's 3-DOF arm model (Pereira & Althoff 2016 Sec. III-B), the same for both arms.

    Coordinates of the mid-forearm point relative to the shoulder, in the torso frame:
    polar angle theta from the medial axis, azimuth phi about it (0 = down, pi/2 = forward),
    and the prismatic extension r.
    """

    theta_min_rad: NonNeg = 0.0
    theta_max_rad: Annotated[float, Field(gt=0.0, le=float(np.pi))] = float(np.pi)
    angle_v_max_rad_s: Pos
    angle_a_max_rad_s2: Pos
    r_v_max_mps: Pos
    r_a_max_mps2: Pos
    base_rotation_rad_s: NonNeg = 0.1
    shoulder_v_max_mps: Pos = 2.0


LEG_PARTS = tuple(p for p, (a, _) in FULL_BODY_PARTS.items() if a not in UPPER_JOINTS)
"""The body parts an upper-body tracker does not measure (thighs, shins, feet)."""


class LegHeights(Strict):
    """The vertical bound of legs that a tracker does not measure (an upper-body tracker):
    every joint of leg part ``p`` is at most ``above_pelvis_m[p]`` above the pelvis joint at the
    same time (negative: below it), and the pelvis rises at most ``rise_max_mps`` (m/s, its
    vertical speed). Fitted to full-body recordings of the activity (:mod:`sara_app.human.legs`),
    which states what it assumes; the conformance monitor checks the measured pelvis's rise."""

    above_pelvis_m: dict[str, Annotated[float, Field(ge=-2.0, le=2.0, allow_inf_nan=False)]]
    rise_max_mps: Pos

    @field_validator("above_pelvis_m")
    @classmethod
    def _parts_complete(cls, v: dict[str, float]) -> dict[str, float]:
        _check_names("leg part", v, LEG_PARTS)
        return v


class DisplacementBound(Strict):
    """How far each joint gets from where it was, per horizon: ``max_m[joint][i]`` bounds the
    distance between its positions ``tau`` apart for every ``tau`` in ``(i step_s, (i + 1)
    step_s]`` (beyond the measured position's ``delta_y``), non-decreasing in ``i``. A joint
    at its peak speed does not keep it: hands that swing at 7 m/s are 0.7-0.8 m from where they
    were 0.2 s before, not 1.4 m. Fitted to recordings (:func:`sara_app.human.calibrate.
    fit_displacement`); R_VEL's radius grows by the smaller of ``v_max tau`` and this bound
    (beyond the table: its last value plus ``v_max`` times the rest), and the conformance
    monitor checks it."""

    step_s: Annotated[float, Field(ge=0.001, le=0.1, allow_inf_nan=False)]
    max_m: dict[str, list[NonNeg]]

    @field_validator("max_m")
    @classmethod
    def _tables(cls, v: dict[str, list[float]]) -> dict[str, list[float]]:
        _check_names("joint", v, FULL_JOINTS)
        sizes = {len(row) for row in v.values()}
        if len(sizes) != 1 or not 1 <= sizes.pop() <= 1000:
            raise ValueError(
                f"displacement tables of lengths {sorted({len(r) for r in v.values()})}; "
                "expected one length, 1 to 1000 values per joint"
            )
        for j, row in v.items():
            if any(b < a for a, b in zip(row, row[1:])):
                raise ValueError(f"displacement table of {j!r} decreases; expected non-decreasing")
        return v


class ParamSet(Strict):
    """A named, complete human parameter set (the JSON file format)."""

    name: str
    description: str = ""
    sources: dict[str, str] = {}
    sound_for: dict[str, str] = {}
    delta_y_m: NonNeg
    delta_v_mps: NonNeg
    delay_s: NonNeg
    iso_v_max_full_mps: Pos = 2.0
    iso_v_max_upper_mps: Pos = 1.6
    joints: dict[str, JointBound]
    body_parts: dict[str, BodyPartGeometry]
    arm: ArmModelParams
    legs_unmeasured: LegHeights | None = None
    """The vertical bound of unmeasured legs; None: the legs of an upper-body track are bounded
    by their reach from the pelvis only."""
    displacement: DisplacementBound | None = None
    """Per-horizon displacement bounds (R_VEL's radius); None: R_VEL grows by ``v_max tau``."""

    @field_validator("joints")
    @classmethod
    def _joints_complete(cls, v: dict[str, JointBound]) -> dict[str, JointBound]:
        _check_names("joint", v, FULL_JOINTS)
        return v

    @field_validator("body_parts")
    @classmethod
    def _parts_complete(cls, v: dict[str, BodyPartGeometry]) -> dict[str, BodyPartGeometry]:
        _check_names("body part", v, tuple(FULL_BODY_PARTS))
        return v


def _check_names(kind: str, given: Mapping[str, object], valid: tuple[str, ...]) -> None:
    unknown = [n for n in given if n not in valid]
    if unknown:
        raise UnknownNameError(kind, unknown[0], valid)
    missing = [n for n in valid if n not in given]
    if missing:
        raise ValueError(f"{kind} parameters missing for {missing}; every one of {valid} is needed")


@dataclass(frozen=True)
class ReachParams:
    """Arrays for one skeleton kind, in the skeleton's joint / part order.

    ``v_max_mps``, ``a_max_mps2``: ``(J,)``; ``half_thickness_m``, ``iso_radius_m``: ``(P,)``;
    ``leg_above_pelvis_m (P,)``, ``pelvis_rise_mps``: the vertical bound of unmeasured legs
    (:class:`LegHeights`; ``inf`` for parts it does not bound and where the set has none);
    ``disp_max_m (J, N)``, ``disp_step_s``: the displacement bound (:class:`DisplacementBound`;
    ``N = 0`` where the set has none).
    """

    kind: str
    name: str
    v_max_mps: np.ndarray
    a_max_mps2: np.ndarray
    half_thickness_m: np.ndarray
    iso_radius_m: np.ndarray
    delta_y_m: float
    delta_v_mps: float
    delay_s: float
    iso_v_max_mps: float
    arm: ArmModelParams
    leg_above_pelvis_m: np.ndarray
    pelvis_rise_mps: float
    disp_max_m: np.ndarray
    disp_step_s: float


def to_reach_params(ps: ParamSet, kind: str) -> ReachParams:
    """The plain arrays of ``ps`` for skeleton ``kind``, looked up by name."""
    sk = skeleton(kind)
    legs = ps.legs_unmeasured
    above = {} if legs is None else legs.above_pelvis_m
    d = ps.displacement
    disp = np.array([d.max_m[j] for j in sk.joints], dtype=float) if d is not None else None
    return ReachParams(
        kind=kind,
        name=ps.name,
        v_max_mps=np.array([ps.joints[j].v_max_mps for j in sk.joints]),
        a_max_mps2=np.array([ps.joints[j].a_max_mps2 for j in sk.joints]),
        half_thickness_m=np.array([0.5 * ps.body_parts[p].thickness_m for p in sk.parts]),
        iso_radius_m=np.array([ps.body_parts[p].iso_radius_m for p in sk.parts]),
        delta_y_m=ps.delta_y_m,
        delta_v_mps=ps.delta_v_mps,
        delay_s=ps.delay_s,
        iso_v_max_mps=ps.iso_v_max_full_mps if kind == "full" else ps.iso_v_max_upper_mps,
        arm=ps.arm,
        leg_above_pelvis_m=np.array([above.get(p, np.inf) for p in sk.parts]),
        pelvis_rise_mps=np.inf if legs is None else legs.rise_max_mps,
        disp_max_m=np.zeros((len(sk.joints), 0)) if disp is None else disp,
        disp_step_s=1.0 if ps.displacement is None else ps.displacement.step_s,
    )


def sustained_speed_mps(p: ReachParams) -> np.ndarray:
    """``(J,)`` the largest speed a joint may keep up without leaving its displacement bound:
    ``min(v_max, min_i D[i] / ((i + 1) step))`` (moving at most that fast, it is never farther
    than ``v tau <= D(tau)`` from where it was ``tau`` before; past the table ``D`` grows at
    ``v_max``); ``v_max`` where the set has no table."""
    n = p.disp_max_m.shape[1]
    if n == 0:
        return np.asarray(p.v_max_mps, dtype=float).copy()
    ends = p.disp_step_s * np.arange(1, n + 1)
    return np.minimum(p.v_max_mps, (p.disp_max_m / ends).min(axis=1))


def available_param_sets() -> tuple[str, ...]:
    """The shipped human parameter sets by name (the folder also holds the threshold sets,
    ``thresholds_*``, which are not)."""
    return tuple(
        sorted(p.stem for p in PARAM_DIR.glob("*.json") if not p.stem.startswith("thresholds_"))
    )


def parse_param_set(data: object, origin: str = "<data>") -> ParamSet:
    try:
        return ParamSet.model_validate(data)
    except ValidationError as e:  # without the values: a file's content is not repeated
        raise ParameterError(
            f"invalid parameter set {origin}: {describe_validation(e, with_input=False)}"
        ) from None


def load_param_set(name_or_path: str | Path) -> ParamSet:
    """Load a shipped set by name (see ``available_param_sets``) or a JSON file by path."""
    name_or_path = RENAMED.get(str(name_or_path), name_or_path)
    path = Path(name_or_path)
    if path.suffix != ".json":
        path = PARAM_DIR / f"{name_or_path}.json"
        if not path.exists():
            raise UnknownNameError("parameter set", str(name_or_path), available_param_sets())
    try:
        data = json.loads(path.read_text())
    except (OSError, json.JSONDecodeError) as e:
        raise ParameterError(f"cannot read parameter set {path}: {e}") from None
    return parse_param_set(data, str(path))


def save_param_set(ps: ParamSet, path: str | Path) -> None:
    """Write ``ps`` as JSON to ``path``; a path that cannot be written is a ParameterError that
    names it (the commands that fit a set end with this, after minutes of fitting). A set that
    would not load (``model_copy`` does not validate: a fit from a noise bound of NaN) is a
    ParameterError naming what is wrong, and nothing is written."""
    data = ps.model_dump()
    parse_param_set(data, f"{ps.name!r} (not written to {path})")
    try:
        Path(path).write_text(json.dumps(data, indent=2) + "\n")
    except OSError as e:
        raise ParameterError(f"cannot write parameter set {ps.name!r} to {path}: {e}") from None
