"""The evidence report: ``sara-app report`` writes one self-contained HTML page (no external
asset; plots embedded) with every section and the configuration checksum, and a PDF where
chromium is installed; the robot's stops are checked against a brute-force recomputation and
ISO 13855's formula against hand-computed values."""

from __future__ import annotations

import html
import os
import re
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from sara_app.cell.build import build_cell
from sara_app.cell.checksum import config_checksum
from sara_app.human.sound_record import summary
from sara_app.report.stopping import iso13855_separation_m, stop_rows
from sara_app.robot.failsafe import plan_joint_stop
from sara_app.scenario import load_scenario


def test_iso13855_separation_follows_the_standard_formula() -> None:
    # S = 2000 T + 850 mm is over 500 mm for any T: then S = 1600 T + 850 (not below 500)
    assert iso13855_separation_m(0.3) == pytest.approx(1.6 * 0.3 + 0.85)
    assert iso13855_separation_m(0.1, c_m=0.0) == pytest.approx(0.2)  # 2000 T <= 500 mm
    assert iso13855_separation_m(0.3, c_m=0.0) == pytest.approx(0.5)  # 1600 T < 500: 500 mm
    assert iso13855_separation_m(0.5, c_m=0.0) == pytest.approx(0.8)


def test_stop_rows_match_a_dense_recomputation() -> None:
    cell = build_cell(load_scenario("close_worker"))
    wps = np.asarray(cell.scenario.task.waypoints_rad)
    rows = stop_rows(cell.robot, cell.limits, wps, 0.01, 0.004)
    assert len(rows) == len(wps)
    for row, q in zip(rows, wps, strict=True):
        best_t, best_d = 0.0, 0.0
        for sign in (1.0, -1.0):
            prof = plan_joint_stop(q, sign * cell.limits.v_max, np.zeros_like(q), cell.limits)
            qs, v, _ = prof.sample(np.linspace(0.0, prof.duration_s, 4000))
            assert np.abs(v[-1]).max() < 1e-9  # at rest at the end
            ends = cell.robot.link_capsules_batch(qs)
            best_d = max(best_d, float(np.linalg.norm(np.diff(ends, axis=0), axis=-1)
                                       .sum(axis=0).max()))  # fmt: skip
            best_t = max(best_t, prof.duration_s)
        assert row.stop_time_s == pytest.approx(best_t)
        assert row.stop_distance_m == pytest.approx(best_d, abs=1e-3)
        assert row.response_time_s == pytest.approx(best_t + 0.014)
        assert row.iso_separation_m == pytest.approx(iso13855_separation_m(best_t + 0.014))


def test_report_command_writes_a_self_contained_page(tmp_path: Path) -> None:
    out, js = tmp_path / "r.html", tmp_path / "r.json"
    pdf = tmp_path / "r.pdf"
    want_pdf = os.path.exists("/usr/bin/chromium")
    cmd = [sys.executable, "-m", "sara_app.cli", "report", "close_worker", "--out", str(out),
           "--json", str(js), "--duration", "0.5", "--episodes", "1", "--modes", "ssm,pfl",
           "--audit", str(tmp_path / "none.sqlite"), "--quiet"]  # fmt: skip
    if want_pdf:
        cmd += ["--pdf", str(pdf)]
    done = subprocess.run(cmd, capture_output=True, text=True, timeout=600)
    assert done.returncode == 0, done.stderr[-2000:]
    page = out.read_text()
    checksum = config_checksum(load_scenario("close_worker"))
    assert f'id="checksum">{checksum}<' in page and checksum in done.stdout
    for title in ("1. Configuration", "2. Containment on recordings", "3. Contact energy",
                  "Audit log", "4. Robot stops and ISO 13855", "5. Closed loop per safety mode",
                  "Adversarial episodes"):  # fmt: skip
        assert title in page, title
    # self-contained: no script, stylesheet, image or link fetched from elsewhere
    assert not re.search(r"""(src|href)\s*=\s*["']?(https?:|//)""", page)
    assert "<script" not in page
    assert page.count('src="data:image/png;base64,') == 2  # containment and closed-loop plots
    assert "02_01" in page and "SSM" in page and "PFL" in page and "JSSA" not in page
    # close_worker's set bounds unmeasured legs: the report says how, and what it assumes
    assert "l_shin -0.18 m" in page and "ASSUMED for the activity" in page
    # what the set claims, in words (its left-out fits among them), and its record as written
    record = load_scenario("close_worker").param_set().sound_for
    rows = summary(record)
    assert any(what.startswith("Each recording left out") for what, _ in rows)
    for what, text in rows:
        assert f"<td>{html.escape(what)}</td><td>{html.escape(text)}</td>" in page, what
    assert "The set's record as written" in page and html.escape(record["leave_one_out"]) in page
    if want_pdf:
        assert pdf.read_bytes().startswith(b"%PDF")


