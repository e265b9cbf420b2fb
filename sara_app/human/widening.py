"""Wider sets for one person whose skeleton says less than the parameter set assumes: a stated
position uncertainty above the set's ``delta_y``, or an upper-body source that does not measure
the legs (DESIGN 8, "use it or brake": a contract-valid message is used, never dropped).

Every model's set is a union of balls around functions of the measured joints (Schepp et al. 2022
Sec. II-B; Pereira & Althoff 2016 Sec. III). If joint ``j`` lies within ``delta_y + e_j`` of its
measurement instead of ``delta_y``, a capsule that must contain joints ``{j}`` stays sound when its
radius grows by ``max_j e_j`` (for R_VEL, R_ACC, ISO 13855 and the head / torso capsules of R_POS,
which are Minkowski sums with B(delta_y)). Exceptions, per model:

- R_POS limbs (ball at the root, radius with the *measured* segment lengths): each of the ``n``
  segment lengths is off by ``2 e`` and the root by ``e``: ``(1 + 2 n) e``. An unmeasured leg
  (all its joints placed at the pelvis) is a ball at the pelvis grown by the ankle's
  ``UNMEASURED_LEG_REACH_M`` (every leg point lies that close to the pelvis, and the leg's root
  then moves at most at the hip's v_max).
- Pereira's arm model maps measured joints to joint angles: a larger position error changes the
  angles in ways its bounds do not cover, so its two arm capsules become infinite (never free:
  the other models decide) when ``e > 0``; its other capsules are ISO 13855 ones.
- R_ACC needs the unmeasured legs' velocities: their bound is infinite (set by the caller), so
  its leg capsules are infinite too.

``UNMEASURED_LEG_REACH_M`` (:mod:`sara_app.human.anatomy`): the farthest a hip, knee or ankle
joint can be from the pelvis joint. How high the legs reach is bounded separately where the
parameter set says so (:mod:`sara_app.human.legs`).
"""

from __future__ import annotations

import numpy as np

from sara_app.human.anatomy import UNMEASURED_LEG_REACH_M
from sara_app.human.reach import MODELS, HumanReach, part_capsules
from sara_app.human.skeleton import UPPER_JOINTS


def _leg_reach(joint: str) -> float:
    """:data:`UNMEASURED_LEG_REACH_M` of a joint name (``l_knee``); 0 for joints of the upper
    body."""
    return UNMEASURED_LEG_REACH_M.get(joint.split("_", 1)[-1], 0.0)


def widening(
    reach: HumanReach, extra_m: float | np.ndarray, legs_measured: bool
) -> np.ndarray | None:
    """Extra radius per model and body part ``(len(MODELS), P)`` (rows in ``MODELS`` order;
    a part's value is that of the model's capsule containing it), or None when nothing is
    widened. ``extra_m``: the position uncertainty beyond the parameter set's ``delta_y``, one
    value or one per joint ``(J,)`` (>= 0; a joint held by the tracking gate)."""
    e = np.maximum(np.broadcast_to(np.asarray(extra_m, float), (reach.skeleton.n_joints,)), 0.0)
    if not e.any() and legs_measured:
        return None
    caps = capsule_widening(reach, e, legs_measured)
    return np.stack([caps[m][part_capsules(reach, m)] for m in MODELS])


def capsule_widening(
    reach: HumanReach, extra_m: float | np.ndarray, legs_measured: bool
) -> dict[str, np.ndarray]:
    """Extra radius per capsule of every model: ``{model: (C,)}`` (see the module notes);
    ``extra_m`` one value or ``(J,)``. A limb of R_POS takes its chain's largest extra."""
    sk = reach.skeleton
    extra = np.maximum(np.broadcast_to(np.asarray(extra_m, float), (sk.n_joints,)), 0.0)
    unmeasured = np.array([not legs_measured and j not in UPPER_JOINTS for j in sk.joints])
    reach_j = np.array([_leg_reach(j) for j in sk.joints])
    e = np.where(unmeasured, extra + reach_j, extra)  # (J,)
    arm_joints = [sk.joints.index(f"{s}_{j}") for s in "lr" for j in ("shoulder", "elbow", "wrist")]
    out = {}
    for m in MODELS:
        cap, joint, _ = reach.coverage[m]
        ext = np.zeros(int(cap.max()) + 1)
        np.maximum.at(ext, cap, e[joint])
        if m == "pos":
            for i, chain in enumerate(sk.limb_chains):
                legs = list(chain)
                worst = float(extra[legs].max())
                leg = float(np.where(unmeasured[legs], reach_j[legs], 0.0).max())
                ext[i] = (1 + 2 * (len(chain) - 1)) * worst + leg
        elif m == "arm" and extra[arm_joints].max() > 0.0:
            ext[:2] = np.inf
        out[m] = ext
    return out


def per_capsule(widen_p: np.ndarray, part_map: np.ndarray, n_capsules: int) -> np.ndarray:
    """``(..., C)`` a model's widening per capsule from its per-part rows ``widen_p (..., P)``
    (one row, or one per person) and the part -> capsule map
    (:func:`~sara_app.human.reach.part_capsules`): a capsule grows by the largest widening of
    the parts it stands for. A capsule that stands for no part keeps its radius: soundness
    needs each part inside its own (widened) capsule only."""
    extra = np.zeros((*widen_p.shape[:-1], n_capsules))
    np.maximum.at(extra.T, part_map, widen_p.T)  # capsules on the first axis of the views
    return extra
