"""JSON message schemas of a SaRA cell (schema version 1) and their validated models.

Every message is a JSON object with ``schema_version`` (int, ``SCHEMA_VERSION``), ``seq``
(int >= 0, strictly increasing per publisher and key) and ``stamp_s`` (float: the producer's
sensor or computation time, seconds of the shared wall clock ``time.time()``). Numbers must be
finite (no NaN, no Infinity), unknown fields are refused, list lengths must be consistent.
``MODELS_BY_KIND`` maps each key kind of ``sara_app.bus.keys`` to its model.

Decoding (``sara_app.bus.codec``) validates against these models and counts every rejection by
reason; ``encode(msg) -> bytes`` is the inverse.

Skeletons: ``joints`` maps the point names of the declared ``source`` (a source of
``sara_app.human.skeleton.SOURCES``) to ``[x, y, z]`` metres in frame ``world``. Every point the
source's mapping uses is required; a name outside the source's point set is refused.
``SkeletonMsg.to_arrays()`` gives the ``(J, 3)`` arrays in the skeleton kind's joint order.
"""

from __future__ import annotations

import math
from typing import Annotated, Any, Literal

import numpy as np
from pydantic import AfterValidator, BaseModel, ConfigDict, Field, field_validator, model_validator
from pydantic_core import PydanticCustomError

from sara_app.bus.keys import NAME_PATTERN
from sara_app.human.skeleton import COCO17_NAMES, SOURCES, skeleton
from sara_app.human.trackers import TRACKER_POINTS, UNIT_M, joint_confidence

SCHEMA_VERSION = 1
"""The schema version of every message kind but those in ``SCHEMA_VERSIONS``."""

Finite = Annotated[float, Field(allow_inf_nan=False)]
NonNeg = Annotated[float, Field(ge=0.0, allow_inf_nan=False)]
Pos = Annotated[float, Field(gt=0.0, allow_inf_nan=False)]
Vec3 = Annotated[list[Finite], Field(min_length=3, max_length=3)]
Name = Annotated[str, Field(pattern=f"^{NAME_PATTERN}$")]
MAX_JOINTS = 64
JointVector = Annotated[list[Finite], Field(min_length=1, max_length=MAX_JOINTS)]
Mode = Literal["intended", "failsafe", "rest", "fault"]

# Point names a source may send beyond those its mapping uses (accepted, not required).
_OPTIONAL_POINTS: dict[str, tuple[str, ...]] = {"coco17": COCO17_NAMES, **TRACKER_POINTS}


def source_points(source: str) -> tuple[frozenset[str], frozenset[str]]:
    """(required, allowed) point names of a skeleton source."""
    required = frozenset(n for names in SOURCES[source][1].values() for n in names)
    return required, required | frozenset(_OPTIONAL_POINTS.get(source, ()))


def _source_matrix(source: str) -> tuple[tuple[str, ...], np.ndarray]:
    """Required point names ``(P,)`` and the ``(J, P)`` averaging matrix of a source."""
    kind, table = SOURCES[source]
    names = tuple(sorted({n for pts in table.values() for n in pts}))
    joints = skeleton(kind).joints
    W = np.zeros((len(joints), len(names)))
    for i, j in enumerate(joints):
        for n in table[j]:
            W[i, names.index(n)] += 1.0 / len(table[j])
    return names, W


_MATRICES = {s: _source_matrix(s) for s in SOURCES}


def _fail(kind: str, message: str) -> PydanticCustomError:
    return PydanticCustomError(kind, message)


class _Msg(BaseModel):
    model_config = ConfigDict(strict=True, extra="forbid", frozen=True)

    schema_version: Literal[1] = 1  # required on the wire (checked by the decoder)
    seq: Annotated[int, Field(ge=0, le=2**63 - 1)]
    stamp_s: NonNeg

    @field_validator("schema_version", mode="before", check_fields=False)
    @classmethod
    def _version_is_int(cls, v: object) -> object:
        if type(v) is not int:  # JSON true would otherwise equal 1
            raise _fail("schema_version", f"schema_version {v!r} is not an int")
        return v


