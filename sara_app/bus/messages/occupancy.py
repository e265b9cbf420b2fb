"""The display's occupancy message: human and robot capsules, contacts, link energies, JSSA."""

from __future__ import annotations

from typing import Annotated, Literal

import numpy as np
from pydantic import BaseModel, ConfigDict, Field, model_validator

from sara_app.bus.messages.base import (
    Finite,
    MsgBase,
    Name,
    NonNeg,
    Pos,
    contract_error,
)
from sara_app.human.skeleton import skeleton


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
            raise contract_error(
                "inconsistent_length",
                f"ends_m has {len(self.ends_m)} numbers; expected 6 * {len(self.radius_m)}",
            )
        if self.below_m is not None and len(self.below_m) != len(self.radius_m):
            raise contract_error(
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
            raise contract_error(
                "inconsistent_length", f"joints_m has {len(self.joints_m)}; expected {n}"
            )
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
            raise contract_error(
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


class OccupancyMsg(MsgBase):
    """Display occupancies, about 10-20 Hz (key ``sara/<cell>/occupancy``), schema version 3
    (version 2: a human's ``legs_below_m``; 3: the capsules' cuts, ``below_m``)."""

    schema_version: Literal[3] = 3  # type: ignore[assignment]
    humans: list[HumanOccupancyMsg] = []
    robot: RobotOccupancyMsg | None = None
    contacts: list[ContactMsg] = []
    links: list[LinkEnergyMsg] = []
    jssa: JssaMsg | None = None
