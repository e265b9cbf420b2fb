"""Scripted human motions with rigid limbs, for demo scenarios (Schepp et al. 2022 Sec. IV
experiments).

A pose is a small parameter vector (pelvis position, yaw, forward lean of the upper body, and the
unit directions of the four arm segments in the leaned body frame); joint positions follow by
forward kinematics with fixed segment lengths, so every interpolated pose has the same limb
lengths (the R_POS model's assumption). Key poses are joined by minimum-jerk (quintic) blends;
each blend's duration is the shortest that keeps every joint below ``frac`` of its speed and
acceleration bound, measured on a dense sampling of the blend (``frac`` leaves room for the
sampling error; :func:`motion_bounds` re-measures a finished motion).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from sara_app.errors import ParameterError
from sara_app.human.skeleton import FULL_JOINTS

_J = {n: i for i, n in enumerate(FULL_JOINTS)}
UPPER_ARM_M = 0.28
FOREARM_M = 0.26
SHOULDER_Y_M = 0.19
SHOULDER_Z_M = 0.50  # above the pelvis
NECK_Z_M = 0.55
HEAD_Z_M = 0.72
# lower body in the body frame relative to the pelvis (standing, legs straight)
STANDING_LEGS_M = {
    "l_hip": (0.0, 0.10, -0.03),
    "r_hip": (0.0, -0.10, -0.03),
    "l_knee": (0.0, 0.11, -0.45),
    "r_knee": (0.0, -0.11, -0.45),
    "l_ankle": (0.0, 0.11, -0.87),
    "r_ankle": (0.0, -0.11, -0.87),
}
"""A standing person's leg joints from the pelvis in the body frame (x forward, y left, z up)."""
PELVIS_Z_M = 0.95
_DOWN = np.array([0.0, 0.0, -1.0])


@dataclass
class Pose:
    """Pelvis ``(3,)`` m (world), yaw rad, lean rad (forward tilt of the upper body about the
    hip line), arm segment directions ``(4, 3)`` unit vectors in the leaned body frame
    (l_upper, l_fore, r_upper, r_fore)."""

    pelvis: np.ndarray
    yaw: float
    lean: float
    arms: np.ndarray

    def vector(self) -> np.ndarray:
        return np.concatenate([self.pelvis, [self.yaw, self.lean], self.arms.ravel()])

    @staticmethod
    def from_vector(x: np.ndarray) -> Pose:
        arms = x[5:17].reshape(4, 3)
        arms = arms / np.linalg.norm(arms, axis=1, keepdims=True)
        return Pose(x[:3].copy(), float(x[3]), float(x[4]), arms)


def standing(xy: tuple[float, float], yaw: float) -> Pose:
    return Pose(np.array([xy[0], xy[1], PELVIS_Z_M]), yaw, 0.0, np.tile(_DOWN, (4, 1)))


def _rz(a: float) -> np.ndarray:
    c, s = np.cos(a), np.sin(a)
    return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])


def _ry(a: float) -> np.ndarray:
    c, s = np.cos(a), np.sin(a)
    return np.array([[c, 0.0, s], [0.0, 1.0, 0.0], [-s, 0.0, c]])


def joints(pose: Pose) -> np.ndarray:
    """Joint positions ``(15, 3)`` in FULL_JOINTS order."""
    R_body = _rz(pose.yaw)
    R_up = R_body @ _ry(pose.lean)  # positive lean tips the upper body forward (+x)
    p = pose.pelvis
    out = np.empty((len(FULL_JOINTS), 3))
    out[_J["pelvis"]] = p
    for name, off in STANDING_LEGS_M.items():
        out[_J[name]] = p + R_body @ np.array(off)
    out[_J["neck"]] = p + R_up @ np.array([0.0, 0.0, NECK_Z_M])
    out[_J["head"]] = p + R_up @ np.array([0.0, 0.0, HEAD_Z_M])
    for k, side in enumerate(("l", "r")):
        sy = SHOULDER_Y_M if side == "l" else -SHOULDER_Y_M
        sh = p + R_up @ np.array([0.0, sy, SHOULDER_Z_M])
        el = sh + UPPER_ARM_M * (R_up @ pose.arms[2 * k])
        out[_J[f"{side}_shoulder"]] = sh
        out[_J[f"{side}_elbow"]] = el
        out[_J[f"{side}_wrist"]] = el + FOREARM_M * (R_up @ pose.arms[2 * k + 1])
    return out