class SkeletonMsg(_Msg):
    """One tracked human at ``stamp_s`` (key ``sara/<cell>/human/<id>/skeleton``)."""

    frame: str = "world"
    source: str
    joints: dict[str, Vec3]
    velocities: dict[str, Vec3] | None = None
    position_uncertainty_m: NonNeg | None = None
    velocity_uncertainty_mps: NonNeg | None = None
    confidence: dict[str, Finite] | None = None
    """Per point, the tracker's own confidence (``sara_app.human.trackers``: Azure Kinect
    levels, BlazePose visibility, ZED 0-100). With it, a point may be left out: it counts as
    missing (its joint is held and widened), as does a point below the source's missing
    level; a low one widens its joint by ``inputs.low_confidence_extra_m``."""

    @field_validator("frame")
    @classmethod
    def _frame(cls, v: str) -> str:
        if v != "world":
            raise _fail("unknown_frame", f"frame {v!r} is not supported; valid: world")
        return v

    @field_validator("source")
    @classmethod
    def _source(cls, v: str) -> str:
        if v not in SOURCES:
            raise _fail("unknown_source", f"source {v!r} unknown; valid: {', '.join(SOURCES)}")
        return v

    @model_validator(mode="after")
    def _names(self) -> SkeletonMsg:
        required, allowed = source_points(self.source)
        for field, points in (("joints", self.joints), ("velocities", self.velocities)):
            if points is None:
                continue
            unknown = sorted(set(points) - allowed)
            if unknown:
                raise _fail(
                    "unknown_joint",
                    f"{field}: {unknown} are not points of source {self.source!r}; "
                    f"valid: {sorted(allowed)}",
                )
            missing = sorted(required - set(points))
            if missing and self.confidence is None:
                raise _fail("missing_joint", f"{field}: source {self.source!r} needs {missing}")
        if self.confidence is not None:
            unknown = sorted(set(self.confidence) - allowed)
            if unknown:
                raise _fail(
                    "unknown_joint",
                    f"confidence: {unknown} are not points of source {self.source!r}; "
                    f"valid: {sorted(allowed)}",
                )
            if not set(self.joints) & required:
                raise _fail("missing_joint", f"joints: source {self.source!r}: none is given")
        return self

    @property
    def kind(self) -> str:
        """The skeleton kind (``'full'`` or ``'upper'``) of the source."""
        return SOURCES[self.source][0]

    def to_arrays(self) -> tuple[np.ndarray, np.ndarray | None]:
        """Positions ``(J, 3)`` m and velocities ``(J, 3)`` m/s (or None) in ``kind`` order.

        Virtual joints are means of source points (velocities too: the mapping is linear); the
        same mapping as ``sara_app.human.skeleton.from_source``, as one matrix product.
        """
        names, W = _MATRICES[self.source]
        unit = UNIT_M.get(self.source, 1.0)

        def mapped(points: dict[str, list[float]]) -> np.ndarray:
            zero = [0.0] * 3
            out = W @ np.array([points.get(n, zero) for n in names]) * unit
            absent = np.array([n not in points for n in names])
            if absent.any():  # a point left out (confidence given): its joints are unknown
                out[(W[:, absent] != 0).any(axis=1)] = np.nan
            return out

        y_m = mapped(self.joints)
        return y_m, None if self.velocities is None else mapped(self.velocities)

    def joint_states(self) -> tuple[np.ndarray, np.ndarray]:
        """``(missing (J,), low (J,))`` per joint of ``kind`` from the points given and their
        confidences (:func:`~sara_app.human.trackers.joint_confidence`); a missing joint's
        position from :meth:`to_arrays` is NaN."""
        kind, table = SOURCES[self.source]
        return joint_confidence(self.source, table, skeleton(kind).joints, self.joints,
                                self.confidence)  # fmt: skip

    @classmethod
    def from_arrays(
        cls,
        kind: str,
        y_m: np.ndarray,
        *,
        seq: int,
        stamp_s: float,
        v_mps: np.ndarray | None = None,
        **extra: Any,
    ) -> SkeletonMsg:
        """Build from ``(J, 3)`` arrays of the project's ``kind`` (source ``sara_<kind>``)."""
        names = skeleton(kind).joints
        joints = dict(zip(names, np.asarray(y_m, dtype=float).tolist()))
        vel = None if v_mps is None else dict(zip(names, np.asarray(v_mps, float).tolist()))
        return cls(
            seq=seq, stamp_s=stamp_s, source=f"sara_{kind}", joints=joints, velocities=vel, **extra
        )


