"""Who may change the cell from the dashboard: with tokens in force a browser changes nothing
until it signs in, each browser signs in for itself, and every change (refused ones too) is a
row of the request audit with the credential's user."""

from __future__ import annotations

import contextlib
import os
import shutil
import time
from pathlib import Path
from types import SimpleNamespace

import pytest
from browser import CHROMIUM, chromium_on, wait_for
from viser_client import ViserClient
from worker_thread import running_worker

from sara_app.bus.session import Bus, free_port
from sara_app.dashboard.access import DashboardAccess, acting
from sara_app.dashboard.bridge import CellView
from sara_app.dashboard.viewer import Dashboard
from sara_app.errors import AccessError, ScenarioError, WorkerTimeoutError
from sara_app.ops.audit import AuditLog, WorkerAnswer
from sara_app.scenario import load_scenario, scenarios_dir

TOKEN = "t0ken-of-the-operator-0123"


def _rows(audit: AuditLog) -> list[tuple[str, int, str, str]]:
    """(path, status, user, client) of the audit's requests, oldest first."""
    rows = reversed(audit.requests(100))
    return [(r["path"], r["status"], r["user"], r["client"]) for r in rows]


def test_changes_need_the_acting_browser_signed_in_and_each_is_audited(tmp_path: Path) -> None:
    audit = AuditLog(tmp_path / "a.sqlite")
    access = DashboardAccess({TOKEN: "anna"}, "c1", audit)
    one, two = SimpleNamespace(client_id=1), SimpleNamespace(client_id=2)
    with acting(one), pytest.raises(AccessError, match="sign in"):
        access.change("parameters", lambda: "changed")
    assert access.sign_in(1, "not-the-token-0123456789") is None
    assert access.sign_in(1, f" {TOKEN} ") == "anna"
    with acting(one):
        assert access.change("parameters", lambda: "changed") == "changed"
    with acting(two), pytest.raises(AccessError):  # a browser is signed in, not the other
        access.change("load", lambda: "changed")
    with pytest.raises(AccessError):  # a change outside any browser's event
        access.change("load", lambda: "changed")

    def refused() -> None:
        raise ScenarioError("refused by validation")

    def late() -> None:
        raise WorkerTimeoutError("no answer")

    def nested() -> str:  # one change made of parts is one row
        return access.change("inner", lambda: "done")

    with acting(one):
        with pytest.raises(ScenarioError):
            access.change("parameters", refused)
        with pytest.raises(WorkerTimeoutError):
            access.change("threshold", late, timeouts=(WorkerTimeoutError,))
        with pytest.raises(RuntimeError):
            access.change("box-0", lambda: (_ for _ in ()).throw(RuntimeError("bug")))
        assert access.change("waypoint-0", nested) == "done"
    access.sign_out(1)
    with acting(one), pytest.raises(AccessError):
        access.change("parameters", lambda: "changed")
    c1, c2 = "dashboard client 1", "dashboard client 2"
    assert _rows(audit) == [
        ("/dashboard/c1/parameters", 401, "local", c1),
        ("/dashboard/c1/sign-in", 401, "local", c1),
        ("/dashboard/c1/sign-in", 200, "anna", c1),
        ("/dashboard/c1/parameters", 200, "anna", c1),
        ("/dashboard/c1/load", 401, "local", c2),
        ("/dashboard/c1/load", 401, "local", "dashboard"),
        ("/dashboard/c1/parameters", 422, "anna", c1),
        ("/dashboard/c1/threshold", 504, "anna", c1),
        ("/dashboard/c1/box-0", 500, "anna", c1),
        ("/dashboard/c1/waypoint-0", 200, "anna", c1),
        ("/dashboard/c1/parameters", 401, "local", c1),
    ]


def test_without_tokens_changes_are_local_and_still_audited(tmp_path: Path) -> None:
    audit = AuditLog(tmp_path / "a.sqlite")
    access = DashboardAccess(None, "c1", audit)
    with acting(SimpleNamespace(client_id=5)):
        assert access.change("save-as", lambda: 1) == 1
    assert access.change("load", lambda: 2) == 2
    assert _rows(audit) == [
        ("/dashboard/c1/save-as", 200, "local", "dashboard client 5"),
        ("/dashboard/c1/load", 200, "local", "dashboard"),
    ]


_BUTTON = "[...document.querySelectorAll('button')].find(b => b.textContent === {!r})"
_TOKEN_INPUT = (
    "[...document.querySelectorAll('label')].find(l => l.textContent === 'API token')"
    ".closest('p').parentElement.parentElement.querySelector('input')"
)


