"""One skeleton message into one person's state: the live worker's path, and the one the
history property test drives (``tests/test_ingest_history.py``), so what is tested is what runs.

The message's joints are mapped to the full skeleton, range-checked, taken by the person's
intake (the tracking gate, the velocity estimator, the conformance monitor and the stale-tracker
rule, :mod:`sara_app.human.intake`) and, when taken, become the person's
:class:`~sara_app.safety.shield.HumanState`: positions (a held joint at the centre of the ball
that encloses its history and its measurement), velocities with their error bounds and the
widening of every model's capsules (:mod:`sara_app.human.widening`). A message that is not taken
changes nothing: the person ages (the reason is returned for the drop counters).
"""

from __future__ import annotations

import numpy as np

from sara_app.bus.messages import SkeletonMsg
from sara_app.cell import Cell
from sara_app.errors import SaraError
from sara_app.human.gate import GateResult
from sara_app.human.skeleton import UPPER_JOINTS, full_body
from sara_app.human.widening import widening
from sara_app.presence import Track


def ingest_skeleton(cell: Cell, track: Track, msg: SkeletonMsg) -> str | None:
    """Take ``msg`` into ``track``; None when taken, else the contract's reason for refusing
    it (``out_of_range``, ``stamp_not_advancing``, ``tracking_inconsistent``, ``repeated``)."""
    p = cell.params
    inputs = cell.scenario.inputs
    y, v = full_body(*msg.to_arrays())
    n_measured = len(y) if msg.kind == "full" else len(UPPER_JOINTS)
    missing, low = (np.pad(a, (0, len(y) - len(a))) for a in msg.joint_states())
    seen = ~missing  # a missing joint's row is NaN: the gate holds it
    if not (
        seen.any()
        and np.abs(y[seen]).max() <= inputs.cell_bound_m
        and (v is None or np.abs(v[seen]).max() <= inputs.cell_bound_m)
    ):
        return "out_of_range"  # NaN and overflow to inf fail the test too
    unc = msg.position_uncertainty_m
    delta_y = p.delta_y_m if unc is None else max(unc, p.delta_y_m)
    try:
        taken = track.intake.take(msg.stamp_s, y, delta_y, n_measured, missing)
    except SaraError:
        return "stamp_not_advancing"
    if taken is None:  # a joint distrusted too long, or a repeat: the person ages
        return track.intake.refusal or "tracking_inconsistent"
    g, v_est, dv_est = taken
    st = track.state
    low_m = np.where(low, inputs.low_confidence_extra_m, 0.0)
    st.widen_m = _widening(cell, track, unc, msg.kind == "full", g, low_m if low.any() else None)
    if v is not None:
        unc_v = msg.velocity_uncertainty_mps
        st.v = np.where(seen[:, None], v, 0.0)
        st.dv = np.full(len(y), p.delta_v_mps if unc_v is None else max(unc_v, p.delta_v_mps))
        st.dv[~g.trusted] = np.inf  # a held joint's stated velocity may be the glitch's
        st.v[~g.trusted] = 0.0
    else:
        st.v, st.dv = v_est.copy(), dv_est.copy()
    if msg.kind != "full":
        st.dv[len(UPPER_JOINTS) :] = np.inf  # the legs' velocities are not measured
    st.y = g.y.copy()
    st.stamp_s = msg.stamp_s
    return None


def _widening(
    cell: Cell,
    track: Track,
    unc_m: float | None,
    legs: bool,
    gated: GateResult | None,
    low_m: np.ndarray | None = None,
) -> np.ndarray | None:
    """The person's widening for a message's stated uncertainty, whether its source measures
    the legs, the joints the gate holds and the tracker's low-confidence joints ``low_m (J,)``
    (cached on the track while nothing is held or low: recomputed when they or the parameters
    change)."""
    reach = cell.shield.reach
    extra = 0.0 if unc_m is None else max(unc_m - cell.params.delta_y_m, 0.0)
    if (gated is not None and gated.held) or low_m is not None:
        track.widen_key = None
        per_joint = extra + (0.0 if gated is None else gated.extra_m)
        per_joint = per_joint + (0.0 if low_m is None else low_m)
        return widening(reach, per_joint, legs_measured=legs)
    key = (unc_m, legs, extra)
    if track.widen_key != key:
        track.widen_key = key
        track.widen_m = widening(reach, extra, legs_measured=legs)
    return track.widen_m


def rewiden(cell: Cell, track: Track) -> None:
    """After new parameters (a scenario edit): the widening of the person's newest message
    under them, where it is cached (nothing held or low; otherwise the next message sets it)."""
    if track.widen_key is not None:
        unc_m, legs, _ = track.widen_key
        track.state.widen_m = _widening(cell, track, unc_m, legs, None)