def _same_lengths(**lists: list[float] | None) -> None:
    given = {k: len(v) for k, v in lists.items() if v is not None}
    if len(set(given.values())) > 1:
        raise _fail("inconsistent_length", f"lengths differ: {given}")


class RobotStateMsg(_Msg):
    """Measured robot joint state (key ``sara/<cell>/robot/state``); lengths = n_dof."""

    q: JointVector
    q_dot: JointVector
    q_ddot: JointVector | None = None

    @model_validator(mode="after")
    def _lengths(self) -> RobotStateMsg:
        _same_lengths(q=self.q, q_dot=self.q_dot, q_ddot=self.q_ddot)
        return self


COMMAND_VALID_PERIODS = 2
COMMAND_VALID_MIN_S = 0.010
"""A command is valid for this many control periods after its stamp, and at least
``COMMAND_VALID_MIN_S`` (``valid_until_s``): a controller that takes a command that late has
left the commanded path by less than a tracking tolerance (about a_brake * 10 ms^2 / 2, 1.5 mrad
at 30 rad/s^2), while a 500 Hz loop on a busy machine misses two periods now and then."""
MAX_FAILSAFE_SAMPLES = 512


class RobotCommandMsg(_Msg):
    """The shielded set point sent to the robot (key ``sara/<cell>/robot/command``), schema
    version 2: the set point ``q``, ``q_dot``, ``q_ddot`` to reach at ``stamp_s + dt`` (the end
    of the cycle's step), ``valid_until_s`` (after it the controller must brake) and the
    verified stop that follows the set point: joint positions ``failsafe_q (F, n)`` at
    ``stamp_s + failsafe_t_s (F,)`` (strictly increasing; the first sample is the set point,
    the last one at rest). Between two samples the robot may move along the straight joint-space
    segment at constant speed (the verified occupancy contains that motion: see
    ``sara_app.robot.occupancy``). Empty when no verified stop exists (JSSA, or not yet)."""

    schema_version: Literal[2] = 2  # type: ignore[assignment]
    q: JointVector
    q_dot: JointVector
    q_ddot: JointVector
    mode: Mode
    valid_until_s: NonNeg
    failsafe_t_s: Annotated[list[Finite], Field(max_length=MAX_FAILSAFE_SAMPLES)] = []
    failsafe_q: Annotated[list[JointVector], Field(max_length=MAX_FAILSAFE_SAMPLES)] = []

    @model_validator(mode="after")
    def _lengths(self) -> RobotCommandMsg:
        _same_lengths(q=self.q, q_dot=self.q_dot, q_ddot=self.q_ddot)
        if len(self.failsafe_t_s) != len(self.failsafe_q):
            raise _fail("inconsistent_length", "failsafe_t_s and failsafe_q differ in length")
        if any(len(q) != len(self.q) for q in self.failsafe_q):
            raise _fail("inconsistent_length", "a failsafe sample has another joint count")
        t = self.failsafe_t_s
        if any(b <= a for a, b in zip(t, t[1:])):
            raise _fail("invalid", "failsafe_t_s must increase strictly")
        if self.valid_until_s < self.stamp_s:
            raise _fail("invalid", "valid_until_s is before stamp_s")
        return self

    def stop_arrays(self) -> tuple[np.ndarray, np.ndarray]:
        """The verified stop as arrays: absolute sample times ``(F,)`` and positions ``(F, n)``;
        without one, the set point at the command's stamp (the robot holds it)."""
        if not self.failsafe_t_s:
            return np.array([self.stamp_s]), np.asarray([self.q], dtype=float)
        return np.asarray(self.failsafe_t_s) + self.stamp_s, np.asarray(self.failsafe_q, float)

    def stop_position(self, t_s: float) -> tuple[np.ndarray, np.ndarray]:
        """Joint positions and velocities ``(n,)`` at time ``t_s`` along the verified stop, as
        the contract has a controller follow it (:func:`position_on_stop`)."""
        return position_on_stop(*self.stop_arrays(), t_s)


