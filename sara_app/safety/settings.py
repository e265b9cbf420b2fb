"""The safety modes' settings (the ``shield`` section of a scenario file): one type per mode,
owned by the verification core and validated once, here. The scenario file composes them;
nothing converts or mirrors them.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from typing import Annotated, Literal

from pydantic import Field, field_validator, model_validator

from sara_app.errors import UnknownNameError
from sara_app.human.model_names import MODELS
from sara_app.safety.thresholds import RENAMED as THRESHOLDS_RENAMED
from sara_app.safety.thresholds import ThresholdSet, load_thresholds
from sara_app.settings import Name, NonNeg, StrictFinite

MAX_DT_S = 0.05
"""The longest control period a scenario may set (s); a cycle's verdict and command may be
stamped up to a period ahead of the clock (``CellWorker.step``)."""
FUTURE_TOLERANCE_S = 0.002
"""How far a message's stamp may lie ahead of the receiver's clock (clocks of one cell are
synchronised); a skeleton stamped further ahead is a fault, a bus message is refused as
``out_of_range``."""

SAFETY_MODES = ("ssm", "pfl", "jssa")
SHAPES = ("blunt", "wedge", "edge", "sheet")
Shape = Literal["blunt", "wedge", "edge", "sheet"]


MAX_THRESHOLD_J = 10.0
"""The physical ceiling of an admissible contact energy: five times the largest value of seed
003 Table I (2 J). No body part's threshold can be set above it, confirmed or not."""


@dataclass(frozen=True)
class ModeFacts:
    """What a safety mode promises and what it produces, for whoever reports or shows it: the
    one place outside the shields that knows the modes apart (metrics, tables, plots ask here).
    """

    scales_speed: bool
    """The verdict carries a speed scale (SSM's and PFL's scaled intended step)."""
    contact_allowed: bool
    """A contact below its body part's energy threshold is allowed; the failure is a harmful
    contact (PFL, Kirschner's SaRA-shield). Otherwise any contact while moving is one."""
    guarantees_separation: bool
    """Formally verified never to touch a person while moving (SSM); JSSA's safe set carries no
    such guarantee (its collisions are reported all the same)."""
    safety_index: bool
    """The verdict carries a safety index phi (JSSA, Zhao et al.)."""
    arm_model: bool
    """Can verify with Pereira's arm model (PFL's compiled check has no per-body-part arm
    capsules)."""


MODE_FACTS = {
    "ssm": ModeFacts(True, False, True, False, True),
    "pfl": ModeFacts(True, True, False, False, False),
    "jssa": ModeFacts(False, False, False, True, True),
}


def mode_facts(mode: str) -> ModeFacts:
    """The facts of safety ``mode`` (one of :data:`SAFETY_MODES`)."""
    if mode not in MODE_FACTS:
        raise UnknownNameError("safety mode", mode, SAFETY_MODES)
    return MODE_FACTS[mode]


def models_of_mode(mode: str, models: Sequence[str]) -> list[str]:
    """Those of ``models`` that safety ``mode`` can verify with (:attr:`ModeFacts.arm_model`)."""
    return [m for m in models if m != "arm" or mode_facts(mode).arm_model]


def check_index_roots(lambda_1: float, lambda_2: float) -> None:
    """Raise ValueError unless ``1 + lambda_1 s + lambda_2 s^2 = 0`` has negative real roots
    (Liu et al. 2022 Sec. 3.1: the safety index's gains)."""
    if lambda_1**2 < 4.0 * lambda_2:
        raise ValueError(
            f"lambda_1 = {lambda_1}, lambda_2 = {lambda_2}: 1 + l1 s + l2 s^2 has complex roots; "
            "expected lambda_1^2 >= 4 lambda_2 (Liu et al. 2022 Sec. 3.1: negative real roots)"
        )


class ThresholdOverride(StrictFinite):
    """One edited entry of the threshold table (Thumm et al. 2024 Table I cell), in J."""

    region: Literal["hand", "lower_arm", "upper_arm", "torso_legs", "head"]
    contact: Literal["constrained", "unconstrained"]
    shape: Shape
    energy_J: Annotated[float, Field(gt=0, le=MAX_THRESHOLD_J, allow_inf_nan=False)]


