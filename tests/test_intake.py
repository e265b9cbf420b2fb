"""A person's widening after a scenario edit (``sara_app.cell.intake.rewiden``): recomputed
under the new parameters where the message's inputs are kept, infinite until the next message
where they are not (a low-confidence or gate-held joint: the old set's widening was kept, up to
8 mm short under a set of smaller ``delta_y``, hostile-user probe 2026-11-30)."""

from __future__ import annotations

import numpy as np

from sara_app.cell.build import build_cell
from sara_app.cell.intake import rewiden, take_measurement, track_for
from sara_app.human.scripted import joints, standing
from sara_app.scenario import load_scenario, parse_scenario


def _cells() -> tuple:
    """The same cell under two parameter sets of different ``delta_y``."""
    data = load_scenario("standing_beside_path").model_dump(mode="json")
    old = build_cell(parse_scenario({**data, "human_params": "work"}))
    new = build_cell(parse_scenario({**data, "human_params": "fast"}))
    assert old.params.delta_y_m != new.params.delta_y_m
    return old, new


def test_a_cached_widening_is_recomputed_under_the_new_parameters() -> None:
    old, new = _cells()
    y = joints(standing((1.2, 0.4), 0.0))
    track = track_for(old, "p")
    assert take_measurement(old, track, 1.0, y, unc_m=0.05) is None
    before = track.state.widen_m.copy()
    rewiden(new, track)
    fresh = track_for(new, "q")
    assert take_measurement(new, fresh, 1.0, y, unc_m=0.05) is None
    np.testing.assert_array_equal(track.state.widen_m, fresh.state.widen_m)
    assert not np.array_equal(before, track.state.widen_m)


def test_an_uncached_widening_is_infinite_until_the_next_message() -> None:
    old, new = _cells()
    y = joints(standing((1.2, 0.4), 0.0))
    track = track_for(old, "p")
    low = np.zeros(len(y), bool)
    low[3] = True  # one joint of low tracker confidence: the widening is not cached
    assert take_measurement(old, track, 1.0, y, unc_m=0.05, low=low) is None
    assert track.widen_key is None and np.isfinite(track.state.widen_m).any()
    kept = track.state.widen_m.copy()
    rewiden(new, track, params_changed=False)  # an edit of something else: kept
    np.testing.assert_array_equal(track.state.widen_m, kept)
    rewiden(new, track)
    assert np.isinf(track.state.widen_m).all()
    assert take_measurement(new, track, 1.01, y + 0.001, unc_m=0.05, low=low) is None
    fresh = track_for(new, "q")
    assert take_measurement(new, fresh, 1.01, y + 0.001, unc_m=0.05, low=low) is None
    np.testing.assert_array_equal(track.state.widen_m, fresh.state.widen_m)