def position_on_stop(
    t_abs_s: np.ndarray, q_stop: np.ndarray, t_s: float
) -> tuple[np.ndarray, np.ndarray]:
    """Joint positions and velocities ``(n,)`` at ``t_s`` along a stop sampled at ``t_abs_s
    (F,)`` with positions ``q_stop (F, n)``: linear in joint space between the samples on
    schedule, the first sample before it and the last one (at rest) after it (for a command:
    :meth:`RobotCommandMsg.stop_arrays`; kept by who follows it many times)."""
    t, q = t_abs_s, q_stop
    if t_s <= t[0]:
        return q[0].copy(), np.zeros(q.shape[1])
    if t_s >= t[-1]:
        return q[-1].copy(), np.zeros(q.shape[1])
    k = int(np.searchsorted(t, t_s, side="right")) - 1
    slope = (q[k + 1] - q[k]) / (t[k + 1] - t[k])
    return q[k] + slope * (t_s - t[k]), slope


TrackingFlag = Literal[
    "jump", "bone", "frozen", "missing", "refused", "speed", "acceleration", "rise",
    "displacement", "stated_velocity", "repeated",
]  # fmt: skip
"""The tracking gate's flags (``jump``, ``bone``, ``frozen``; ``refused``: skeletons refused
for a joint distrusted too long) and the conformance monitor's (``speed``, ``acceleration``,
``rise``: the upward speed of a person whose legs are bounded below the pelvis,
``displacement``: a joint farther from where it was than the set's displacement bound,
``stated_velocity``: a tracker's stated velocity the positions contradict)."""


class ViolationMsg(BaseModel):
    """A person's joint beyond the active parameter set's bound (the person is a fault)."""

    model_config = ConfigDict(strict=True, extra="forbid", frozen=True)

    human_id: Name
    joint: Name
    quantity: Literal["speed", "acceleration", "rise", "displacement", "stated_velocity"]
    value: Finite
    """m/s or m/s^2: the least speed, acceleration or upward speed (``rise``) that explains the
    measured motion; m for ``displacement`` (the distance beyond the noise bound); m/s for
    ``stated_velocity`` (the stated velocity's distance from the positions' estimate, the bound
    the sum of both uncertainties)."""
    bound: Finite
    stamp_s: Finite


class JointFlagMsg(BaseModel):
    """A flag of one joint: ``flag`` (a ``TrackingFlag``) at ``stamp_s`` (for a held joint:
    since when it is held)."""

    model_config = ConfigDict(strict=True, extra="forbid", frozen=True)

    joint: Name
    flag: TrackingFlag
    stamp_s: Finite


class TrackingNowMsg(BaseModel):
    """A person's tracking as it stands: the joints the gate holds now (their last trusted
    position, grown by the reach since) and the newest flag of the gate or the monitor."""

    model_config = ConfigDict(strict=True, extra="forbid", frozen=True)

    held: list[JointFlagMsg] = Field(default=[], max_length=32)
    last_flag: JointFlagMsg | None = None


class VerdictMsg(_Msg):
    """The outcome of one control cycle (key ``sara/<cell>/verdict``), schema version 4 (2: the
    monitor's ``rise`` among the tracking flags and violations' quantities; 3: its
    ``displacement``; 4: its ``stated_velocity``).

    ``results``: model name -> True when that model's human set is free of the robot's set.
    ``skeleton_age_s``: human id -> age of the newest accepted skeleton at decision time.
    ``dropped``: reason -> count of rejected or dropped input messages since the worker started.
    """

    schema_version: Literal[4] = 4  # type: ignore[assignment]
    cell: Name
    safety_mode: Literal["ssm", "pfl", "jssa"]
    mode: Mode
    results: dict[str, bool] = {}
    skeleton_age_s: dict[str, Finite] = {}
    min_distance_m: Finite | None = None
    cycle_time_us: NonNeg
    faults: list[str] = []
    dropped: dict[str, Annotated[int, Field(ge=0)]] = {}
    intervened: bool = False
    """The safety layer changed the nominal motion (failsafe, slowed down, jerk filtered)."""
    speed_scale: NonNeg | None = None
    """PFL: the path-speed cap as a fraction of the admissible speed (1: full speed)."""
    tracking: dict[Name, dict[TrackingFlag, Annotated[int, Field(ge=0)]]] = {}
    """human id -> flag -> joint-frames flagged since the person became known (people with
    no flag are left out)."""
    tracking_now: dict[Name, TrackingNowMsg] = Field(default={}, max_length=64)
    """human id -> the person's tracking now (people never flagged are left out)."""
    violations: list[ViolationMsg] = Field(default=[], max_length=64)
    """The newest violations of every person now on the failsafe for breaking the bounds."""
    blocking: list[Annotated[str, Field(max_length=80)]] = Field(default=[], max_length=16)
    """``"<person id> <body part>"``: the body parts the check could not clear this cycle (why
    the robot brakes or slows; SSM: per body part; empty where the mode says nothing per part)."""


