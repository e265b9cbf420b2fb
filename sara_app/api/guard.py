"""The REST service's front door (an ASGI middleware around the FastAPI app):

- **Host check** (against DNS rebinding): a request whose ``Host`` header is not one the service
  answers to (``127.0.0.1``, ``localhost``, ``[::1]`` and the names given) is refused (421).
- **Size limit**: a request body over ``MAX_BODY_BYTES`` is refused (413) before it is read in
  full (a stated ``Content-Length`` at once, a streamed body as soon as it passes the limit).
- **Credentials**: with ``require_token`` (always when the service listens on anything but
  loopback), a mutating request (POST, PUT, PATCH, DELETE) needs ``Authorization: Bearer
  <token>`` with a token of the tokens file. Read-only routes stay open.
- **One user per request**: the token's user, or ``local`` without a valid token
  (:func:`request_user`); every audit row of the request (this request log, the threshold and
  people audits) records that one name, never a name in the body.
- **Audit**: every mutating request is recorded with its outcome (status), refused ones
  included (401, 413, 421, 422, ...).

Tokens file: a JSON object ``{"<token>": "<user>"}`` (``serve --require-token`` creates one with
a random token for user ``operator`` in the data folder when there is none, and says where).
"""

from __future__ import annotations

import hmac
import json
import logging
import secrets
from collections.abc import Callable
from pathlib import Path
from typing import Any

from sara_app.errors import ParameterError
from sara_app.ops.audit import AuditLog

log = logging.getLogger("sara_app.api")
MAX_BODY_BYTES = 1024 * 1024
MUTATING = frozenset({"POST", "PUT", "PATCH", "DELETE"})
LOOPBACK_NAMES = ("127.0.0.1", "localhost", "[::1]")
LOCAL_USER = "local"
"""The user of a request without a valid token (a service without tokens on loopback)."""


MAX_USER_CHARS = 64
"""The longest user name a token may carry: what a bus message records (``RetireMsg.user``)."""


def load_tokens(path: str | Path, create: bool = False) -> dict[str, str]:
    """``{token: user}`` from a tokens file; with ``create``, a new file with one random token
    for user ``operator`` when there is none. ParameterError when it cannot be used."""
    p = Path(path)
    if create and not p.exists():
        p.parent.mkdir(parents=True, exist_ok=True)
        p.write_text(json.dumps({secrets.token_urlsafe(24): "operator"}, indent=1) + "\n")
        p.chmod(0o600)
    try:
        data = json.loads(p.read_text(encoding="utf-8"))
    except (OSError, ValueError) as e:
        raise ParameterError(f"API tokens file {str(p)!r} cannot be read: {e}") from None
    if (
        not isinstance(data, dict)
        or not data
        or not all(
            isinstance(k, str) and len(k) >= 16 and isinstance(v, str) and v
            for k, v in data.items()
        )
    ):
        raise ParameterError(
            f"API tokens file {str(p)!r}: expected a JSON object of tokens (16 characters or "
            "more) to user names"
        )
    long = [u for u in data.values() if len(u) > MAX_USER_CHARS]
    if long:  # every audit row and bus message records the user whole (hostile-user probe)
        raise ParameterError(
            f"API tokens file {str(p)!r}: user name {long[0][:40]!r}... has {len(long[0])} "
            f"characters; at most {MAX_USER_CHARS}"
        )
    return data


