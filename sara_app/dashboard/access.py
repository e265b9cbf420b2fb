"""Who may change the cell from the 3D dashboard, and the audit of every change it makes.

The REST service's rules (:mod:`sara_app.api.guard`) hold for the dashboard too:

- With API tokens in force (``serve --require-token``, or an API reachable from other
  machines), each browser signs in with a token of the tokens file in its own "Access" panel
  (the field and the sign-in live in that browser only: viser's client-scoped GUI). Until it
  has, every change it asks for (load, save as, parameters, safety mode, gizmo drags,
  thresholds) is refused; once signed in, the change is made and recorded as the token's user.
- Without tokens (the default, loopback only) changes are open to this machine, as the API's
  are, and recorded as ``local``.
- Every change asked for, and every sign-in, is one row of the request audit
  (``GET /api/requests/audit``) with its outcome: method ``VIEW``, path
  ``/dashboard/<cell>/<action>``, status 200 (done), 401 (no credential), 422 (refused by
  validation or by the worker), 504 (no answer) or 500 (failed).

Which browser acts is viser's: a GUI callback gets the client that sent the event, and
:func:`acting` makes it the thread's current client while the callback runs (viser runs each
callback on one executor thread). An edit outside any client's event (a script calling the
bridge) has no client: it is allowed only without tokens.
"""

from __future__ import annotations

import hmac
import logging
import threading
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import Any, TypeVar

import viser

from sara_app.errors import AccessError, SaraError
from sara_app.ops.audit import AuditLog

log = logging.getLogger("sara_app.dashboard")
T = TypeVar("T")
LOCAL_USER = "local"
_current = threading.local()


@contextmanager
def acting(event: Any) -> Iterator[None]:
    """While the block runs, the thread's changes are those of ``event``'s client (a viser
    ``GuiEvent``; None or an event without a client: nobody's)."""
    previous = getattr(_current, "client_id", None)
    _current.client_id = getattr(event, "client_id", None)
    try:
        yield
    finally:
        _current.client_id = previous


def on_event(action: Callable[[], object]) -> Callable[[Any], None]:
    """A viser callback that runs ``action()`` as the event's client."""

    def handler(event: Any) -> None:
        with acting(event):
            action()

    return handler


def current_client() -> int | None:
    return getattr(_current, "client_id", None)


class DashboardAccess:
    """``DashboardAccess(tokens, cell="", audit=None)``: ``tokens`` ``{token: user}`` (None: no
    credential needed); ``audit``: the audit log or its path (None: the default one, opened at
    the first change)."""

    def __init__(
        self,
        tokens: dict[str, str] | None = None,
        cell: str = "",
        audit: AuditLog | str | Path | None = None,
    ) -> None:
        self.tokens = dict(tokens or {})
        self.required = tokens is not None
        self.cell = cell
        self._audit = audit
        self._users: dict[int, str] = {}
        self._lock = threading.Lock()

    # -- sign-in -------------------------------------------------------------------------------
    def attach(self, server: viser.ViserServer) -> None:
        """Give every browser its own "Access" folder (token field, sign in / out, who is signed
        in): a browser's own elements do not show inside a folder of the shared GUI (it stood
        there as an empty, unlabelled box)."""
        server.on_client_connect(self._add_client_gui)
        server.on_client_disconnect(lambda client: self.sign_out(client.client_id))
        for client in server.get_clients().values():
            self._add_client_gui(client)

    def _add_client_gui(self, client: viser.ClientHandle) -> None:
        with client.gui.add_folder("Access", expand_by_default=self.required):
            state = client.gui.add_markdown(self._state_text(client.client_id))
            if not self.required:
                return
            field = client.gui.add_text("API token", "")
            sign_in, sign_out = client.gui.add_button("Sign in"), client.gui.add_button("Sign out")

        def do_sign_in(_event: Any) -> None:
            user = self.sign_in(client.client_id, str(field.value))
            field.value = ""  # type: ignore[misc]  # never left on screen
            state.content = self._state_text(client.client_id, failed=user is None)

        def do_sign_out(_event: Any) -> None:
            self.sign_out(client.client_id)
            state.content = self._state_text(client.client_id)

        sign_in.on_click(do_sign_in)
        sign_out.on_click(do_sign_out)

    def _state_text(self, client_id: int, failed: bool = False) -> str:
        if not self.required:
            return f"Changes are open to this machine and recorded as `{LOCAL_USER}`."
        user = self._users.get(client_id)
        if user is not None:
            return f"Signed in as **{user}**: changes are recorded under this name."
        head = "**⚠ Unknown token.** " if failed else ""
        return head + "Read-only: sign in with an API token to change the cell."

    def sign_in(self, client_id: int, token: str) -> str | None:
        """The token's user (now this client's), or None (recorded as a refused sign-in)."""
        user = next(
            (
                u
                for t, u in self.tokens.items()
                if hmac.compare_digest(t.encode(), token.strip().encode())
            ),
            None,
        )
        with self._lock:
            if user is not None:
                self._users[client_id] = user
        self._record("sign-in", 200 if user is not None else 401, client_id, user)
        return user

    def sign_out(self, client_id: int) -> None:
        with self._lock:
            self._users.pop(client_id, None)

    def user(self, claimed: str = "") -> str:
        """The user of the acting client: its credential's user; when no credential is needed,
        the name it gives (``claimed``, free text as in the API) or ``local``;
        :class:`AccessError` when one is needed and it has none."""
        client_id = current_client()
        user = None if client_id is None else self._users.get(client_id)
        if user is not None:
            return user
        if self.required:
            raise AccessError(
                "changes from the dashboard need a credential: sign in with an API token in the "
                "Access panel"
            )
        return claimed.strip() or LOCAL_USER

    # -- audited changes -------------------------------------------------------------------------
    def require(self, action: str, claimed: str = "") -> str:
        """:meth:`user`, with a refusal recorded as ``action`` (401)."""
        try:
            return self.user(claimed)
        except AccessError:
            self._record(action, 401, current_client(), None)
            raise

    def change(
        self, action: str, fn: Callable[[], T], timeouts: tuple[type[BaseException], ...] = ()
    ) -> T:
        """Run the change ``fn()`` for the acting client if it may; one audit row whatever the
        outcome (exceptions are re-raised)."""
        if getattr(_current, "in_change", False):  # part of a change being recorded
            return fn()
        client_id = current_client()
        user = self.require(action)
        status = 500
        _current.in_change = True
        try:
            result = fn()
            status = 200
            return result
        except timeouts:
            status = 504
            raise
        except (SaraError, ValueError):
            status = 422
            raise
        finally:
            _current.in_change = False
            self._record(action, status, client_id, user)

    def audit(self) -> AuditLog:
        if not isinstance(self._audit, AuditLog):
            self._audit = AuditLog(self._audit)
        return self._audit

    def _record(self, action: str, status: int, client_id: int | None, user: str | None) -> None:
        who = "dashboard" if client_id is None else f"dashboard client {client_id}"
        try:
            self.audit().record_request(
                "VIEW", f"/dashboard/{self.cell}/{action}", status, who, user or LOCAL_USER, 0
            )
        except Exception:  # noqa: BLE001 - a failed audit row must not fail the answer
            log.exception("auditing a dashboard change failed")
