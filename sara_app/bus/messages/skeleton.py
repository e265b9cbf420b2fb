"""The skeleton message: one tracked person's joints, in a source's point names."""

from __future__ import annotations

from typing import Any

import numpy as np
from pydantic import field_validator, model_validator

from sara_app.bus.messages.base import (
    Finite,
    MsgBase,
    NonNeg,
    Vec3,
    contract_error,
)
from sara_app.human.skeleton import COCO17_NAMES, SOURCES, skeleton
from sara_app.human.trackers import TRACKER_POINTS, UNIT_M, joint_confidence

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


class SkeletonMsg(MsgBase):
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
            raise contract_error("unknown_frame", f"frame {v!r} is not supported; valid: world")
        return v

    @field_validator("source")
    @classmethod
    def _source(cls, v: str) -> str:
        if v not in SOURCES:
            raise contract_error(
                "unknown_source", f"source {v!r} unknown; valid: {', '.join(SOURCES)}"
            )
        return v

    @model_validator(mode="after")
    def _names(self) -> SkeletonMsg:
        required, allowed = source_points(self.source)
        for field, points in (("joints", self.joints), ("velocities", self.velocities)):
            if points is None:
                continue
            unknown = sorted(set(points) - allowed)
            if unknown:
                raise contract_error(
                    "unknown_joint",
                    f"{field}: {unknown} are not points of source {self.source!r}; "
                    f"valid: {sorted(allowed)}",
                )
            missing = sorted(required - set(points))
            if missing and self.confidence is None:
                raise contract_error(
                    "missing_joint", f"{field}: source {self.source!r} needs {missing}"
                )
        if self.confidence is not None:
            unknown = sorted(set(self.confidence) - allowed)
            if unknown:
                raise contract_error(
                    "unknown_joint",
                    f"confidence: {unknown} are not points of source {self.source!r}; "
                    f"valid: {sorted(allowed)}",
                )
            if not set(self.joints) & required:
                raise contract_error(
                    "missing_joint", f"joints: source {self.source!r}: none is given"
                )
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
