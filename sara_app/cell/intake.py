"""One person's measurement into the shield's view of them: the live worker
(:mod:`sara_app.runtime.people`, from a skeleton message) and the simulator's sensors
(:mod:`sara_app.sim.simulator`) take measurements through this one path.

A measurement is range-checked, taken by the person's intake (the tracking gate, the velocity
estimator, the conformance monitor and the stale-tracker rule, :mod:`sara_app.human.intake`)
and, when taken, becomes the person's :class:`~sara_app.safety.shield.HumanState`: positions (a
held joint at the centre of the ball that encloses its history and its measurement), velocities
with their error bounds and the widening of every model's capsules
(:mod:`sara_app.human.widening`). A measurement that is not taken changes nothing: the person
ages (the reason is returned for the drop counters).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from sara_app.cell.build import Cell
from sara_app.errors import SaraError
from sara_app.human.gate import GateResult
from sara_app.human.intake import Displacement, Intake, displacement_of
from sara_app.human.legs import leg_caps
from sara_app.human.skeleton import UPPER_JOINTS
from sara_app.human.tracking_settings import IntakeSettings
from sara_app.human.widening import widening
from sara_app.safety.shield import HumanState


@dataclass
class Track:
    """One person: the shield's view (``state``), their intake (gate, velocity estimator and
    conformance monitor) and ``evidence_s``,
    the wall-clock time of the newest evidence of them (skeleton stamp, refusal time or the
    stamp of a frame that listed them)."""

    state: HumanState
    intake: Intake
    evidence_s: float = -math.inf
    widen_key: tuple[float | None, bool, float] | None = None
    widen_m: np.ndarray | None = None
    """The widening for ``widen_key = (stated uncertainty m, legs measured, extra m)``."""


def unmeasured_track(
    human_id: str,
    delta_y_m: float,
    v_max: np.ndarray,
    a_max: np.ndarray,
    settings: IntakeSettings | None = None,
    pelvis_rise_mps: float = np.inf,
    displacement: Displacement = None,
) -> Track:
    """A known person without a measurement yet (a fault until one arrives);
    ``pelvis_rise_mps``: the monitor's bound on the pelvis's rise where the legs are not
    measured (:mod:`sara_app.human.legs`); ``displacement``: the monitor's displacement bound
    (:func:`~sara_app.human.intake.displacement_of`)."""
    return Track(
        HumanState.unmeasured(human_id, len(v_max)),
        Intake(
            delta_y_m, v_max, a_max, settings or IntakeSettings(), pelvis_rise_mps, displacement
        ),  # fmt: skip
    )


def track_for(cell: Cell, human_id: str) -> Track:
    """A new, unmeasured track of ``human_id`` under the cell's parameters and intake settings."""
    p = cell.params
    gate = cell.scenario.inputs.gate.intake()
    return unmeasured_track(
        human_id,
        p.delta_y_m,
        p.v_max_mps,
        p.a_max_mps2,
        gate,
        p.pelvis_rise_mps,
        displacement_of(p),
    )


