"""Compiled Composite Rigid Body Algorithm: joint-space inertia matrices ``M (S, n, n)`` at ``S``
configurations in one call (the numbers of ``pin.crba``, without a Python loop over samples).

Formulation (Featherstone's CRBA written in pinocchio's universe frame ``0``; no base transform,
so moments stay about the robot's own origin). Per sample, forward along the chain, the pose
``(R_j, p_j)`` of joint ``j``'s frame is ``pose(parent) @ placement_j @ X_J(q_j)`` with ``X_J``
a rotation about the unit axis ``a_j`` (revolute, Rodrigues: ``Rp + sin q Rp K + (1 - cos q) Rp
K^2``) or a translation along it (prismatic). The motion subspace at the origin of frame 0 is
``S_j = (v, w) = (p_j x a_w, a_w)`` (revolute) or ``(a_w, 0)`` (prismatic), ``a_w = R_j a_j``.
Body ``j``'s spatial inertia about the origin: mass ``m``, first moment ``h = m c_w`` (``c_w``
the world centre of mass) and ``I_O = R I_c R^T + m (|c_w|^2 1 - c_w c_w^T)``. Composite
inertias are plain sums over the subtree (same frame). With ``F_j = I^C_j S_j`` (linear
momentum ``m v + w x h``, angular momentum ``I_O w + h x v``), ``M[i, j] = S_i . F_j`` for every
joint ``i`` supporting ``j``, 0 for the other pairs; the armature is added to the diagonal (as
``pin.crba`` does). Both triangles are written.

Supported joints: one-dof revolute joints about an axis through the joint frame's origin and
one-dof prismatic joints (any axis); :class:`CompiledCrba` decides at construction (and checks
the result against ``pin.crba`` on random configurations); ``supported = False`` (with
``reason``) tells the caller to keep the pinocchio loop.

Explicit signature (read-only inputs: ``'A'`` layout for the configurations, ``'C'`` for the
model constants, packed into two arrays: each array argument costs dispatch time), ``cache=True``:
compiled or loaded at import. No array-argument helpers in the inner loops (each such call costs
tens of ns); ``fastmath={"contract"}`` only (FMA: about 13 % faster; NaN and inf unchanged).
"""

from __future__ import annotations

import math

import numpy as np
import pinocchio as pin
from numba import njit, types

from sara_app.kernel_types import RO2 as _RO2
from sara_app.kernel_types import ROC2 as _ROC2
from sara_app.kernel_types import ROCI2 as _ROCI2
from sara_app.kernel_types import WC2 as _WC2
from sara_app.kernel_types import WC3 as _WC3

__all__ = ["REVOLUTE", "PRISMATIC", "CompiledCrba", "crba_kernel"]

REVOLUTE, PRISMATIC = 0, 1
_CHECK_RTOL = 1e-10


# Columns of ``ints (n, 4 + n)`` per joint: position index, velocity index, type, parent (-1:
# the universe), then ``support[j, i]`` (1: joint i supports joint j, i == j included).
# Columns of the constants ``P (n, 47)`` per joint: placement rotation Rp (row-major, 0:9),
# Rp K (9:18), Rp K^2 (18:27) (K = [a]x; zero for a prismatic joint), placement translation tp
# (27:30), axis a (30:33), Rp a (33:36); body mass (36), centre of mass c (37:40), rotational
# inertia about c as xx, yy, zz, xy, xz, yz (40:46), all in the joint frame; armature (46).
# Columns of the scratch ``work (n, 28)``: R (0:9), p (9:12), S = (v, w) (12:18), composite
# inertia m, h (3), I_O xx yy zz xy xz yz (18:28).