def aim_arm(pose: Pose, side: str, target_world: np.ndarray) -> Pose:
    """The pose with one wrist moved toward ``target_world`` (straight arm if out of reach,
    elbow bent downward otherwise)."""
    R_up = _rz(pose.yaw) @ _ry(pose.lean)
    sy = SHOULDER_Y_M if side == "l" else -SHOULDER_Y_M
    sh = pose.pelvis + R_up @ np.array([0.0, sy, SHOULDER_Z_M])
    d = R_up.T @ (np.asarray(target_world, dtype=float) - sh)  # leaned body frame
    dist = float(np.linalg.norm(d))
    u = d / max(dist, 1e-9)
    reach = UPPER_ARM_M + FOREARM_M
    arms = pose.arms.copy()
    k = 0 if side == "l" else 2
    if dist >= reach - 1e-6:
        arms[k] = arms[k + 1] = u
    else:
        # two-link IK: elbow on the circle around d, on its lowest side
        a = (UPPER_ARM_M**2 - FOREARM_M**2 + dist**2) / (2 * dist)
        h = np.sqrt(max(UPPER_ARM_M**2 - a * a, 0.0))
        down = _DOWN - np.dot(_DOWN, u) * u
        nd = np.linalg.norm(down)
        down = down / nd if nd > 1e-9 else np.array([1.0, 0.0, 0.0])
        elbow = a * u + h * down
        arms[k] = elbow / np.linalg.norm(elbow)
        fore = d - elbow
        arms[k + 1] = fore / np.linalg.norm(fore)
    return Pose(pose.pelvis.copy(), pose.yaw, pose.lean, arms)


def _quintic(s: np.ndarray) -> np.ndarray:
    return s * s * s * (10.0 - 15.0 * s + 6.0 * s * s)


class ScriptedMotion:
    """Key poses joined by quintic blends timed to the joint bounds; ``pose(t)`` -> ``(15, 3)``.

    ``keys``: list of ``(Pose, hold_s)``: move to the pose, then hold it for ``hold_s``.
    ``v_max (15,)`` m/s, ``a_max (15,)`` m/s^2: the joint bounds to respect (times ``frac``).
    """

    def __init__(
        self,
        keys: list[tuple[Pose, float]],
        v_max: np.ndarray,
        a_max: np.ndarray,
        *,
        frac: float = 0.8,
        start_s: float = 0.0,
    ) -> None:
        if not keys:
            raise ParameterError("a scripted motion needs at least one key pose")
        if not 0 < frac <= 1:
            raise ParameterError(f"frac = {frac!r}; expected a fraction in (0, 1]")
        self.start_s = float(start_s)
        self._vecs = [k.vector() for k, _ in keys]
        # segment list: (t0, duration, x0, x1) with holds as zero-motion segments
        self._t0: list[float] = []
        self._dur: list[float] = []
        self._x0: list[np.ndarray] = []
        self._x1: list[np.ndarray] = []
        t = 0.0
        prev = self._vecs[0]
        for (_, hold), x in zip(keys, self._vecs):
            if not np.array_equal(prev, x):
                T = self._blend_time(prev, x, v_max * frac, a_max * frac)
                self._add(t, T, prev, x)
                t += T
            if hold > 0:
                self._add(t, hold, x, x)
                t += hold
            prev = x
        self.duration_s = t
        self._t0a = np.array(self._t0)

    def _add(self, t0: float, T: float, x0: np.ndarray, x1: np.ndarray) -> None:
        self._t0.append(t0)
        self._dur.append(T)
        self._x0.append(x0)
        self._x1.append(x1)

    @staticmethod
    def _blend_time(x0: np.ndarray, x1: np.ndarray, v: np.ndarray, a: np.ndarray) -> float:
        s = np.linspace(0.0, 1.0, 201)
        ys = np.stack([joints(Pose.from_vector(x0 + (x1 - x0) * si)) for si in _quintic(s)])
        h = s[1] - s[0]
        dv = np.linalg.norm(np.diff(ys, axis=0), axis=2) / h  # (200, 15) per unit time
        da = np.linalg.norm(np.diff(ys, 2, axis=0), axis=2) / (h * h)
        T_v = float((dv.max(axis=0) / v).max())
        T_a = float(np.sqrt((da.max(axis=0) / a).max()))
        return max(T_v, T_a, 0.05)

    def pose(self, t: float) -> np.ndarray:
        """Joint positions ``(15, 3)`` at absolute time ``t`` (s); held before and after."""
        tl = t - self.start_s
        if tl <= 0.0 or not self._t0:
            return joints(Pose.from_vector(self._vecs[0]))
        i = int(np.searchsorted(self._t0a, tl, side="right")) - 1
        s = min(max((tl - self._t0[i]) / self._dur[i], 0.0), 1.0)
        x0, x1 = self._x0[i], self._x1[i]
        return joints(Pose.from_vector(x0 + (x1 - x0) * float(_quintic(np.array(s)))))


