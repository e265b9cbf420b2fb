"""Where simulated humans are: recorded, scripted or adversarial motion, behind one interface.

Every source answers ``pose(t, robot_ends, robot_radius) -> (15, 3)`` joint positions (full
skeleton, world frame) for increasing times ``t``; only adversaries look at the robot. Built from
a scenario's human specification by :func:`make_motion`.
"""

from __future__ import annotations

from typing import Protocol

import numpy as np

from sara_app.errors import ParameterError
from sara_app.geometry.shapes import point_segment_closest
from sara_app.human.params import ReachParams, sustained_speed_mps
from sara_app.human.recordings import Recording, load_recording
from sara_app.human.scripted import (
    STANDING_LEGS_M,
    ScriptedMotion,
    build_motion,
    joints,
    standing,
)
from sara_app.human.skeleton import FULL_JOINTS, UPPER_JOINTS


class HumanMotion(Protocol):
    def pose(self, t: float, robot_ends: np.ndarray, robot_radius: np.ndarray) -> np.ndarray: ...


def reacts_to_robot(motion: HumanMotion) -> bool:
    """Whether the motion's poses depend on where the robot is (an adversary chasing it); a
    source that does not say is taken to (its replayer then follows the robot's commands)."""
    return bool(getattr(motion, "reacts_to_robot", True))


def measures_legs(motion: HumanMotion, tracks: str = "auto") -> bool:
    """Whether a sensor that ``tracks`` (``SensorSpec.tracks``) measures this person's legs
    (``auto``: what the source has; an upper-body recording's standing legs are not)."""
    if tracks != "auto":
        return tracks == "full"
    return bool(getattr(motion, "legs_measured", True))


def standing_legs(upper: np.ndarray) -> np.ndarray:
    """``(T, 15, 3)`` from an upper-body recording's ``(T, 9, 3)``: the legs of a standing
    person (:data:`~sara_app.human.scripted.STANDING_LEGS_M`, as the scripted people stand)
    under the pelvis, turned with the shoulders. The assumption of every simulation of an
    upper-body recording: the person stands (the recording has no legs to replay)."""
    pelvis = upper[:, UPPER_JOINTS.index("pelvis")]
    left = upper[:, UPPER_JOINTS.index("l_shoulder")] - upper[:, UPPER_JOINTS.index("r_shoulder")]
    left[:, 2] = 0.0
    left /= np.maximum(np.linalg.norm(left, axis=1, keepdims=True), 1e-9)
    up = np.array([0.0, 0.0, 1.0])
    forward = np.cross(left, up)
    legs = [pelvis + x * forward + y * left + z * up for x, y, z in STANDING_LEGS_M.values()]
    order = [FULL_JOINTS.index(j) for j in STANDING_LEGS_M]  # the full skeleton's leg order
    out = np.concatenate([upper, np.zeros((len(upper), len(legs), 3))], axis=1)
    out[:, order] = np.stack(legs, axis=1)
    return out


class Scripted:
    reacts_to_robot = False

    def __init__(self, motion: ScriptedMotion) -> None:
        self.motion = motion

    def pose(self, t: float, robot_ends: np.ndarray, robot_radius: np.ndarray) -> np.ndarray:
        return self.motion.pose(t)


RAMP_S = 1.0
"""How long a replayed recording takes to come up to its own speed, and to come to rest."""


