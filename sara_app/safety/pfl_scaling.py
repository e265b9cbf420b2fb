"""The PFL shield's speed scaling (:mod:`sara_app.safety.pfl_shield`): its tuning
(:class:`SpeedScaling`) and the record of what a cycle checked (:class:`PflCycle`); the path
speeds a verdict suggests are computed in the compiled check
(:func:`~sara_app.safety.pfl_kernels.speed_kernel`, ``stuck_kernel``).

Speed scaling. Link energies along the path scale with the square of the path speed (``v = q'
s'``), so a violated entry with energy ``E`` and threshold ``T`` at path speed ``s'`` suggests
the cap ``s' sqrt(T / E)``. That is a CANDIDATE only (a slower robot may lose the velocity
relaxation and meet a more severe class; its stop covers other space). A failed check is
planned again at ``cut`` times the current path speed (as SSM's scaling does: a little slower
often removes the contact altogether, the stop being shorter) and checked again, at most
``max_replans`` times per cycle. If none verifies, the robot brakes along the held failsafe
(base class) and the last check's candidate (times ``cut``, at most that speed) is kept as the
cap for the next cycle. Interval 0 starts at the current state: an entry already too
fast there cannot be fixed by a slower plan, so no replan is tried. After a verified cycle the
cap rises again: at once when no contact was possible at all, else to the speed the margins
allow (``s' sqrt(T / E)`` over the possible contacts, divided by ``hysteresis``) when that is
at least ``hysteresis`` times the cap, by at most ``raise_factor`` per cycle and only
``hold_cycles`` verified cycles after a failure. The cap never goes below ``min_speed_scale``
times the admissible speed at the robot's position: there the shield brakes instead. Nobody in
the cell: no cap. A robot at rest has no energy and always verifies (Thumm et al. 2024: a robot
at rest cannot hurt), consistent with the SSM shield.

Defaults, measured in closed loop (``sara-app pfl throughput``): a quick rise (no hold, no rate
limit) keeps PFL at least as fast as SSM, because whatever SSM verifies (no possible contact) PFL
verifies too; a slow rise (x1.25 per cycle after 10 quiet cycles) left the robot creeping after
the person had moved out of reach (standing_beside_path: 3.67 s, against 3.19 s for SSM and for
these defaults). A hysteresis above 1 (1.25 until 2026-11-28) keeps a cap that verified near its
limit where it is, and so for good in ``[allowed / 1.25, allowed)`` where clamping classes bind:
in the bench cells the robot crept at 5-10 % of its speed. Times to goal in PFL, hysteresis
1.25 -> 1.0 (2026-11-28, at most 2.5x each scenario's duration): punches never -> 16.31 s (SSM
16.32 s), bench_worker 27.56 -> 18.06 s, tracking_glitches 11.14 -> 6.39 s (SSM 7.92 s),
box_pick_place 25.82 -> 20.00 s, ur10e_close_worker 18.06 -> 16.24 s, close_worker 5.64 ->
5.55 s, standing_beside_path 11.72 -> 11.51 s, headbutt and bench_handover unchanged; no
harmful contact in any. Then the replan within a cycle at ``cut`` times the current speed
instead of at the energies' candidate (which, where a clamping class binds, jumped to a speed
at which the contact stays possible): close_worker 5.55 -> 4.90 s (SSM 4.87 s),
standing_beside_path 11.51 -> 10.96 s, bench_worker 18.06 -> 17.74 s, tracking_glitches 6.39
-> 6.27 s, ur10e_close_worker 16.24 -> 9.96 s (SSM 18.28 s), box_pick_place 20.00 -> 19.96 s,
bench_handover 9.32 -> 9.28 s, punches 16.31 s and headbutt 21.00 -> 21.04 s; a replan at
``cut`` times the current speed for the held cap as well lost 1.8 s in punches. The price of
both is more replans (punches: 1 091 -> 3 592 in 8 000 cycles; at
most ``1 + max_replans`` = 2 checks per cycle and ``model_budget(people)`` model evaluations
over them (``max_models``, fewer with more than two people: ``max_person_models``):
the worst cycle is bounded, a cycle that runs out brakes as after a failed check). A replan cut
of 0.95 or two replans per cycle moved these times by -1.5 to +0.8 s, and a second replan at
the energies' candidate after the one at the current speed lost 1.2 s in close_worker: not
taken.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

from sara_app.errors import ParameterError
from sara_app.safety.pfl import PflResult

__all__ = ["PflCycle", "SpeedScaling"]


@dataclass(frozen=True)
class PflCycle:
    """What the PFL shield checked this cycle: ``result`` (merged over the models: each entry
    from the first model that proves it safe, an unproved one with the highest threshold seen;
    ``result.contact`` is the first model's; None when nobody is in the cell), ``cap`` the
    path-speed cap of the checked trajectory (rad/s, inf: none), ``speed_scale`` that cap over
    the admissible speed at the robot (<= 1), ``checks`` the PFL checks run (1 + replans),
    ``models_used`` how many models the last check evaluated, ``evaluations`` how many model
    evaluations the cycle's checks made in all (at most ``SpeedScaling.max_models``)."""

    result: PflResult | None
    cap: float
    speed_scale: float
    checks: int
    models_used: int
    evaluations: int = 0


@dataclass
class SpeedScaling:
    """Tuning of the speed scaling (see the module notes for the measurements behind the
    defaults)."""

    cut: float = 0.9
    """A replan's cap is this fraction of the candidate (and of the current speed at most)."""
    hysteresis: float = 1.0
    """Raise only when the margins allow this many times the cap, to the allowed speed over it.
    1.25 (the earlier default) left the cap for good in ``[allowed / 1.25, allowed)``, where
    clamping classes bind: the robot crept at 5-10 % of its speed (punches never reached its
    goal in 50 s, SSM 16.3 s); 1.0 goes straight to the margins' speed and lets the replan
    correct an overshoot (measured in the module notes)."""
    raise_factor: float = math.inf
    """Largest raise per cycle (inf: straight to what the margins allow)."""
    hold_cycles: int = 0
    """Verified cycles after a failure before the cap may rise."""
    free_jump: bool = True
    """No possible contact in a verified trajectory: lift the cap at once."""
    max_replans: int = 1
    """Replans per cycle after a failed check (each one PFL check more)."""
    max_models: int = 6
    """Model evaluations (classifications, the main cost of a check) per cycle, over all its
    checks. When they run out, the check counts as failed with what it proved (conservative:
    the robot brakes on the held failsafe, the candidate is the next cycle's cap) and no replan
    follows. Bounds the worst cycle (2 checks x 4 models = 8 otherwise). With the shipped four
    models (acc, vel, pos, combined) 4 left no replan after a full first check: close_worker
    took 4.52 s (braking SSM 4.30 s); 6 gives 4.24 s and no other shipped scenario slower
    (docs/measurements/2026-11-26-sound-sets.md); with three models 4 and 6 gave the same
    times to goal."""

    max_person_models: int = 16
    """Model evaluations times people per cycle: with more than ``max_person_models //
    max_models`` people the cycle evaluates fewer models (at least one), because a
    classification's cost grows with the people it classifies (about 50-100 µs per evaluation
    with 4 people, the pairs between people included). 16 keeps 6 evaluations for up to 2
    people, 5 for 3 and 4 for 4: PFL braking with 4 people took 1.11 ms median, 1.34 ms p99
    with 6 and takes 0.77 / 0.91 ms with 4 (2026-11-28, ``sara-app bench``), within a 1 kHz
    loop. Fewer evaluations are conservative (fewer entries proved: the robot slows or brakes
    sooner); a single person keeps 6, as the shipped scenarios measured above."""

    def __post_init__(self) -> None:
        if self.max_models < 1 or self.max_replans < 0 or self.max_person_models < 1:
            raise ParameterError(
                f"max_models = {self.max_models}, max_replans = {self.max_replans}, "
                f"max_person_models = {self.max_person_models}; expected max_models >= 1, "
                "max_replans >= 0 and max_person_models >= 1"
            )

    def model_budget(self, people: int) -> int:
        """Model evaluations a cycle with ``people`` people may make (>= 1)."""
        return max(1, min(self.max_models, self.max_person_models // max(people, 1)))
