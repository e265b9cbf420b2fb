"""The shipped set ``bench_assembly`` (light work at a bench: bolts, screws, stacking, handovers):
the effective set of the scenarios' models contains the recordings it was fitted to, with the
conformance monitor quiet on them, and the monitor faults a person whose work is beyond it
(TUM's forceful hammering: a wrist at 7 m/s)."""

from __future__ import annotations

import pytest

from sara_app.human.analysis import EFFECTIVE
from sara_app.human.failures import Ceilings, split
from sara_app.human.intake import screen_recording
from sara_app.human.params import load_param_set, to_reach_params
from sara_app.human.recording import Recording
from sara_app.human.recordings import load_recording, shared_data_dir
from sara_app.human.validation import containment_on
from sara_app.scenario import load_scenario

MODELS = ("acc", "vel", "pos", "combined")
FITTED = ("62_01", "62_02", "62_04", "62_05", "62_06") + tuple(
    f"{task}/{i}" for task, n in (("CollaborativeStacking", 4), ("HumanRobotHandover", 6))
    for i in range(n)
)  # fmt: skip


def _pieces(name: str) -> list[Recording]:
    """The recording without its reconstruction failures (the ceilings the set was fitted with)."""
    ps = load_param_set("bench_assembly")
    return split(load_recording(name), Ceilings(8.0, 400.0), ps.delta_y_m)[0]


def _need_data() -> None:
    try:
        shared_data_dir()
    except Exception:  # noqa: BLE001 - RecordingError: no data folder on this machine
        pytest.skip("data folder not found")


def _check(name: str, horizon_s: float) -> tuple[int, int, int, int]:
    """``(checked, contained, unflagged, faulted frames)`` of the recording's pieces under the
    shipped set: the effective set of ``MODELS`` at ``horizon_s``."""
    counts, faulted = containment_on(load_param_set("bench_assembly"), _pieces(name), horizon_s,
                                     MODELS)  # fmt: skip
    return (*counts[EFFECTIVE], faulted)


def _faulted_frames(name: str) -> int:
    """Frames of the recording's pieces the conformance monitor faults under the shipped set."""
    ps = load_param_set("bench_assembly")
    return sum(int(screen_recording(to_reach_params(ps, r.kind), r).faulted.sum())
               for r in _pieces(name))  # fmt: skip


def test_the_scenarios_of_light_work_run_on_it() -> None:
    for name in ("close_worker", "standing_beside_path", "ur10e_close_worker", "bench_handover"):
        sc = load_scenario(name)
        assert sc.human_params == "bench_assembly", name
        assert set(sc.shield.models) == set(MODELS), name


@pytest.mark.parametrize("horizon_s", [0.1, 0.2, 0.5])
def test_the_shipped_handover_is_contained_with_the_monitor_quiet(horizon_s: float) -> None:
    """HumanRobotHandover/0 ships in the package (the ``bench_handover`` scenarios)."""
    checked, contained, unflagged, faulted = _check("HumanRobotHandover/0", horizon_s)
    assert checked > 10_000 and contained == checked and unflagged == 0 and faulted == 0


def test_every_recording_it_was_fitted_to_is_contained() -> None:
    """The 15 recordings (with the data folder), 0.2 s: every future position inside the
    effective set, no frame faulted."""
    _need_data()
    for name in FITTED:
        checked, contained, _, faulted = _check(name, 0.2)
        assert checked > 0 and contained == checked and faulted == 0, (name, checked, contained)


@pytest.mark.parametrize("name", ["CollaborativeHammering/0", "PickPlaceCloseHuman/1"])
def test_work_beyond_it_is_faulted_by_the_monitor(name: str) -> None:
    """Forceful hammering (a wrist at 7.2 m/s) and a fast reach while picking (7.5 m/s) are
    beyond the set: the monitor faults the person (the robot then stays on its failsafe)."""
    _need_data()
    assert _faulted_frames(name) > 0