class Guard:
    """ASGI middleware: ``Guard(app, audit, tokens=None, require_token=False, hosts=())``;
    ``audit()`` returns the audit log (opened lazily)."""

    def __init__(
        self,
        app: Any,
        audit: Callable[[], AuditLog],
        *,
        tokens: dict[str, str] | None = None,
        require_token: bool = False,
        hosts: tuple[str, ...] = (),
    ) -> None:
        if require_token and not tokens:
            raise ParameterError("require_token needs at least one token")
        self.app, self.audit = app, audit
        self.tokens = dict(tokens or {})
        self.require_token = require_token
        self.hosts = frozenset(LOOPBACK_NAMES) | frozenset(hosts)

    async def __call__(self, scope: dict, receive: Any, send: Any) -> None:
        if scope["type"] != "http":
            await self.app(scope, receive, send)
            return
        headers = {k.decode("latin-1").lower(): v.decode("latin-1") for k, v in scope["headers"]}
        method = scope["method"]
        status: list[int] = [0]
        size = [0]
        user = self._user(headers.get("authorization", ""))
        scope.setdefault("state", {})["auth_user"] = user

        over = [False]  # the streamed body passed the limit

        async def send_status(message: dict) -> None:
            if over[0]:  # the app's answer to a body cut short (400): the 413 is sent instead
                return
            if message["type"] == "http.response.start":
                status[0] = message["status"]
            await send(message)

        refusal = self._refusal(headers, method, user)
        if refusal is not None:
            await _reply(send_status, *refusal)
        else:

            async def counted() -> dict:
                message = await receive()
                size[0] += len(message.get("body", b""))
                if size[0] > MAX_BODY_BYTES:
                    if status[0] == 0:  # nothing answered yet: the answer is 413
                        over[0], status[0] = True, 413
                        await _reply(send, 413, f"request body over {MAX_BODY_BYTES} bytes")
                    raise _TooLarge()
                return message

            try:
                await self.app(scope, counted, send_status)
            except _TooLarge:
                pass  # answered in counted (FastAPI's body parser may also swallow it)
        if method in MUTATING:
            self._record(scope, method, status[0], user, size[0] or _length(headers))

    def _user(self, authorization: str) -> str | None:
        scheme, _, token = authorization.partition(" ")
        if scheme.lower() != "bearer" or not token:
            return None
        for known, user in self.tokens.items():
            if hmac.compare_digest(known.encode(), token.strip().encode()):
                return user
        return None

    def _refusal(self, headers: dict[str, str], method: str, user: str | None) -> tuple | None:
        host = headers.get("host", "")
        name = host.rsplit(":", 1)[0] if not host.startswith("[") else host.split("]")[0] + "]"
        if name not in self.hosts:
            return 421, f"host {host[:100]!r} is not served here; use 127.0.0.1"
        if _length(headers) > MAX_BODY_BYTES:
            return 413, f"request body over {MAX_BODY_BYTES} bytes"
        if method in MUTATING and self.require_token and user is None:
            return 401, "this service needs 'Authorization: Bearer <token>' for changes"
        return None

    def _record(self, scope: dict, method: str, status: int, user: str | None, size: int) -> None:
        client = scope.get("client") or ("", 0)
        try:
            self.audit().record_request(
                method, scope.get("path", ""), status, str(client[0]), user or LOCAL_USER, size
            )
        except Exception:  # noqa: BLE001 - a failed audit row must not fail the answer
            log.exception("auditing a request failed")


class _TooLarge(Exception):
    pass


def _length(headers: dict[str, str]) -> int:
    try:
        return int(headers.get("content-length", "0"))
    except ValueError:
        return 0


async def _reply(send: Any, status: int, detail: str) -> None:
    body = json.dumps({"detail": detail}).encode()
    await send(
        {
            "type": "http.response.start",
            "status": status,
            "headers": [
                (b"content-type", b"application/json"),
                (b"content-length", b"%d" % len(body)),
            ],
        }
    )
    await send({"type": "http.response.body", "body": body})


def credential_user(request: Any) -> str | None:
    """The user of the request's valid token (None: no token, or not checked)."""
    state = request.scope.get("state") or {}
    return state.get("auth_user")


def request_user(request: Any) -> str:
    """Who makes the request, as every audit row of it records it: the token's user, else
    :data:`LOCAL_USER` (the same name the request log gives it)."""
    return credential_user(request) or LOCAL_USER