@njit(types.void(_RO2, _ROCI2, _ROC2, _WC2, _WC3), cache=True, fastmath={"contract"})
def crba_kernel(
    Q: np.ndarray, ints: np.ndarray, P: np.ndarray, work: np.ndarray, M: np.ndarray
) -> None:
    """Inertia matrices ``M[s] (nv, nv)`` (both triangles) at configurations ``Q (S, nq)``.

    Per joint ``j`` in kinematic order (``parent < j``): ``ints (n, 4 + n)`` and ``P (n, 47)``
    (columns in the module source); ``work (n, 28)`` scratch; ``M (S, nv, nv)`` C-contiguous.
    A non-finite ``Q`` row gives non-finite entries in its matrix (no exception).
    """
    S = Q.shape[0]
    n = ints.shape[0]
    for s in range(S):
        for j in range(n):  # forward: poses, motion subspaces, body inertias about the origin
            x = Q[s, ints[j, 0]]
            if ints[j, 2] == REVOLUTE:
                sq, cq, dq = math.sin(x), 1.0 - math.cos(x), 0.0
            else:
                sq, cq, dq = 0.0, 0.0, x
            r00 = P[j, 0] + sq * P[j, 9] + cq * P[j, 18]
            r01 = P[j, 1] + sq * P[j, 10] + cq * P[j, 19]
            r02 = P[j, 2] + sq * P[j, 11] + cq * P[j, 20]
            r10 = P[j, 3] + sq * P[j, 12] + cq * P[j, 21]
            r11 = P[j, 4] + sq * P[j, 13] + cq * P[j, 22]
            r12 = P[j, 5] + sq * P[j, 14] + cq * P[j, 23]
            r20 = P[j, 6] + sq * P[j, 15] + cq * P[j, 24]
            r21 = P[j, 7] + sq * P[j, 16] + cq * P[j, 25]
            r22 = P[j, 8] + sq * P[j, 17] + cq * P[j, 26]
            t0 = P[j, 27] + dq * P[j, 33]
            t1 = P[j, 28] + dq * P[j, 34]
            t2 = P[j, 29] + dq * P[j, 35]
            pj = ints[j, 3]
            if pj >= 0:
                a00, a01, a02 = work[pj, 0], work[pj, 1], work[pj, 2]
                a10, a11, a12 = work[pj, 3], work[pj, 4], work[pj, 5]
                a20, a21, a22 = work[pj, 6], work[pj, 7], work[pj, 8]
                p0 = work[pj, 9] + a00 * t0 + a01 * t1 + a02 * t2
                p1 = work[pj, 10] + a10 * t0 + a11 * t1 + a12 * t2
                p2 = work[pj, 11] + a20 * t0 + a21 * t1 + a22 * t2
                r00, r01, r02, r10, r11, r12, r20, r21, r22 = (
                    a00 * r00 + a01 * r10 + a02 * r20,
                    a00 * r01 + a01 * r11 + a02 * r21,
                    a00 * r02 + a01 * r12 + a02 * r22,
                    a10 * r00 + a11 * r10 + a12 * r20,
                    a10 * r01 + a11 * r11 + a12 * r21,
                    a10 * r02 + a11 * r12 + a12 * r22,
                    a20 * r00 + a21 * r10 + a22 * r20,
                    a20 * r01 + a21 * r11 + a22 * r21,
                    a20 * r02 + a21 * r12 + a22 * r22,
                )
            else:
                p0, p1, p2 = t0, t1, t2
            work[j, 0], work[j, 1], work[j, 2] = r00, r01, r02
            work[j, 3], work[j, 4], work[j, 5] = r10, r11, r12
            work[j, 6], work[j, 7], work[j, 8] = r20, r21, r22
            work[j, 9], work[j, 10], work[j, 11] = p0, p1, p2
            ax, ay, az = P[j, 30], P[j, 31], P[j, 32]
            u0 = r00 * ax + r01 * ay + r02 * az  # world axis
            u1 = r10 * ax + r11 * ay + r12 * az
            u2 = r20 * ax + r21 * ay + r22 * az
            if ints[j, 2] == REVOLUTE:
                work[j, 12] = p1 * u2 - p2 * u1
                work[j, 13] = p2 * u0 - p0 * u2
                work[j, 14] = p0 * u1 - p1 * u0
                work[j, 15], work[j, 16], work[j, 17] = u0, u1, u2
            else:
                work[j, 12], work[j, 13], work[j, 14] = u0, u1, u2
                work[j, 15] = work[j, 16] = work[j, 17] = 0.0
            m, cx, cy, cz = P[j, 36], P[j, 37], P[j, 38], P[j, 39]
            ixx, iyy, izz, ixy, ixz, iyz = (
                P[j, 40],
                P[j, 41],
                P[j, 42],
                P[j, 43],
                P[j, 44],
                P[j, 45],
            )
            c0 = r00 * cx + r01 * cy + r02 * cz + p0
            c1 = r10 * cx + r11 * cy + r12 * cz + p1
            c2 = r20 * cx + r21 * cy + r22 * cz + p2
            # T = R I_c, then R I_c R^T (upper entries)
            b00 = r00 * ixx + r01 * ixy + r02 * ixz
            b01 = r00 * ixy + r01 * iyy + r02 * iyz
            b02 = r00 * ixz + r01 * iyz + r02 * izz
            b10 = r10 * ixx + r11 * ixy + r12 * ixz
            b11 = r10 * ixy + r11 * iyy + r12 * iyz
            b12 = r10 * ixz + r11 * iyz + r12 * izz
            b20 = r20 * ixx + r21 * ixy + r22 * ixz
            b21 = r20 * ixy + r21 * iyy + r22 * iyz
            b22 = r20 * ixz + r21 * iyz + r22 * izz
            cc = c0 * c0 + c1 * c1 + c2 * c2
            work[j, 18] = m
            work[j, 19], work[j, 20], work[j, 21] = m * c0, m * c1, m * c2
            work[j, 22] = b00 * r00 + b01 * r01 + b02 * r02 + m * (cc - c0 * c0)
            work[j, 23] = b10 * r10 + b11 * r11 + b12 * r12 + m * (cc - c1 * c1)
            work[j, 24] = b20 * r20 + b21 * r21 + b22 * r22 + m * (cc - c2 * c2)
            work[j, 25] = b00 * r10 + b01 * r11 + b02 * r12 - m * c0 * c1
            work[j, 26] = b00 * r20 + b01 * r21 + b02 * r22 - m * c0 * c2
            work[j, 27] = b10 * r20 + b11 * r21 + b12 * r22 - m * c1 * c2
        for j in range(n - 1, 0, -1):  # backward: composite inertias (same frame: sums)
            pj = ints[j, 3]
            if pj >= 0:
                for c in range(18, 28):
                    work[pj, c] += work[j, c]
        for j in range(n):
            v0, v1, v2 = work[j, 12], work[j, 13], work[j, 14]
            w0, w1, w2 = work[j, 15], work[j, 16], work[j, 17]
            m, h0, h1, h2 = work[j, 18], work[j, 19], work[j, 20], work[j, 21]
            ixx, iyy, izz = work[j, 22], work[j, 23], work[j, 24]
            ixy, ixz, iyz = work[j, 25], work[j, 26], work[j, 27]
            f0 = m * v0 + w1 * h2 - w2 * h1  # linear momentum m v + w x h
            f1 = m * v1 + w2 * h0 - w0 * h2
            f2 = m * v2 + w0 * h1 - w1 * h0
            n0 = ixx * w0 + ixy * w1 + ixz * w2 + h1 * v2 - h2 * v1  # I_O w + h x v
            n1 = ixy * w0 + iyy * w1 + iyz * w2 + h2 * v0 - h0 * v2
            n2 = ixz * w0 + iyz * w1 + izz * w2 + h0 * v1 - h1 * v0
            vj = ints[j, 1]
            for i in range(j + 1):
                vi = ints[i, 1]
                val = 0.0
                if ints[j, 4 + i]:
                    val = (
                        work[i, 12] * f0 + work[i, 13] * f1 + work[i, 14] * f2
                        + work[i, 15] * n0 + work[i, 16] * n1 + work[i, 17] * n2
                    )  # fmt: skip
                M[s, vi, vj] = val
                M[s, vj, vi] = val
            M[s, vj, vj] += P[j, 46]


