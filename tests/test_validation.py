"""Leave-one-recording-out validation (sara_app.human.validation): the bound-wise maximum of
single fits is the fit on all, the held-out checks count what the others' set misses, and the
derived margin makes the set fitted on all contain every recording that was left out."""

from __future__ import annotations

import numpy as np
from test_calibrate import _synthetic

from sara_app.human.analysis import EFFECTIVE, containment
from sara_app.human.calibrate import calibrate
from sara_app.human.params import load_param_set, to_reach_params
from sara_app.human.reach import HumanReach
from sara_app.human.validation import combine, leave_one_out, widened

MODELS = ("pos", "vel", "acc")


def _bounds(ps):
    return (np.array([b.v_max_mps for b in ps.joints.values()]),
            np.array([b.a_max_mps2 for b in ps.joints.values()]))  # fmt: skip


def test_the_maximum_of_single_fits_is_the_fit_on_all() -> None:
    base = load_param_set("schepp2022_table1")
    recs = [_synthetic(s) for s in (2.4, 3.0)]
    together = calibrate(base, recs, 0.2, "all")[0]
    alone = combine([calibrate(base, [r], 0.2, f"one{k}")[0] for k, r in enumerate(recs)], "x")
    for a, b in zip(_bounds(together), _bounds(alone)):
        np.testing.assert_allclose(a, b)
    assert together.arm.r_v_max_mps == alone.arm.r_v_max_mps


def test_a_faster_recording_left_out_is_missed_and_the_margin_covers_it() -> None:
    base = load_param_set("schepp2022_table1")
    recs = [_synthetic(2.2), _synthetic(2.3), _synthetic(3.2)]  # the last is faster than the rest
    val, own = leave_one_out(base, [[r] for r in recs], [f"r{k}" for k in range(3)], 0.2, MODELS)
    fast = val.rows[2]
    assert fast.contained < fast.checked and fast.v_ratio > 1.0  # the others' set misses it
    assert all(r.contained == r.checked for r in val.rows[:2])  # each slow one: covered
    mv, ma, mr = val.margin
    assert mv == max(1.0, *(r.v_ratio for r in val.rows)) and min(mv, ma, mr) >= 1.0
    for i, rec in enumerate(recs):  # widened by the margin, the others' set holds each one
        others = widened(combine([p for k, p in enumerate(own) if k != i], "o"), val.margin, "w")
        reach = HumanReach(to_reach_params(others, rec.kind))
        eff = containment(reach, rec.times_s, rec.positions_m, 0.2, MODELS)[EFFECTIVE]
        assert eff.contained == eff.checked, rec.name