class CapsulesMsg(BaseModel):
    """Flat capsules: ``ends_m`` is ``(C, 2, 3)`` flattened, ``radius_m`` is ``(C,)``;
    ``below_m`` (``(C,)`` or None): the world height each capsule is cut at, the set being the
    capsule's part at or below it (None entries, or no list: the whole capsule)."""

    model_config = ConfigDict(strict=True, extra="forbid", frozen=True)

    ends_m: list[Finite]
    radius_m: list[NonNeg]
    below_m: list[Finite | None] | None = None

    @model_validator(mode="after")
    def _lengths(self) -> CapsulesMsg:
        if len(self.ends_m) != 6 * len(self.radius_m):
            raise _fail(
                "inconsistent_length",
                f"ends_m has {len(self.ends_m)} numbers; expected 6 * {len(self.radius_m)}",
            )
        if self.below_m is not None and len(self.below_m) != len(self.radius_m):
            raise _fail(
                "inconsistent_length",
                f"below_m has {len(self.below_m)} entries; expected {len(self.radius_m)} (one "
                "per capsule) or none",
            )
        return self

    @classmethod
    def from_arrays(
        cls, ends_m: np.ndarray, radius_m: np.ndarray, below_m: np.ndarray | None = None
    ) -> CapsulesMsg:
        """From ``(..., 2, 3)`` ends, ``(...)`` radii and cut heights (flattened in C order;
        ``inf``: uncut; no list when no capsule is cut)."""
        below = None
        if below_m is not None:
            z = np.asarray(below_m, float).ravel()
            if np.isfinite(z).any():
                below = [float(x) if np.isfinite(x) else None for x in z.tolist()]
        return cls(
            ends_m=np.asarray(ends_m, float).ravel().tolist(),
            radius_m=np.asarray(radius_m, float).ravel().tolist(),
            below_m=below,
        )

    def arrays(self) -> tuple[np.ndarray, np.ndarray]:
        """``(C, 2, 3)`` ends and ``(C,)`` radii."""
        return np.asarray(self.ends_m).reshape(-1, 2, 3), np.asarray(self.radius_m)

    def cuts(self) -> np.ndarray:
        """``(C,)`` the cut heights, ``inf`` where a capsule is whole."""
        if self.below_m is None:
            return np.full(len(self.radius_m), np.inf)
        return np.array([np.inf if z is None else z for z in self.below_m], dtype=float)


class HumanOccupancyMsg(BaseModel):
    """One human for display: ``joints_m`` is ``(J, 3)`` flattened in ``kind`` joint order."""

    model_config = ConfigDict(strict=True, extra="forbid", frozen=True)

    id: Name
    kind: Literal["full", "upper"]
    joints_m: list[Finite]
    models: dict[str, CapsulesMsg] = {}
    legs_below_m: Finite | None = None
    """World height (m) the legs of a person whose tracker does not measure them stay below
    over the displayed horizon, where the parameter set bounds them (the highest of their
    parts' bounds; each model's capsules carry their own cuts, ``below_m``); None: no bound."""

    @model_validator(mode="after")
    def _lengths(self) -> HumanOccupancyMsg:
        n = 3 * skeleton(self.kind).n_joints
        if len(self.joints_m) != n:
            raise _fail("inconsistent_length", f"joints_m has {len(self.joints_m)}; expected {n}")
        return self