class Playback:
    """A recording replayed from ``clip_start_s`` at scenario time ``start_s``, turned by
    ``yaw_rad`` about the vertical through its first pelvis position and moved by ``offset_m``;
    linear interpolation between frames. An upper-body recording stands on
    :func:`standing_legs` (``legs_measured`` False: its sensor measures the upper body only).

    A clip starts and ends mid-motion (a walk at 1.3 m/s); held still before and after it, the
    person would change speed in no time, which no parameter set allows (the conformance monitor
    rightly reports it). So the clip's time is eased in and out: its rate rises linearly from 0
    to 1 over ``RAMP_S`` (at most half the clip) and falls back to 0 before its end, adding at
    most (clip speed) / ``RAMP_S`` to the clip's accelerations."""

    reacts_to_robot = False

    def __init__(
        self,
        rec: Recording,
        *,
        start_s: float = 0.0,
        clip_start_s: float = 0.0,
        offset_m: tuple[float, float, float] = (0.0, 0.0, 0.0),
        yaw_rad: float = 0.0,
    ) -> None:
        self.legs_measured = rec.kind == "full"
        y = rec.positions_m if self.legs_measured else standing_legs(rec.positions_m)
        self.t = rec.times_s - rec.times_s[0]
        self.start_s, self.clip_start_s = start_s, min(clip_start_s, float(self.t[-1]))
        self.clip_s = float(self.t[-1]) - self.clip_start_s
        self.ramp_s = min(RAMP_S, self.clip_s / 2.0)
        pelvis = rec.positions_m[0, rec.joints.index("pelvis")]
        pivot = np.array([pelvis[0], pelvis[1], 0.0])
        c, s = np.cos(yaw_rad), np.sin(yaw_rad)
        R = np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])
        self.y = (y - pivot) @ R.T + pivot + np.asarray(offset_m)

    @property
    def duration_s(self) -> float:
        """Scenario time from ``start_s`` until the person rests at the clip's last pose."""
        return self.clip_s + self.ramp_s

    def clip_time(self, t: float) -> float:
        """The clip's time (s from its first frame) shown at scenario time ``t``."""
        tau, R, D = t - self.start_s, self.ramp_s, self.clip_s
        if R <= 0.0:
            warped = min(max(tau, 0.0), D)
        elif tau <= 0.0:
            warped = 0.0
        elif tau < R:
            warped = tau * tau / (2.0 * R)
        elif tau < self.duration_s - R:
            warped = R / 2.0 + (tau - R)
        elif tau < self.duration_s:
            warped = D - (self.duration_s - tau) ** 2 / (2.0 * R)
        else:
            warped = D
        return self.clip_start_s + warped

    def pose(self, t: float, robot_ends: np.ndarray, robot_radius: np.ndarray) -> np.ndarray:
        c = self.clip_time(t)
        i = int(np.searchsorted(self.t, c, side="right"))
        if i <= 0:
            return self.y[0].copy()
        if i >= len(self.t):
            return self.y[-1].copy()
        w = (c - self.t[i - 1]) / (self.t[i] - self.t[i - 1])
        return (1.0 - w) * self.y[i - 1] + w * self.y[i]


