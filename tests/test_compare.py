"""The SSM / PFL / JSSA comparison (``sara_app.sim.compare``, ``sara-app compare``) at small
size."""

from __future__ import annotations

import numpy as np
import pytest

from sara_app.cli import main
from sara_app.scenario import load_scenario, parse_scenario
from sara_app.sim.compare import _Recorder, compare, format_table, run_mode, with_mode


class _Line:
    """A motion source: joints at ``y0 + v t + a t^2 / 2`` (15 joints)."""

    def __init__(self, v: float, a: float) -> None:
        self.v, self.a = v, a

    def pose(self, t: float, robot_ends: np.ndarray, robot_radius: np.ndarray) -> np.ndarray:
        x = self.v * t + 0.5 * self.a * t * t
        return np.tile([x, 0.0, 1.0], (15, 1))


def test_recorder_measures_true_joint_acceleration() -> None:
    none = np.zeros((0, 2, 3))
    for a in (0.0, 2.0):
        rec = _Recorder(_Line(0.7, a))
        for k in range(50):
            rec.pose(k * 0.004, none, np.zeros(0))
        assert rec.max_acc(0.1) == pytest.approx(a, abs=1e-6)
    assert _Recorder(_Line(1.0, 5.0)).max_acc(0.1) == 0.0  # nothing recorded yet


def test_with_mode_replaces_only_the_mode() -> None:
    sc = load_scenario("punches")
    j = with_mode(sc, "jssa")
    assert j.shield.mode == "jssa" and sc.shield.mode == "ssm"
    assert j.model_dump(exclude={"shield"}) == sc.model_dump(exclude={"shield"})


def test_table_over_two_scenarios_and_the_modes() -> None:
    rows = compare(["empty_cell", "punches"], ("ssm", "pfl", "jssa"), duration_s=0.6)
    assert [(r.scenario, r.mode) for r in rows] == [
        (s, m) for s in ("empty_cell", "punches") for m in ("ssm", "pfl", "jssa")
    ]
    for r in rows:
        if r.error:  # a mode that cannot be built is reported, not raised
            assert r.mode == "pfl"
            continue
        assert r.cycles == round(0.6 / load_scenario(r.scenario).shield.dt_s)
        assert 0.0 <= r.intervened_share <= 1.0
        assert r.collisions_moving == 0 and r.fault_cycles == 0 and r.harmful_contacts == 0
        assert r.metrics is not None and r.metrics.safety_mode == r.mode
        assert (r.below_d_min is None) == (r.mode != "jssa")
        if r.below_d_min is not None:
            assert r.below_d_min == r.below_broken + r.below_kept
        if r.scenario == "empty_cell":
            assert np.isinf(r.min_sep_moving_m) and r.intervened_share == 0.0
        else:
            assert np.isfinite(r.min_sep_moving_m)
    text = format_table(rows)
    assert len(text.splitlines()) == 2 + len(rows) + 1
    assert "punches" in text and "jssa" in text


def test_jssa_steps_below_d_min_are_split_by_the_assumption(monkeypatch) -> None:
    """A JSSA blind to people (d_min 0.5 m) runs close to them: its steps below d_min are all
    counted, as broken near the punching person (accelerating limbs) and as kept next to the
    person standing still."""
    from sara_app.safety.jssa import JssaController
    from sara_app.scenario import parse_scenario

    step = JssaController.step

    def blind(self, q, qd, qdd, u, ends, radius, vel, dt, *rest):
        return step(self, q, qd, qdd, u, ends[:0], radius[:0], vel[:0], dt)

    monkeypatch.setattr(JssaController, "step", blind)
    for name, horizon_s in (("punches", 2.5), ("standing_beside_path", 2.0)):
        data = with_mode(load_scenario(name), "jssa").model_dump(mode="json")
        data["shield"]["jssa"]["d_min_m"] = 0.5
        row = run_mode(parse_scenario(data), "jssa", duration_s=horizon_s)
        assert row.below_d_min is not None and row.below_d_min > 0
        if name == "punches":
            assert row.below_broken is not None and row.below_broken > 0
        else:
            assert row.below_broken == 0 and row.below_kept == row.below_d_min


def test_command_prints_the_table_and_rejects_unknown_names(capsys) -> None:
    rc = main(
        ["compare", "--scenarios", "empty_cell", "--modes", "jssa", "--duration", "0.1", "--quiet"]
    )
    assert rc == 0
    out = capsys.readouterr().out
    assert "empty_cell" in out and "jssa" in out
    assert main(["compare", "--scenarios", "nowhere", "--quiet"]) == 2
    assert main(["compare", "--modes", "magic", "--quiet"]) == 2


def test_pfl_throughput_is_the_comparison_of_ssm_and_pfl(capsys) -> None:
    rc = main(["pfl", "throughput", "empty_cell", "--duration", "0.1", "--quiet"])
    assert rc == 0
    lines = capsys.readouterr().out.splitlines()
    assert "harm" in lines[0]
    assert [ln.split()[:2] for ln in lines[2:4]] == [["empty_cell", "ssm"], ["empty_cell", "pfl"]]
    assert main(["pfl", "throughput", "nowhere", "--quiet"]) == 2


def test_with_mode_drops_the_models_the_mode_cannot_verify_with() -> None:
    data = load_scenario("punches").model_dump(mode="json")
    data["shield"]["models"] = ["arm", "vel"]
    sc = parse_scenario(data)
    assert with_mode(sc, "pfl").shield.models == ["vel"]  # PFL has no arm model
    assert with_mode(sc, "ssm").shield.models == ["arm", "vel"]
    data["shield"]["models"] = ["arm"]
    assert with_mode(parse_scenario(data), "pfl").shield.models == ["vel"]
