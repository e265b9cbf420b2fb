"""The tracking gate's per-frame checks in plain numpy: the oracle of
``sara_app.human.gate_kernels.gate_frame`` (the library's ``Gate.check`` before it was
compiled)."""

from __future__ import annotations

import numpy as np

from sara_app.human.anatomy import BONE_RANGE_M
from sara_app.human.gate import Gate, GateResult
from sara_app.human.gate_kernels import FROZEN_EPS_M
from sara_app.human.skeleton import FULL_JOINTS


class ReferenceGate(Gate):
    """A :class:`Gate` whose ``check`` is the numpy version."""

    def check(
        self, t_s: float, y: np.ndarray, delta_y_m: float, n_measured: int,
        missing: np.ndarray | None = None,
    ) -> GateResult:  # fmt: skip
        out = self.out
        lost = self._none if missing is None else np.asarray(missing, bool)
        if lost.any():
            y = np.where(lost[:, None], self.y_trusted, y)
        m = (np.arange(y.shape[0]) < n_measured) & ~lost
        held = np.isfinite(self.since_s)
        dist = np.linalg.norm(y - self.y_trusted, axis=1)
        reach = 2.0 * delta_y_m + self.v_max_mps * (t_s - self.t_trusted)
        jump = m & np.isfinite(self.t_trusted) & (dist > reach)
        same = m & np.all(np.abs(y - self.y_prev) <= FROZEN_EPS_M, axis=1)
        moved = m & ~same & np.isfinite(self.y_prev[:, 0])
        frozen = same & (moved.any() | held)
        bone = m & self._bone_blame(y, delta_y_m, jump | frozen | held, m)
        out.flags[:, 0], out.flags[:, 1], out.flags[:, 2], out.flags[:, 3] = (
            jump,
            bone,
            frozen,
            lost,
        )
        glitch = bone | frozen | lost
        only_jump = jump & ~glitch
        with np.errstate(divide="ignore", invalid="ignore"):
            out.jump_speed_mps[:] = np.where(
                only_jump, (dist - 2.0 * delta_y_m) / (t_s - self.t_trusted), 0.0
            )
        bad = glitch | jump
        restart = frozen & (self.t_trusted > self.first_seen_s)
        self.t_trusted[restart] = self.first_seen_s[restart]
        self.y_trusted[restart] = y[restart]
        start = np.where(frozen, np.minimum(self.first_seen_s, t_s), t_s)
        self.since_s = np.where(bad, np.where(held, self.since_s, start), np.nan)
        good = ~bad
        self.y_trusted[good] = y[good]
        self.t_trusted[good] = t_s
        self.dy_trusted[good] = delta_y_m
        out.trusted[:] = good
        self._enclose_held(t_s, y, delta_y_m, good, frozen, lost, all_good=bool(good.all()))
        held_s = np.where(bad, t_s - self.since_s, 0.0)
        out.refused = bool((held_s > self.settings.max_hold_s).any()) or bool(
            (lost & ~np.isfinite(self.t_trusted)).any()
        )
        self.first_seen_s = np.where(same, self.first_seen_s, t_s)
        self.y_prev[:] = y
        if np.isnan(self.length_m).any() and not (bad | jump)[m].any():
            self._learn_bones(y)
        self._tally(t_s, flagged=bool(out.flags.any()))
        return out

    def _bone_blame(
        self, y: np.ndarray, delta_y_m: float, suspect: np.ndarray, measured: np.ndarray
    ) -> np.ndarray:
        """``(J,)`` joints blamed for an inconsistent bone of two measured joints: its suspect
        ends, else both."""
        blame = np.zeros(y.shape[0], dtype=bool)
        if not len(self.bones):
            return blame
        a, b = self.bones[:, 0], self.bones[:, 1]
        length = np.linalg.norm(y[a] - y[b], axis=1)
        with np.errstate(invalid="ignore"):  # nan: a bone not known yet is not checked
            off = np.abs(length - self.length_m) > 2.0 * delta_y_m + self.settings.bone_tol_m
        if self.settings.anatomy:  # a person's range, from the table by the joints' names
            rng = np.array([BONE_RANGE_M[(FULL_JOINTS[i], FULL_JOINTS[k])] for i, k in self.bones])
            noise = 2.0 * delta_y_m
            with np.errstate(invalid="ignore"):  # nan: as for the own length, not checked
                off |= (length < rng[:, 0] - noise) | (length > rng[:, 1] + noise)
        off &= measured[a] & measured[b]
        sa, sb = suspect[a], suspect[b]
        either = sa | sb
        blame[a[off & (sa | ~either)]] = True
        blame[b[off & (sb | ~either)]] = True
        return blame


def reference_repeated(
    y: np.ndarray, raw: np.ndarray, n_measured: int, missing: np.ndarray
) -> bool:
    """The numpy version of ``repeated_frame`` (``Intake._repeated`` before it was compiled):
    the same answer, and ``raw`` updated the same way."""
    m = (np.arange(len(y)) < n_measured) & ~np.asarray(missing, bool)
    same = bool(m.any()) and bool(np.all(np.abs(y[m] - raw[m]) <= FROZEN_EPS_M))
    if not same:
        raw[:] = y
    return same
