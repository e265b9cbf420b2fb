"""The admissible path-speed boxes of a :class:`~sara_app.robot.path.PathTrajectory` under
given joint limits (the time-scaling of :mod:`sara_app.robot.path`'s notes): per piece ``k`` a
box ``(V_k, A_k, J_k)`` for the path speed, acceleration and jerk that keeps every joint within
its limits, and the tables the follower's scalar loops read."""

from __future__ import annotations

import math
import weakref

import numpy as np

from sara_app.errors import RobotModelError
from sara_app.robot.joints import LIMIT_MARGIN, LimitArrays, limit_arrays
from sara_app.robot.model import JointLimits
from sara_app.robot.path import PathTrajectory

__all__ = ["PathTables", "path_tables", "piece_boxes", "piece_room", "sub_piece_room"]


class PathTables:
    """Per-piece data of a path under given limits, as Python floats for scalar hot loops.

    ``lin[k]``: piece ``k`` is straight; ``v_lin, a_lin, j_lin``: its exact path limits then;
    ``rows[k]``: per-joint tuples ``(M1, M2, M3, 1/M1, v_max, a_max, j_max)``.
    """

    __slots__ = ("source", "lim", "lin", "v_lin", "a_lin", "j_lin", "rows", "u", "dl")

    def __init__(self, path: PathTrajectory, limits: JointLimits) -> None:
        self.source = limits
        lim = limit_arrays(limits, path.n_joints)
        self.lim = lim
        self.lin: list[bool] = []
        self.v_lin: list[float] = []
        self.a_lin: list[float] = []
        self.j_lin: list[float] = []
        self.rows: list[list[tuple[float, ...]]] = []
        self.u: list[list[float]] = []
        self.dl: list[list[float]] = []
        if path.n_pieces == 0 or path._p is None:
            return
        self.u = path._p.u.tolist()
        self.dl = path._p.dl.tolist()
        with np.errstate(divide="ignore", invalid="ignore"):
            v_lin = np.min(lim.v * path.invM1, axis=1)
            a_lin = np.min(lim.a * path.invM1, axis=1)
            j_lin = np.min(lim.j * path.invM1, axis=1)
        self.v_lin = [float(x) for x in v_lin]
        self.a_lin = [float(x) for x in a_lin]
        self.j_lin = [float(x) for x in j_lin]
        self.lin = [
            bool(x) for x in (np.max(path.M2, axis=1) == 0) & (np.max(path.M3, axis=1) == 0)
        ]
        cols = (lim.v, lim.a, lim.j)
        for k in range(path.n_pieces):
            self.rows.append(
                list(
                    zip(
                        path.M1[k].tolist(),
                        path.M2[k].tolist(),
                        path.M3[k].tolist(),
                        path.invM1[k].tolist(),
                        *(c.tolist() for c in cols),
                        strict=True,
                    )
                )
            )


_CACHE: weakref.WeakKeyDictionary[PathTrajectory, PathTables] = weakref.WeakKeyDictionary()
"""The newest tables of each live path (a path does not change once built)."""


def path_tables(path: PathTrajectory, limits: JointLimits) -> PathTables:
    """:class:`PathTables` of ``path`` under ``limits`` (cached per path and limits object)."""
    cached = _CACHE.get(path)
    if cached is not None and cached.source is limits:
        return cached
    tables = _CACHE[path] = PathTables(path, limits)
    return tables


def piece_room(tab: PathTables, k: int, w: float, am: float) -> tuple[float, float]:
    """``(A, J)`` room on piece ``k`` at path speed <= ``w`` and ``|s''|`` <= ``am``:
    ``min_j (a_j - M2 w^2) / M1`` and ``min_j (j_j - M3 w^3 - 3 M2 w am) / M1``;
    ``(-1, -1)`` if the speed alone breaks a joint velocity limit."""
    if tab.lin[k]:
        if w > tab.v_lin[k]:
            return -1.0, -1.0
        return tab.a_lin[k], tab.j_lin[k]
    w2 = w * w
    w3 = w2 * w
    A = math.inf
    J = math.inf
    for m1, m2, m3, im1, vj, aj, jj in tab.rows[k]:
        if m1 * w > vj:
            return -1.0, -1.0
        ar = (aj - m2 * w2) * im1
        jr = (jj - m3 * w3 - 3.0 * m2 * w * am) * im1
        if ar < A:
            A = ar
        if jr < J:
            J = jr
    return A, J


