"""What a client may send the 3D view: a field's new value, nothing else.

viser applies a client's GUI update to whatever properties it names (``label``, ``visible``,
``disabled``, ``options``, ...), and the server's fields are shared by every browser: a program
that speaks viser's protocol (anything on this machine, or anywhere when the view is served
beyond loopback) could relabel, hide or re-enable every operator's controls, a client that has
not signed in too (hostile-client probe, 2026-12-04: ``{"visible": false}`` on the safety-mode
dropdown hid it in every browser). viser's own page only ever sends ``{"value": ...}`` (its
``Generated.tsx``, ``Button.tsx`` and ``ButtonGroup.tsx`` in viser 1.1), so :func:`install`
drops any update that names another property before a handler sees it, and logs it.

viser 1.1 has no option for it: the filter is the first of the server's handlers of
``GuiUpdateMessage`` (a list it keeps per message type). It runs before the per-browser
fields' handlers too: viser hands each message to the server's handlers first (a task started
before the browser's) and this filter takes no await, so the message is emptied before they run.
"""

from __future__ import annotations

import logging
from typing import Any

import viser
from viser import _messages

log = logging.getLogger("sara_app.dashboard")
ALLOWED = frozenset({"value"})
"""The properties a browser sends."""


def _values_only(client_id: int, message: Any) -> None:
    names = set(getattr(message, "updates", None) or {})
    if names <= ALLOWED:
        return
    log.warning("dashboard client %s: update of %s of a field refused (a browser sends its "
                "value only)", client_id, sorted(map(str, names - ALLOWED))[:5])  # fmt: skip
    message.uuid = ""  # names no field: every handler ignores it
    message.updates = {}


def install(server: viser.ViserServer) -> None:
    """Put the filter first among ``server``'s handlers of GUI updates."""
    handlers = server._websock_server._incoming_handlers  # noqa: SLF001 - see the module notes
    handlers.setdefault(_messages.GuiUpdateMessage, []).insert(0, _values_only)  # type: ignore[arg-type]