class Adversary:
    """Body parts that chase the robot at the model bounds (bang-bang acceleration).

    ``'rigid'``: the whole body translates with one velocity, bounded by the smallest joint
    ``v_max`` and ``a_max`` (respects every model, R_POS included). ``'limbs'``: every joint
    chases its nearest robot point with its own bounds (respects R_VEL, R_ACC and ISO 13855 where
    ``v_max`` is below its speed; limbs stretch, so R_POS and the arm model do not apply). Where
    the set bounds displacements (R_VEL's table), ``v_max`` is the speed a joint may keep up
    within it (:func:`~sara_app.human.params.sustained_speed_mps`): a person within every bound
    of the set. A person who bursts to ``v_max`` and stops in time could press harder; not
    modelled.
    Integration: the velocity changes by at most ``a_max dt`` per step and is projected onto the
    ``v_max`` ball (a projection onto a convex set containing the old velocity never lengthens
    the change), positions use the mean velocity of the step.
    """

    def __init__(
        self,
        strategy: str,
        position_xy: tuple[float, float],
        params: ReachParams,
        *,
        start_s: float = 0.0,
        seed: int = 0,
    ) -> None:
        if strategy not in ("rigid", "limbs"):
            raise ParameterError(f"strategy = {strategy!r}; valid: rigid, limbs")
        self.strategy = strategy
        rng = np.random.default_rng(seed)
        self.y = joints(standing(position_xy, float(rng.uniform(-np.pi, np.pi))))
        self.v = np.zeros_like(self.y)
        self.start_s = start_s
        self.t_last: float | None = None
        # the speed it keeps up stays within the set's displacement bound too, where it has one
        v_max = sustained_speed_mps(params)
        if strategy == "rigid":
            self.v_max = np.full(len(self.y), float(v_max.min()))
            self.a_max = np.full(len(self.y), float(params.a_max_mps2.min()))
        else:
            self.v_max = v_max
            self.a_max = params.a_max_mps2.copy()
        # a little randomness in how hard it pushes (still within the bounds)
        self.push = float(rng.uniform(0.85, 1.0))

    def _targets(self, robot_ends: np.ndarray) -> np.ndarray:
        """Nearest point on any link axis for every joint ``(15, 3)``."""
        seg = robot_ends.reshape(-1, 2, 3)
        d, t = point_segment_closest(self.y[:, None, :], seg[None])  # (15, L)
        k = np.argmin(d, axis=1)
        a, b = seg[k, 0], seg[k, 1]
        tt = t[np.arange(len(k)), k][:, None]
        return a + tt * (b - a)

    def pose(self, t: float, robot_ends: np.ndarray, robot_radius: np.ndarray) -> np.ndarray:
        if self.t_last is None or t <= self.start_s:
            self.t_last = t
            return self.y.copy()
        dt = t - self.t_last
        self.t_last = t
        if dt <= 0:
            return self.y.copy()
        tgt = self._targets(robot_ends)
        if self.strategy == "rigid":
            d = tgt - self.y
            i = int(np.argmin(np.linalg.norm(d, axis=1)))
            d = np.broadcast_to(d[i], self.y.shape)
        else:
            d = tgt - self.y
        n = np.linalg.norm(d, axis=1, keepdims=True)
        want = self.v_max[:, None] * d / np.maximum(n, 1e-9)
        dvel = want - self.v
        dn = np.linalg.norm(dvel, axis=1, keepdims=True)
        step = np.minimum(dn, (self.push * self.a_max * dt)[:, None])
        v_new = self.v + dvel / np.maximum(dn, 1e-12) * step
        sp = np.linalg.norm(v_new, axis=1, keepdims=True)
        v_new *= np.minimum(1.0, self.v_max[:, None] / np.maximum(sp, 1e-12))
        self.y = self.y + 0.5 * (self.v + v_new) * dt
        self.v = v_new
        return self.y.copy()


def measured(y: np.ndarray, noise_m: float, rng: np.random.Generator) -> np.ndarray:
    """``y (J, 3)`` with sensor noise uniform in a cube whose corners lie ``noise_m`` away (so
    every joint's error is at most ``noise_m``, the parameter set's delta_y when sound)."""
    if noise_m <= 0:
        return y
    return y + rng.uniform(-1, 1, y.shape) * (noise_m / np.sqrt(3.0))


def make_motion(spec: object, params: ReachParams) -> HumanMotion:
    """A motion source for one scenario human (``sara_app.scenario`` human models)."""
    from sara_app.scenario import AdversarialHuman, RecordingHuman, ScriptedHuman

    if isinstance(spec, RecordingHuman):
        rec = load_recording(spec.recording)
        return Playback(
            rec,
            start_s=spec.start_s,
            clip_start_s=spec.clip_start_s,
            offset_m=spec.offset_m,
            yaw_rad=spec.yaw_rad,
        )
    if isinstance(spec, ScriptedHuman):
        return Scripted(
            build_motion(
                spec.motion,
                spec.position_m,
                spec.target_m,
                params.v_max_mps,
                params.a_max_mps2,
                speed_scale=spec.speed_scale,
                start_s=spec.start_s,
            )
        )
    if isinstance(spec, AdversarialHuman):
        return Adversary(
            spec.strategy, spec.position_m, params, start_s=spec.start_s, seed=spec.seed
        )
    raise ParameterError(f"unknown human specification {type(spec).__name__}")