class RobotOccupancyMsg(BaseModel):
    """Robot link capsules per interval: ``capsules`` holds ``(K, L)`` capsules, K-major."""

    model_config = ConfigDict(strict=True, extra="forbid", frozen=True)

    link_names: list[str]
    n_intervals: Annotated[int, Field(ge=0)]
    capsules: CapsulesMsg
    verified: bool

    @model_validator(mode="after")
    def _lengths(self) -> RobotOccupancyMsg:
        n = self.n_intervals * len(self.link_names)
        if len(self.capsules.radius_m) != n:
            raise _fail(
                "inconsistent_length",
                f"robot has {len(self.capsules.radius_m)} capsules; expected "
                f"{self.n_intervals} intervals * {len(self.link_names)} links",
            )
        return self


ContactClass = Literal["unconstrained", "env-constrained", "self-constrained"]
"""Thumm et al. 2024 Sec. VI contact classes (free collision; clamped against the environment;
clamped between robot links)."""

Point = Annotated[list[Finite], Field(min_length=3, max_length=3)]


class ContactMsg(BaseModel):
    """A possible contact between a robot link and a body part over the shielded trajectory
    (PFL): its class, the link's energy and the threshold that applies (for display)."""

    model_config = ConfigDict(strict=True, extra="forbid", frozen=True)

    human_id: Name
    body_part: str
    link: str
    kind: ContactClass
    interval: Annotated[int, Field(ge=0)] = 0
    """The first interval of the shielded trajectory in which the contact is possible."""
    energy_j: NonNeg | None = None
    energy_limit_j: NonNeg | None = None


class LinkEnergyMsg(BaseModel):
    """One robot link's kinetic energy (max over the shielded trajectory, Thumm et al. 2024 eq.
    46-48) and its margin to the smallest threshold of the contacts it could make."""

    model_config = ConfigDict(strict=True, extra="forbid", frozen=True)

    link: str
    energy_j: NonNeg
    limit_j: NonNeg | None = None
    """None: the link cannot touch anybody over the trajectory."""
    margin_j: Finite | None = None
    human_id: Name | None = None
    body_part: str | None = None
    contact: ContactClass | None = None
    shape: Literal["blunt", "wedge", "edge", "sheet"] = "blunt"


class JssaMsg(BaseModel):
    """The JSSA filter's state this cycle (Liu et al. 2022): safety index, critical pair,
    activity."""

    model_config = ConfigDict(strict=True, extra="forbid", frozen=True)

    phi_m2: Finite | None = None
    """None when no pair exists (nobody near) or the cycle fell back to braking."""
    active: bool
    fallback: bool = False
    reason: str = ""
    link: str | None = None
    robot_point_m: Point | None = None
    other_point_m: Point | None = None
    distance_m: Finite | None = None
    d_min_m: Pos


class OccupancyMsg(_Msg):
    """Display occupancies, about 10-20 Hz (key ``sara/<cell>/occupancy``), schema version 3
    (version 2: a human's ``legs_below_m``; 3: the capsules' cuts, ``below_m``)."""

    schema_version: Literal[3] = 3  # type: ignore[assignment]
    humans: list[HumanOccupancyMsg] = []
    robot: RobotOccupancyMsg | None = None
    contacts: list[ContactMsg] = []
    links: list[LinkEnergyMsg] = []
    jssa: JssaMsg | None = None


def _check_finite_tree(value: object, depth: int = 0) -> None:
    if isinstance(value, float) and not math.isfinite(value):
        raise _fail("finite_number", f"non-finite number {value!r}")
    if depth > 64:
        raise _fail("too_deep", "nesting deeper than 64")
    if isinstance(value, dict):
        for v in value.values():
            _check_finite_tree(v, depth + 1)
    elif isinstance(value, list):
        for v in value:
            _check_finite_tree(v, depth + 1)


FiniteTree = Annotated[dict[str, Any], AfterValidator(lambda v: (_check_finite_tree(v), v)[1])]
"""A JSON object (a scenario) whose numbers are all finite."""