def test_report_refuses_bad_input_before_writing(tmp_path: Path, capsys) -> None:
    from sara_app.cli import main

    out = tmp_path / "r.html"
    assert main(["report", "close_worker", "--out", str(out), "--modes", "ssm,fly"]) == 2
    assert "valid choices" in capsys.readouterr().err and not out.exists()
    for extra in (["--episodes", "-1"], ["--duration", "-1"], ["--duration", "nan"]):
        with pytest.raises(SystemExit) as e:  # refused by the option's type, before anything
            main(["report", "close_worker", "--out", str(out), *extra])
        assert e.value.code == 2 and not out.exists()
        assert f"argument {extra[0]}: '{extra[1]}'; expected" in capsys.readouterr().err
    assert main(["report", "no_such_cell", "--out", str(out)]) != 0
    assert "no_such_cell" in capsys.readouterr().err and not out.exists()


def test_the_report_checks_the_recording_the_cell_replays_with_its_skeleton() -> None:
    """``bench_handover`` replays the shipped TUM handover (an upper-body recording): the report
    checks it besides the CMU walk, under the set's upper-body sets (it crashed on an
    upper-body recording given with ``--recording`` before), and the set contains it."""
    from sara_app.report.evidence import Settings, gather

    ev = gather(load_scenario("bench_handover"), Settings(modes=(), episodes=0))
    rows = [r for r in ev.containment if r["recording"].startswith("HumanRobotHandover")]
    assert {r["horizon_s"] for r in rows} == {0.1, 0.3, 0.5}
    effective = [r for r in rows if r["model"] == "effective"]
    assert effective and all(r["share"] == 1.0 and r["unflagged"] == 0 for r in effective)
    assert all(r["monitor_violations"] == 0 for r in rows)
    assert {r["recording"] for r in ev.containment} >= {"02_01"}


def test_the_report_lists_what_the_worker_answered_and_marks_its_configuration(
    tmp_path: Path,
) -> None:
    """The worker's record of the requests it answered (a real audit log) in the report: each
    request with its user and outcome, the row that left this report's configuration in force
    in bold, text escaped, rows the worker could not record counted; none without a log."""
    from sara_app.ops.audit import AuditLog, WorkerAnswer
    from sara_app.report.evidence import Evidence
    from sara_app.report.html import _worker_answers

    log = AuditLog(tmp_path / "audit.sqlite")
    mine, other = "c" * 64, "d" * 64
    log.record_worker_answers([
        WorkerAnswer(1.0, "cell1", "edit", "api-1", "alice", True, "applied", "", other),
        WorkerAnswer(2.0, "cell1", "retire", "s-2", "<script>", False, "refused", "not known",
                     other),
    ], lost_before=3)  # fmt: skip
    log.record_worker_answers([WorkerAnswer(3.0, "cell1", "edit", "s-3", "bob", False,
                                            "applied", "", mine)])  # fmt: skip
    ev = Evidence("now", "here", "0", "x", mine, {}, {})
    assert _worker_answers(ev) == ""  # no audit log given
    ev.worker_answers = log.worker_answers("cell1")
    page = _worker_answers(ev)
    assert [page.index(x) for x in ("s-3", "s-2", "api-1")] == sorted(
        page.index(x) for x in ("s-3", "s-2", "api-1")
    )  # newest first
    assert f"<b>{mine[:12]}</b>" in page and f"<b>{other[:12]}</b>" not in page
    assert "&lt;script&gt;" in page and "<script>" not in page
    assert "<b>3 answered requests could not be recorded</b>" in page
    ev.worker_answers = log.worker_answers("cell2")
    assert "None recorded for this cell" in _worker_answers(ev)


def test_a_containment_row_of_nothing_checked_claims_nothing() -> None:
    """A recording whose frames lie further apart than a horizon has no future position within
    it: the row said "100 %" (contained == checked == 0), green; it says "nothing checked"."""
    from types import SimpleNamespace

    from sara_app.report.html import _containment

    row = {"recording": "sparse", "model": "vel", "horizon_s": 0.1, "checked": 0,
           "contained": 0, "share": float("nan"), "misses_per_joint": {}, "worst_m": 0.0,
           "monitor_violations": 0, "unflagged": 0}  # fmt: skip
    page = _containment(SimpleNamespace(containment=[row]))  # type: ignore[arg-type]
    assert '<span class="bad">nothing checked</span>' in page and 'class="ok"' not in page
    page = _containment(SimpleNamespace(containment=[row | {"checked": 5, "contained": 5}]))
    assert '<span class="ok">100 %</span>' in page