@pytest.mark.skipif(not os.path.exists(CHROMIUM), reason=f"{CHROMIUM} is absent")
def test_a_browser_changes_the_cell_only_after_signing_in(tmp_path: Path) -> None:
    """Real browser, real viser server, real bus and worker: "Apply parameters" is refused and
    audited until the browser signs in with the token, then the worker applies it."""
    folder = tmp_path / "scenarios"
    shutil.copytree(scenarios_dir(), folder)
    sc = load_scenario("empty_cell", folder)
    audit = AuditLog(tmp_path / "audit.sqlite")
    port = free_port()
    dash = Dashboard(access=DashboardAccess({TOKEN: "operator"}, "acc1", audit))
    stack = contextlib.ExitStack()
    try:
        with Bus.router(port), Bus.client(port) as wbus, Bus.client(port) as vbus, \
                running_worker("acc1", sc, wbus, status_hz=10.0, audit=audit.path):  # fmt: skip
            view = CellView("acc1", vbus, dash, sc, folder, ack_timeout_s=20.0, audit=audit)
            url = dash.start(port=free_port(), on_params_edit=view.edit)  # as serve wires it
            view.refresh_panels()
            page = stack.enter_context(chromium_on(url))
            wait_for(lambda: page.eval("document.body.innerText.includes('Read-only')"), 30, "page")

            def scenario_tab() -> bool:  # clicked until the layout has settled
                if not page.eval(f"!!{_BUTTON.format('Apply parameters')}"):
                    page.click("document.querySelector('[role=tab][title=Scenario]')")
                    return False
                return True

            wait_for(scenario_tab, 20, "the scenario tab")

            def applied() -> list[int]:
                rows = _rows(audit)
                return [s for p, s, _, _ in rows if p == "/dashboard/acc1/parameters"]

            def revision() -> int | None:
                view.poll()
                return view.scenario_revision

            first = wait_for(revision, 30, "the worker's scenario revision")
            page.click(_BUTTON.format("Apply parameters"))
            wait_for(lambda: applied() == [401], 10, "the refused change in the audit")
            assert "sign in with an API token" in page.eval("document.body.innerText")
            time.sleep(0.5)
            assert revision() == first  # nothing reached the worker
            page.type_text(_TOKEN_INPUT, TOKEN)
            time.sleep(0.5)  # the typed value reaches the server before the click
            page.click(_BUTTON.format("Sign in"))
            wait_for(
                lambda: page.eval("document.body.innerText.includes('Signed in as')"), 10, "in"
            )
            assert page.eval(f"{_TOKEN_INPUT}.value") == ""  # the token does not stay on screen
            page.click(_BUTTON.format("Apply parameters"))
            wait_for(lambda: applied() == [401, 200], 60, "the accepted change in the audit")
            wait_for(lambda: revision() != first, 10, "the worker's new revision")
            users = {u for p, s, u, _ in _rows(audit) if s == 200}
            assert users == {"operator"}
            # the Changes tab shows the worker's own record of it, and a sender's text as text
            audit.record_worker_answers(
                [
                    WorkerAnswer(
                        time.time(),
                        "acc1",
                        "retire",
                        "x1",
                        "a|b <b>c</b>",
                        False,
                        "refused",
                        "",
                        "",
                    )
                ]
            )
            page.click("document.querySelector('[role=tab][title=Changes]')")

            def changes() -> str | None:
                view.poll()  # re-reads the rows when due
                text = str(page.eval("document.body.innerText"))
                return text if "a|b <b>c</b>" in text else None

            text = str(wait_for(changes, 20, "the Changes tab"))
            assert "operator" in text and "applied" in text, text
    finally:
        stack.close()
        dash.stop()


def test_a_client_loads_only_the_servers_own_scenarios_once_signed_in(tmp_path: Path) -> None:
    """A client that is not a browser (tests/viser_client.py) sends the "Scenario" dropdown a
    path of its choosing, which no browser offers: a JSON file holding tokens. Before signing in
    the load is refused for want of a credential; signed in, it is refused as no scenario of
    the server's; a name that climbs out of the scenarios folder too. The file is never quoted
    (it was read, and its tokens shown in the refusal, before the access check). Every attempt
    is a row of the audit; a stored scenario's name loads."""
    folder = tmp_path / "scenarios"
    shutil.copytree(scenarios_dir(), folder)
    secret = tmp_path / "secret" / "tokens.json"
    secret.parent.mkdir()
    secret.write_text('{"secret-token-of-anna-0123456789": "anna"}')
    sc = load_scenario("empty_cell", folder)
    audit = AuditLog(tmp_path / "audit.sqlite")
    port = free_port()
    dash = Dashboard(access=DashboardAccess({TOKEN: "operator"}, "acc2", audit))
    try:
        with Bus.router(port), Bus.client(port) as wbus, Bus.client(port) as vbus, \
                running_worker("acc2", sc, wbus, status_hz=10.0, audit=audit.path):  # fmt: skip
            view = CellView("acc2", vbus, dash, sc, folder, ack_timeout_s=20.0, audit=audit)
            dash.start(port=free_port(), on_select_scenario=view.select)  # as serve wires it
            view.refresh_panels()
            assert dash.server is not None and dash.panels is not None
            client = ViserClient(dash.server.get_port())
            try:
                loads: list[int] = []

                def load(name: str) -> str:
                    """The panel's answer to loading ``name`` (one more audit row; the row is
                    written before the answer is shown)."""
                    panels = dash.panels
                    assert panels is not None
                    before = panels.message.content
                    client.send("Scenario", value=name)
                    wait_for(lambda: panels.scenario.value == name, 10, "the name taken")
                    client.send("Load", value=True)
                    wait_for(lambda: len(_loads(audit)) > len(loads), 30, "the load's audit row")
                    wait_for(lambda: panels.message.content != before, 10, "the load's answer")
                    loads[:] = _loads(audit)
                    return str(panels.message.content)

                climbing = os.path.relpath(secret.with_suffix(""), folder)  # ../secret/tokens
                said = load(str(secret))
                assert "sign in" in said and "secret-token" not in said, said
                client.send("API token", value=TOKEN)
                client.send("Sign in", value=True)
                wait_for(lambda: any(p.endswith("/sign-in") and s == 200
                                     for p, s, _, _ in _rows(audit)), 10, "signed in")  # fmt: skip
                for name in (str(secret), climbing):
                    said = load(name)
                    assert "unknown scenario" in said and "secret-token" not in said, said
                    assert "empty_cell" in said  # the valid choices are named
                assert "refused" not in load("empty_cell")
                assert loads == [401, 422, 422, 200]
            finally:
                client.close()
    finally:
        dash.stop()


def _loads(audit: AuditLog) -> list[int]:
    return [s for p, s, _, _ in _rows(audit) if p.endswith("/load")]