class PflSettings(StrictFinite):
    """Power and force limiting (Thumm et al. 2024): threshold set, edits, contact shapes, speed
    scaling."""

    thresholds: str = "thresholds_thumm2024"
    overrides: list[ThresholdOverride] = []
    link_shapes: dict[str, Shape] = {}
    """Worst-case contact shape per robot link name (default blunt): the tool's shape."""
    min_speed_scale: Annotated[float, Field(gt=0, le=1)] = 0.02
    """Below this fraction of the path's admissible speed the shield brakes instead."""
    unclampable_pairs: list[tuple[Name, Name]] | None = None
    """Robot link pairs that cannot clamp a body part between them (Thumm et al. 2024 eq. 36),
    a design declaration for the safety engineer to confirm; None: the shipped robot's
    declaration (``sara_app.safety.topology``), none for any other robot (every pair may
    clamp: conservative)."""

    def source_set(self) -> ThresholdSet:
        """The named threshold set as shipped: the source of every entry."""
        return load_thresholds(self.thresholds)

    def edited_set(self) -> tuple[ThresholdSet, list[str]]:
        """The set in force (the named set with ``overrides`` applied) and the edits above the
        shipped value (confirmed by the safety engineer)."""
        ts, above = self.source_set(), []
        for o in self.overrides:
            ts, up = ts.with_energy(o.region, o.contact, o.shape, o.energy_J)
            if up:
                above.append(f"{o.region}/{o.contact}/{o.shape} = {o.energy_J} J")
        return ts, above

    @field_validator("thresholds")
    @classmethod
    def _current_name(cls, v: str) -> str:
        return THRESHOLDS_RENAMED.get(v, v)

    @field_validator("overrides")
    @classmethod
    def _unique_entries(cls, v: list[ThresholdOverride]) -> list[ThresholdOverride]:
        keys = [(o.region, o.contact, o.shape) for o in v]
        dup = sorted({k for k in keys if keys.count(k) > 1})
        if dup:
            raise ValueError(f"threshold entry {'/'.join(dup[0])} overridden twice")
        return v


class JssaSettings(StrictFinite):
    """JSSA in a cell (Liu et al. 2022): the controller's parameters
    (:class:`sara_app.safety.jssa.JssaParams`) are derived from these by
    :func:`sara_app.safety.jssa_mode.jssa_params`."""

    d_min_m: Annotated[float, Field(gt=0, le=2)] = 0.05
    lambda_1: Annotated[float, Field(gt=0, le=1e3)] = 3.0
    lambda_2: Annotated[float, Field(ge=0, le=1e3)] = 1.0
    constraints: Literal["single", "multi"] = "multi"
    """One constraint per close capsule pair (default: the paper's single critical pair let the
    distance fall below d_min in 2 of 30 constant-velocity crossings, multi in none of 60)."""
    eta_per_s: NonNeg | None = None

    @model_validator(mode="after")
    def _real_negative_roots(self) -> JssaSettings:
        check_index_roots(self.lambda_1, self.lambda_2)
        return self


class SsmSettings(StrictFinite):
    """SSM's speed scaling. Each cycle first checks the trajectory at full path speed; when that
    check fails it plans again at ``cut * min(cap, the failed plan's largest path speed)`` (a
    shorter stop, smaller sets), at most ``max_replans`` times (0: brake at once, Schepp et al.
    2022's shield), never below ``min_speed_scale`` times the admissible speed at the robot
    (there it brakes on the held failsafe, as without scaling). Measured in closed loop
    (``docs/measurements/2026-11-25-combined-model.md``): close_worker 5.67 -> 4.64 s with these
    values, the other scenarios unchanged; a slower return to full speed (x1.5 per verified
    cycle) or a deeper cut (0.5) made them slower than braking."""

    max_replans: Annotated[int, Field(ge=0, le=5)] = 2
    cut: Annotated[float, Field(gt=0, lt=1)] = 0.9
    """Each replan's path-speed cap as a fraction of the previous plan's top speed."""
    min_speed_scale: Annotated[float, Field(ge=0, le=1)] = 0.05
    """Below this fraction of the path's admissible speed the shield brakes instead."""


class ShieldSettings(StrictFinite):
    """The verification core's settings: the safety mode and its own section, the control
    period, the interval length, the human models and the input bounds; validated once, here
    (a scenario file's ``shield`` section)."""

    mode: Literal["ssm", "pfl", "jssa"] = "ssm"
    """Safety mode: speed and separation monitoring, power and force limiting, or JSSA."""
    dt_s: Annotated[float, Field(ge=1e-4, le=MAX_DT_S)] = 0.004
    max_interval_s: Annotated[float, Field(gt=0, le=0.1)] = 0.02
    models: list[str] = ["pos", "vel", "acc", "combined"]
    tracking_tol_rad: Annotated[float, Field(gt=0, le=0.1)] = 0.005
    skeleton_timeout_s: Annotated[float, Field(gt=0, le=5)] = 0.2
    ssm: SsmSettings = SsmSettings()
    pfl: PflSettings = PflSettings()
    jssa: JssaSettings = JssaSettings()

    @field_validator("models")
    @classmethod
    def _known_models(cls, v: list[str]) -> list[str]:
        if not v:
            raise ValueError(f"at least one model is needed; valid: {', '.join(MODELS)}")
        bad = [m for m in v if m not in MODELS]
        if bad:
            raise ValueError(f"unknown model {bad[0]!r}; valid: {', '.join(MODELS)}")
        if len(set(v)) != len(v):
            raise ValueError(f"models listed twice in {v}")
        return v

    @model_validator(mode="after")
    def _models_of_the_mode(self) -> ShieldSettings:
        if models_of_mode(self.mode, self.models) != list(self.models):
            valid = ", ".join(models_of_mode(self.mode, MODELS))
            raise ValueError(
                f"model 'arm' (Pereira's arm model) is not available in PFL mode; valid: {valid}"
            )
        return self