def _flat_sym(I3: np.ndarray) -> list[float]:
    return [I3[0, 0], I3[1, 1], I3[2, 2], I3[0, 1], I3[0, 2], I3[1, 2]]


def _skew(a: np.ndarray) -> np.ndarray:
    return np.array([[0.0, -a[2], a[1]], [a[2], 0.0, -a[0]], [-a[1], a[0], 0.0]])


class CompiledCrba:
    """:func:`crba_kernel` for one pinocchio model: constants extracted once, scratch owned.

    ``supported`` is False (``reason`` says why) when a joint is not a one-dof revolute or
    prismatic joint, or when the compiled matrices differ from ``pin.crba`` on random
    configurations; the caller then keeps ``pin.crba``. Not thread-safe (scratch buffer).
    """

    def __init__(self, pm: pin.Model, seed: int = 0) -> None:
        self.nq, self.nv = int(pm.nq), int(pm.nv)
        self.supported, self.reason = True, ""
        try:
            self._extract(pm)
        except _Unsupported as e:
            self.supported, self.reason = False, str(e)
            return
        rng = np.random.default_rng(seed)
        Q = rng.uniform(-2.0, 2.0, (4, self.nq))
        M = np.empty((4, self.nv, self.nv))
        self.compute(Q, M)
        data = pm.createData()
        for s in range(4):
            ref = np.triu(pin.crba(pm, data, Q[s]))
            ref = ref + np.triu(ref, 1).T
            scale = max(float(np.max(np.abs(ref))), 1e-300)
            err = float(np.max(np.abs(M[s] - ref))) / scale
            if not err <= _CHECK_RTOL:
                self.supported = False
                self.reason = f"compiled CRBA differs from pin.crba by {err:.3g} (relative)"
                return

    def _extract(self, pm: pin.Model) -> None:
        n = pm.njoints - 1
        if n < 1:
            raise _Unsupported("model has no joints")
        data = pm.createData()
        pin.computeJointJacobians(pm, data, pin.neutral(pm))
        ints = np.zeros((n, 4 + n), dtype=np.int64)
        P = np.zeros((n, 47))
        for jid in range(1, pm.njoints):
            j, jm = jid - 1, pm.joints[jid]
            if jm.nq != 1 or jm.nv != 1:
                raise _Unsupported(f"joint {pm.names[jid]!r} ({jm.shortname()}) is not one-dof")
            kind, a = _joint_kind(pm, data, jid)
            ints[j, :4] = pm.idx_qs[jid], pm.idx_vs[jid], kind, pm.parents[jid] - 1
            for i in pm.supports[jid].tolist()[1:]:
                ints[j, 4 + i - 1] = 1
            Rp = np.array(pm.jointPlacements[jid].rotation)
            K = _skew(a) if kind == REVOLUTE else np.zeros((3, 3))
            Y = pm.inertias[jid]
            P[j, 0:9] = Rp.ravel()
            P[j, 9:18] = (Rp @ K).ravel()
            P[j, 18:27] = (Rp @ K @ K).ravel()
            P[j, 27:30] = pm.jointPlacements[jid].translation
            P[j, 30:33] = a
            P[j, 33:36] = Rp @ a
            P[j, 36:46] = [Y.mass, *np.asarray(Y.lever), *_flat_sym(np.asarray(Y.inertia))]
            P[j, 46] = float(np.asarray(pm.armature)[pm.idx_vs[jid]])
        ints.flags.writeable = False
        P.flags.writeable = False
        self._ints, self._consts = ints, P
        self._work = np.zeros((n, 28))

    def kernel_arrays(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """``(ints, P, work)`` of :func:`crba_kernel` for kernels that call it themselves (the
        scratch ``work`` included: not thread-safe either)."""
        return self._ints, self._consts, self._work

    def compute(self, Q: np.ndarray, M: np.ndarray) -> None:
        """``M (S, nv, nv)`` C-contiguous (written, both triangles) from ``Q (S, nq)`` float64
        (shapes checked by the caller)."""
        crba_kernel(Q, self._ints, self._consts, self._work, M)


def _joint_kind(pm: pin.Model, data: pin.Data, jid: int) -> tuple[int, np.ndarray]:
    """:data:`REVOLUTE` or :data:`PRISMATIC` and the unit axis in the joint frame, from the
    joint's motion subspace (``data`` holds the joint Jacobians at some configuration)."""
    J = pin.getJointJacobian(pm, data, jid, pin.ReferenceFrame.LOCAL)
    col = np.reshape(np.array(J), (6, -1))[:, pm.idx_vs[jid]]
    lin, ang = np.linalg.norm(col[:3]), np.linalg.norm(col[3:])
    if lin <= 1e-12 and abs(ang - 1.0) <= 1e-9:
        return REVOLUTE, col[3:] / ang
    if ang <= 1e-12 and abs(lin - 1.0) <= 1e-9:
        return PRISMATIC, col[:3] / lin
    raise _Unsupported(
        f"joint {pm.names[jid]!r} ({pm.joints[jid].shortname()}) is neither revolute about an "
        "axis through its origin nor prismatic"
    )


class _Unsupported(Exception):
    """A model feature the compiled CRBA does not handle (internal: becomes ``reason``)."""