class ParamsMsg(_Msg):
    """A full scenario or parameter update for the worker (key ``sara/<cell>/params``).

    ``confirm``: the sender's user confirmed that the edit loosens what the verdict assumes
    (:mod:`sara_app.ops.loosening`); without it the worker refuses such an edit, whoever sends
    it. ``user``: who sent it and confirmed it (the worker's log and its audit record name
    them). Schema version 2 (version 1 had neither; absent: not confirmed)."""

    schema_version: Literal[2] = 2  # type: ignore[assignment]
    request_id: Name
    scenario: FiniteTree
    confirm: bool = False
    user: Annotated[str, Field(max_length=64)] = ""


class ParamsAckMsg(_Msg):
    """The worker's answer to a ``ParamsMsg`` (key ``sara/<cell>/params/ack``)."""

    request_id: Name
    accepted: bool
    reason: str = ""


class StatusMsg(_Msg):
    """Worker heartbeat, about 1 Hz (key ``sara/<cell>/status``), schema version 2 (version 1
    had no ``loop_time_*``, ``overruns`` or ``robot_q_measured``)."""

    schema_version: Literal[2] = 2  # type: ignore[assignment]
    cell: Name
    state: Literal["starting", "running", "stopping", "fault"]
    scenario: str = ""
    uptime_s: NonNeg = 0.0
    humans: list[str] = []
    cycle_time_p50_us: NonNeg | None = None
    cycle_time_p99_us: NonNeg | None = None
    loop_time_p50_us: NonNeg | None = None
    loop_time_p99_us: NonNeg | None = None
    """The worker's whole step per cycle (the inputs taken, the shield's cycle, the command and
    verdict sent; ``cycle_time`` is the shield's cycle alone), over its recent cycles."""
    overruns: Annotated[int, Field(ge=0)] = 0
    """Control periods the worker's loop missed since it started (a step that ended more than
    a whole period late)."""
    robot_q_measured: Annotated[list[Finite], Field(max_length=MAX_JOINTS)] | None = None
    """The joint positions (rad) the newest robot state reports; None before a controller
    spoke. What an operator confirms in a re-plan (``robot/replan``)."""
    detail: Annotated[str, Field(max_length=300)] = ""
    """What a ``starting`` worker is doing (building the cell: loading the robot model and
    compiling the kernels, with the seconds so far)."""
    config_sha256: Annotated[str, Field(pattern="^([0-9a-f]{64})?$")] = ""
    """The running configuration's checksum (scenario, parameter and threshold sets, code; see
    ``sara_app.cell.checksum``): the one printed in the cell's evidence report. Empty while
    starting."""


class ScenarioStateMsg(_Msg):
    """The scenario the worker runs now (key ``sara/<cell>/scenario``): published at start,
    after every accepted update and with each status heartbeat, so that every editor (dashboard,
    API) builds its next edit on what the cell really runs. ``revision`` counts accepted
    updates since the worker started."""

    cell: Name
    revision: Annotated[int, Field(ge=0)]
    scenario: FiniteTree


MAX_FRAME_PEOPLE = 256
"""The most person ids one tracker frame may list (a cell tracks far fewer, see the scenario's
``inputs.max_people``; a longer list is refused as ``invalid``)."""


class TrackerFrameMsg(_Msg):
    """A tracker's heartbeat (key ``sara/<cell>/tracker/<tracker_id>/frame``): at ``stamp_s``
    the tracker saw exactly the people ``people`` (possibly none). The robot moves only while
    every tracker the scenario declares has sent a fresh frame; a person is forgotten only when
    every declared tracker has sent a frame stamped after the person's last skeleton that does
    not list them (or an operator retires them)."""

    people: Annotated[list[Name], Field(max_length=MAX_FRAME_PEOPLE)]

    @field_validator("people")
    @classmethod
    def _unique(cls, v: list[str]) -> list[str]:
        if len(set(v)) != len(v):
            raise _fail("invalid", "people lists an id twice")
        return v


class RetireMsg(_Msg):
    """An operator's decision that a person has left (key ``sara/<cell>/retire``): the worker
    forgets ``human_id`` (until a tracker lists it or a skeleton arrives again) and answers on
    ``params/ack`` with ``request_id``. ``user`` and ``reason`` go to the audit log."""

    request_id: Name
    human_id: Name
    user: Annotated[str, Field(min_length=1, max_length=64)]
    reason: Annotated[str, Field(max_length=500)] = ""


