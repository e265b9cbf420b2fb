"""The 3D view's front door: a request (page or WebSocket handshake) whose ``Host`` or
``Origin`` is not this machine (or the name the view is served on) is refused with 403.

Why: a browser lets any web page open a WebSocket to ``ws://127.0.0.1:8080``; the dashboard
takes edits over it, so without this check a page open in the operator's browser could drive
the cell's dashboard (cross-site WebSocket hijacking), and a DNS-rebound name could read it; the
REST service refuses foreign ``Host`` headers (:mod:`sara_app.api.guard`), the view did not
(hostile-user probe, 2026-11-30: ``Origin: http://evil.example`` got the scene). A client
without an ``Origin`` header (not a browser page) is checked on ``Host`` only.

viser 1.1 has no option for it: :func:`install` gives the ``websockets`` server that viser starts
a ``process_request`` that checks first and then hands over to viser's own (its file server).
"""

from __future__ import annotations

import http
import threading
from typing import Any
from urllib.parse import urlsplit

import websockets.asyncio.server as ws_server

LOOPBACK_NAMES = ("127.0.0.1", "localhost", "[::1]", "::1")
_allowed: set[str] = set(LOOPBACK_NAMES)
_lock = threading.Lock()
_original_serve = ws_server.serve


def allow_host(name: str) -> None:
    """Also answer requests for host ``name`` (the address a view is served on)."""
    if name not in ("", "0.0.0.0", "::"):  # a wildcard bind: still this machine's names only
        with _lock:
            _allowed.add(name)


def _host_name(netloc: str) -> str:
    """``netloc`` (``host[:port]``, ``[v6][:port]``) without its port, lower case."""
    netloc = netloc.strip().lower()
    if netloc.startswith("["):
        return netloc.split("]", 1)[0] + "]"
    return netloc.rsplit(":", 1)[0] if netloc.count(":") == 1 else netloc


def _port(netloc: str, default: int) -> int | None:
    """The port of ``netloc`` (``default`` when none is given; None when it is not a port)."""
    rest = netloc.rsplit("]", 1)[-1] if netloc.startswith("[") else netloc
    if ":" not in rest:
        return default
    text = rest.rsplit(":", 1)[1]
    return int(text) if text.isdigit() else None


def refusal(headers: Any) -> str | None:
    """Why a request with ``headers`` is refused (None: it is not): a ``Host`` that is not
    this machine's, or an ``Origin`` that is not this view's own page (the same name and port:
    a page of another local service, e.g. on port 8000 or a developer's server, is another
    site too)."""
    raw_host = headers.get("Host", "")
    host = _host_name(raw_host)
    if host not in _allowed:
        return f"host {host[:100]!r} is not served here; use 127.0.0.1"
    origin = headers.get("Origin")
    if origin is not None:
        parts = urlsplit(origin) if "://" in origin else None
        if (
            parts is None
            or parts.scheme not in ("http", "https")
            or _host_name(parts.netloc) not in _allowed
            or _port(parts.netloc, 443 if parts.scheme == "https" else 80) != _port(raw_host, 80)
        ):
            return f"origin {origin[:100]!r} may not use this view"
    return None


def _guarded_serve(*args: Any, process_request: Any = None, **kwargs: Any) -> Any:
    def check(connection: Any, request: Any) -> Any:
        why = refusal(request.headers)
        if why is not None:
            return connection.respond(http.HTTPStatus.FORBIDDEN, why + "\n")
        return None if process_request is None else process_request(connection, request)

    return _original_serve(*args, process_request=check, **kwargs)


def install() -> None:
    """Check every view started from now on in this process (idempotent). Replaces the
    ``serve`` of ``websockets.asyncio.server``, the one viser calls; the dashboard's process
    serves no other WebSocket server."""
    ws_server.serve = _guarded_serve  # type: ignore[assignment,misc]