def motion_bounds(motion: ScriptedMotion, dt: float = 1e-3) -> tuple[np.ndarray, np.ndarray]:
    """Largest finite-difference speed and acceleration of every joint ``(15,)``, ``(15,)``."""
    t = np.arange(motion.start_s, motion.start_s + motion.duration_s + dt, dt)
    ys = np.stack([motion.pose(ti) for ti in t])
    v = np.linalg.norm(np.diff(ys, axis=0), axis=2) / dt
    a = np.linalg.norm(np.diff(ys, 2, axis=0), axis=2) / (dt * dt)
    return v.max(axis=0), a.max(axis=0)


def _facing(xy: tuple[float, float], target: np.ndarray) -> float:
    return float(np.arctan2(target[1] - xy[1], target[0] - xy[0]))


def build_motion(
    motion: str,
    position_xy: tuple[float, float],
    target: tuple[float, float, float],
    v_max: np.ndarray,
    a_max: np.ndarray,
    *,
    speed_scale: float = 1.0,
    start_s: float = 0.0,
) -> ScriptedMotion:
    """The scripted experiments: 'stand', 'approach' (slow walk up to the target and back),
    'punch' (right punches at the target, then a left), 'headbutt' (lean the head at the target)
    and 'box_pick' (pick a box up beside the body and put it down at the target)."""
    tgt = np.asarray(target, dtype=float)
    yaw = _facing(position_xy, tgt)
    base = standing(position_xy, yaw)
    keys: list[tuple[Pose, float]] = [(base, 0.5)]
    vm, am = v_max * speed_scale, a_max * speed_scale
    fwd = np.array([np.cos(yaw), np.sin(yaw), 0.0])
    left = np.array([-np.sin(yaw), np.cos(yaw), 0.0])
    if motion == "stand":
        keys = [(base, 1.0)]
    elif motion == "approach":
        dist = float(np.hypot(*(tgt[:2] - base.pelvis[:2])))
        stop = base.pelvis + fwd * max(dist - 0.55, 0.0)
        near = Pose(stop, yaw, 0.0, base.arms.copy())
        # the paper's "slow approach": walking speed capped at 0.5 m/s
        vm = np.minimum(vm, 0.5 * speed_scale)
        keys += [(near, 2.0), (base, 0.5)]
    elif motion == "punch":
        guard = aim_arm(
            aim_arm(base, "r", base.pelvis + [0, 0, 0.45] + 0.25 * fwd),
            "l",
            base.pelvis + [0, 0, 0.45] + 0.25 * fwd + 0.1 * left,
        )
        keys.append((guard, 0.3))
        for arm in ("r", "r", "l"):
            keys += [(aim_arm(guard, arm, tgt), 0.1), (guard, 0.3)]
        keys.append((base, 0.5))
    elif motion == "headbutt":
        d_h = float(np.hypot(*(tgt[:2] - base.pelvis[:2])))
        lean = float(np.clip(np.arctan2(d_h, max(tgt[2] - PELVIS_Z_M, 0.05)), 0.0, 1.0))
        bent = Pose(base.pelvis.copy(), yaw, lean, base.arms.copy())
        keys += [(bent, 0.2), (base, 0.4), (bent, 0.2), (base, 0.5)]
    elif motion == "box_pick":
        side = Pose(base.pelvis.copy(), yaw + 1.2, 0.0, base.arms.copy())
        box_at = side.pelvis + _rz(side.yaw) @ np.array([0.45, 0.0, -0.35])
        bend = Pose(side.pelvis.copy(), side.yaw, 0.7, side.arms.copy())
        grab = aim_arm(aim_arm(bend, "l", box_at + 0.15 * left), "r", box_at - 0.15 * left)
        up = aim_arm(
            aim_arm(side, "l", side.pelvis + [0, 0, 0.25] + 0.3 * left),
            "r",
            side.pelvis + [0, 0, 0.25] + 0.3 * left,
        )
        turn = Pose(base.pelvis.copy(), yaw, 0.3, up.arms.copy())
        place = aim_arm(aim_arm(turn, "l", tgt + 0.15 * left), "r", tgt - 0.15 * left)
        keys += [
            (side, 0.2),
            (bend, 0.0),
            (grab, 0.5),
            (up, 0.2),
            (turn, 0.2),
            (place, 0.5),
            (turn, 0.2),
            (base, 0.5),
        ]
    else:
        from sara_app.errors import UnknownNameError

        raise UnknownNameError(
            "scripted motion", motion, ("stand", "approach", "punch", "headbutt", "box_pick")
        )
    return ScriptedMotion(keys, vm, am, start_s=start_s)