def sub_piece_room(
    path: PathTrajectory, tab: PathTables, k: int, sa: float, sb: float, w: float, am: float
) -> tuple[float, float]:
    """:func:`piece_room` with the maxima of ``|q'|``, ``|q''|``, ``|q'''|`` taken over
    ``[sa, sb]`` inside piece ``k`` only. The extremes are exact: along a blend ``q'`` is
    monotone, ``h'`` is concave with its peak at the middle and ``h''`` is linear."""
    if tab.lin[k]:
        return piece_room(tab, k, w, am)
    s0 = path._s0_list[k]
    x_lo, x_hi = path._x0_list[k], path._x1_list[k]
    iL = path._invL_list[k]
    xa = min(max(x_lo + (sa - s0) * iL, x_lo), x_hi)
    xb = min(max(x_lo + (sb - s0) * iL, xa), x_hi)
    ha, hb = xa * xa * (3.0 - 2.0 * xa), xb * xb * (3.0 - 2.0 * xb)
    xm = min(max(0.5, xa), xb)
    dh = 6.0 * xm * (1.0 - xm) * iL
    ddh = max(abs(6.0 - 12.0 * xa), abs(6.0 - 12.0 * xb)) * iL * iL
    w2 = w * w
    w3 = w2 * w
    A = math.inf
    J = math.inf
    for (_, _, _, _, vj, aj, jj), uj, dj in zip(tab.rows[k], tab.u[k], tab.dl[k], strict=True):
        m1 = max(abs(uj + ha * dj), abs(uj + hb * dj))
        adj = abs(dj)
        m2 = adj * dh
        if m1 * w > vj:
            return -1.0, -1.0
        if m1 > 0.0:
            ar = (aj - m2 * w2) / m1
            jr = (jj - adj * ddh * w3 - 3.0 * m2 * w * am) / m1
            if ar < A:
                A = ar
            if jr < J:
                J = jr
    return A, J


def piece_boxes(
    path: PathTrajectory, lim: LimitArrays, tangential_share: float
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """``(V, A, J)`` per piece: path speed, acceleration and jerk limits that keep every joint
    within its limits on that piece (see the module notes)."""
    M1, M2, M3 = path.M1, path.M2, path.M3
    iM1 = path.invM1
    rho = tangential_share
    with np.errstate(divide="ignore", invalid="ignore"):
        v_vel = np.min(np.where(M1 > 0, lim.v / np.where(M1 > 0, M1, 1.0), np.inf), axis=1)
        v_acc = np.min(
            np.where(M2 > 0, np.sqrt((1 - rho) * lim.a / np.where(M2 > 0, M2, 1.0)), np.inf),
            axis=1,
        )
        a_lin = np.min(lim.a * iM1, axis=1)
        # jerk: M3 V^3 + 3 M2 a_lin V <= (1 - rho) j, per joint; unique positive root of a
        # cubic with non-negative coefficients (stable Cardano form, then two Newton steps)
        c3 = M3
        c1 = 3.0 * M2 * a_lin[:, None]
        r = (1 - rho) * lim.j
        v_j = np.full(M1.shape, np.inf)
        lin_only = (c3 == 0) & (c1 > 0)
        v_j = np.where(lin_only, r / np.where(c1 > 0, c1, 1.0), v_j)
        cub = c3 > 0
        c3s = np.where(cub, c3, 1.0)
        pp = c1 / c3s
        qq = r / c3s
        disc = np.sqrt(0.25 * qq * qq + pp**3 / 27.0)
        aa = np.cbrt(0.5 * qq + disc)
        bb = np.cbrt(disc - 0.5 * qq)
        root = qq / (aa * aa + aa * bb + bb * bb)
        for _ in range(2):
            f = root**3 + pp * root - qq
            root = root - f / (3.0 * root * root + pp)
        v_j = np.where(cub, root, v_j)
    V = np.minimum(np.minimum(v_vel, v_acc), np.min(v_j, axis=1))
    V = V * (1.0 - LIMIT_MARGIN)
    A = np.min((lim.a - M2 * (V * V)[:, None]) * iM1, axis=1)
    A = np.maximum(A, 0.0) * (1.0 - LIMIT_MARGIN)
    J = np.min((lim.j - M3 * (V**3)[:, None] - 3.0 * M2 * (V * A)[:, None]) * iM1, axis=1)
    J = J * (1.0 - LIMIT_MARGIN)
    if np.any(A <= 0) or np.any(J <= 0) or np.any(V <= 0):  # pragma: no cover - by construction
        raise RobotModelError("path has a piece with no admissible path speed; check the limits")
    return V, A, J