def take_measurement(
    cell: Cell,
    track: Track,
    stamp_s: float,
    y: np.ndarray,
    *,
    v: np.ndarray | None = None,
    missing: np.ndarray | None = None,
    low: np.ndarray | None = None,
    unc_m: float | None = None,
    unc_v_mps: float | None = None,
    legs_measured: bool = True,
) -> str | None:
    """Take joint positions ``y (J, 3)`` of the full skeleton (world frame, m) stamped
    ``stamp_s`` into ``track``; None when taken, else the contract's reason for refusing them
    (``out_of_range``, ``stamp_not_advancing``, ``tracking_inconsistent``, ``repeated``).
    ``v (J, 3)``: stated velocities (None: estimated); ``missing``, ``low (J,)``: joints not
    measured or of low tracker confidence; ``unc_m``, ``unc_v_mps``: stated uncertainties;
    ``legs_measured``: False for an upper-body source (the legs' rows are then not measured)."""
    p = cell.params
    inputs = cell.scenario.inputs
    J = len(y)
    n_measured = J if legs_measured else len(UPPER_JOINTS)
    missing = np.zeros(J, bool) if missing is None else missing
    seen = ~missing  # a missing joint's row is NaN: the gate holds it
    if not (
        seen.any()
        and np.abs(y[seen]).max() <= inputs.cell_bound_m
        and (v is None or np.abs(v[seen]).max() <= inputs.cell_bound_m)
    ):
        return "out_of_range"  # NaN and overflow to inf fail the test too
    delta_y = p.delta_y_m if unc_m is None else max(unc_m, p.delta_y_m)
    try:
        taken = track.intake.take(stamp_s, y, delta_y, n_measured, missing)
    except SaraError:
        return "stamp_not_advancing"
    if taken is None:  # a joint distrusted too long, or a repeat: the person ages
        return track.intake.refusal or "tracking_inconsistent"
    g, v_est, dv_est = taken
    st = track.state
    low_m = (
        None if low is None or not low.any() else np.where(low, inputs.low_confidence_extra_m, 0.0)
    )
    st.widen_m = _widening(cell, track, unc_m, legs_measured, g, low_m)
    st.leg_cap = None  # unmeasured legs: below the gated pelvis, its uncertainty included
    if not legs_measured:
        st.leg_cap = leg_caps(p, g.y, _joint_extra(_stated_extra(cell, unc_m), g, low_m))
    if v is not None:  # checked against the positions' estimate (a contradiction: a fault)
        v_s = np.where((seen & g.trusted)[:, None], v, 0.0)
        dv_s = np.full(J, p.delta_v_mps if unc_v_mps is None else max(unc_v_mps, p.delta_v_mps))
        dv_s[~g.trusted] = np.inf  # a held joint's stated velocity may be the glitch's
        st.v, st.dv = track.intake.stated(stamp_s, v_s, dv_s, v_est, dv_est,
                                          inputs.trust_stated_velocities)  # fmt: skip
    else:
        st.v, st.dv = v_est.copy(), dv_est.copy()
    if not legs_measured:
        st.dv[len(UPPER_JOINTS) :] = np.inf  # the legs' velocities are not measured
    st.y = g.y.copy()
    st.stamp_s = stamp_s
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
    extra = _stated_extra(cell, unc_m)
    if (gated is not None and gated.held) or low_m is not None:
        track.widen_key = None
        return widening(reach, _joint_extra(extra, gated, low_m), legs_measured=legs)
    key = (unc_m, legs, extra)
    if track.widen_key != key:
        track.widen_key = key
        track.widen_m = widening(reach, extra, legs_measured=legs)
    return track.widen_m


def _stated_extra(cell: Cell, unc_m: float | None) -> float:
    """A message's stated position uncertainty beyond the parameter set's ``delta_y`` (m)."""
    return 0.0 if unc_m is None else max(unc_m - cell.params.delta_y_m, 0.0)


def _joint_extra(
    stated_m: float, gated: GateResult | None, low_m: np.ndarray | None
) -> float | np.ndarray:
    """Each joint's uncertainty beyond ``delta_y``: the stated one, plus the gate's for the
    joints it holds and the tracker's low-confidence allowance ``low_m (J,)``."""
    return stated_m + (0.0 if gated is None else gated.extra_m) + (0.0 if low_m is None else low_m)


def rewiden(cell: Cell, track: Track, params_changed: bool = True) -> None:
    """After a scenario edit (``params_changed``: of the human parameters): the widening of
    the person's newest message under the new parameters, where it is cached (nothing held or
    low). Where it is not (joints the gate holds or the tracker marks low: the message's
    extra uncertainty is not kept), infinite until the next message when the parameters
    changed. Conservative shortcut: that person's sets clear nothing for up to one message
    period (it kept the old set's widening: up to 8 mm short under a set of smaller
    ``delta_y``, hostile-user probe 2026-11-30). The legs' height bound is dropped until the
    next message (no bound is the wider set)."""
    track.state.leg_cap = None
    if track.widen_key is not None:
        unc_m, legs, _ = track.widen_key
        track.state.widen_m = _widening(cell, track, unc_m, legs, None)
    elif params_changed and track.state.widen_m is not None:
        track.state.widen_m = np.full_like(track.state.widen_m, np.inf)