class ReplanMsg(_Msg):
    """An operator's decision that the robot stands where its controller says (key
    ``sara/<cell>/robot/replan``), after it stopped or was moved away from the worker's plan
    while the same controller ran (a protective stop, a hand guiding; the worker never moves its
    plan there on the controller's word alone, see ``sara_app.runtime.robot_link``). ``q``:
    the joint positions the operator confirms (rad, n_dof). The worker plans from the measured
    state when that state is fresh, at rest and within the tracking tolerance of ``q``, and its
    own plan is at rest; it answers on ``params/ack`` with ``request_id``. ``user`` and
    ``reason`` go to the audit log."""

    request_id: Name
    q: JointVector
    user: Annotated[str, Field(min_length=1, max_length=64)]
    reason: Annotated[str, Field(max_length=500)] = ""


BrakingCause = Literal["controller", "worker", "lost", "delivery"]
"""Why the newest command expired before a newer one came: ``controller``, the controller's own
loop was held up past the command's validity (commands waited in its queue); ``worker``, the
worker's next command was stamped too late (its cycle was held up, or it restarted); ``lost``,
the next command sent never arrived (dropped on the bus); ``delivery``, the next command was
sent in time and arrived too late (the bus or the router was held up)."""


class ControllerStatusMsg(_Msg):
    """The robot controller's heartbeat, about 1 Hz (key ``sara/<cell>/controller/status``):
    command delivery as the controller saw it since it started. ``commands_lost``: sequence
    numbers of a worker run never received; ``commands_late``: received after their set point's
    time (``stamp_s + dt``); ``commands_expired``: received after ``valid_until_s``;
    ``commands_refused``: not followed (expired and not where the robot stands);
    ``braking_events``: times the newest command expired and the robot braked on its own;
    ``worker_runs``: worker runs seen (a run's sequence numbers restart at 0); ``braking``: it
    brakes on its own now. Schema version 2 (version 1 had no ``braking_causes`` or
    ``receive_failed``)."""

    schema_version: Literal[2] = 2  # type: ignore[assignment]
    cell: Name
    commands_received: Annotated[int, Field(ge=0)]
    commands_lost: Annotated[int, Field(ge=0)]
    commands_late: Annotated[int, Field(ge=0)]
    commands_expired: Annotated[int, Field(ge=0)]
    commands_refused: Annotated[int, Field(ge=0)]
    braking_events: Annotated[int, Field(ge=0)]
    worker_runs: Annotated[int, Field(ge=0)]
    braking: bool
    braking_causes: dict[BrakingCause, Annotated[int, Field(ge=0)]] = {}
    """Why it braked on its own, per braking event (:data:`BrakingCause`)."""
    receive_failed: bool = False
    """Its wait for commands failed: it reads them at every state due instead, up to a
    control period late (the reference controller; restart it to wait again)."""


Message = (
    SkeletonMsg
    | RobotStateMsg
    | RobotCommandMsg
    | VerdictMsg
    | OccupancyMsg
    | ParamsMsg
    | ParamsAckMsg
    | StatusMsg
    | ScenarioStateMsg
    | TrackerFrameMsg
    | RetireMsg
    | ControllerStatusMsg
    | ReplanMsg
)

MODELS_BY_KIND: dict[str, type[_Msg]] = {
    "skeleton": SkeletonMsg,
    "robot_state": RobotStateMsg,
    "robot_command": RobotCommandMsg,
    "verdict": VerdictMsg,
    "occupancy": OccupancyMsg,
    "params": ParamsMsg,
    "params_ack": ParamsAckMsg,
    "status": StatusMsg,
    "scenario": ScenarioStateMsg,
    "tracker_frame": TrackerFrameMsg,
    "retire": RetireMsg,
    "controller_status": ControllerStatusMsg,
    "robot_replan": ReplanMsg,
}


SCHEMA_VERSIONS: dict[str, int] = {
    kind: int(m.model_fields["schema_version"].default) for kind, m in MODELS_BY_KIND.items()
}
"""Each message kind's schema version (the robot command is at 2: validity and failsafe)."""


def encode(msg: _Msg) -> bytes:
    """The JSON bytes of a validated message."""
    return msg.model_dump_json().encode()
