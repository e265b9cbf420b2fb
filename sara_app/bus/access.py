"""Who may say what on the bus: zenoh's own user-password authentication and access control on
the router (``transport.auth.usrpwd`` and ``access_control``), one user per role.

Roles and what they may publish (``put``) on a cell's keys; every authenticated user may
subscribe and use liveliness (reading is not restricted; the API guards what people read):

=============  =================================================================================
role           may publish
=============  =================================================================================
tracker        ``sara/<cell>/human/*/skeleton``, ``sara/<cell>/tracker/*/frame``
controller     ``sara/<cell>/robot/state``, ``sara/<cell>/controller/status``
editor         ``sara/<cell>/params``, ``sara/<cell>/retire``, ``sara/<cell>/robot/replan``
               (the API, the dashboard)
worker         the worker's outputs: ``robot/command``, ``verdict``, ``occupancy``,
               ``params/ack``, ``status``, ``scenario``, and its liveliness token
=============  =================================================================================

Every editor's request the worker answers is in the audit log, whoever sent it (the worker's
own record, :mod:`sara_app.runtime.ledger`). An editor's scenario edit that loosens what the
verdict assumes is applied only when its message says its user confirmed it
(``ParamsMsg.confirm``; the worker compares it with what it runs,
:func:`sara_app.runtime.edits.unconfirmed_loosening`).

An unauthenticated session, or one with a wrong password, cannot connect at all; an
authenticated one cannot publish outside its role (the router drops the message). The
credentials file holds ``user:password`` lines (zenoh's dictionary format), created with random
passwords (mode 0600) where there is none; processes read their role's password from it.
"""

from __future__ import annotations

import secrets
from pathlib import Path
from typing import Any

from sara_app.bus import keys
from sara_app.errors import ParameterError

ROLES: dict[str, tuple[str, ...]] = {
    "tracker": ("human/*/skeleton", "tracker/*/frame"),
    "controller": ("robot/state", "controller/status"),
    "editor": ("params", "retire", "robot/replan"),
    "worker": ("robot/command", "verdict", "occupancy", "params/ack", "status", "scenario"),
}
ROUTER_USER = "router"
_READ = [
    "declare_subscriber",
    "liveliness_query",
    "declare_liveliness_subscriber",
    "reply",
]


class Credentials:
    """The credentials file: ``password(role)``; ``Credentials.create(path)`` makes one."""

    def __init__(self, path: str | Path) -> None:
        self.path = Path(path)
        try:
            lines = self.path.read_text(encoding="utf-8").splitlines()
        except OSError as e:
            raise ParameterError(f"zenoh credentials {str(self.path)!r} unreadable: {e}") from e
        self.passwords = dict(ln.split(":", 1) for ln in lines if ":" in ln)

    @classmethod
    def create(cls, path: str | Path) -> Credentials:
        """The file at ``path``, with a random password per role (and the router's) when it
        does not exist yet."""
        p = Path(path)
        if not p.exists():
            p.parent.mkdir(parents=True, exist_ok=True)
            users = (*ROLES, ROUTER_USER)
            p.write_text("".join(f"{u}:{secrets.token_urlsafe(18)}\n" for u in users))
            p.chmod(0o600)
        return cls(p)

    def password(self, role: str) -> str:
        try:
            return self.passwords[role]
        except KeyError:
            raise ParameterError(
                f"no password for zenoh user {role!r} in {str(self.path)!r}; "
                f"users: {', '.join(sorted(self.passwords))}"
            ) from None


def router_access(cells: list[str], credentials: Credentials) -> dict[str, Any]:
    """The router's ``transport.auth`` and ``access_control`` config for ``cells``."""
    for c in cells:
        keys.check_name("cell", c)
    rules = [
        {
            "id": "read",
            "permission": "allow",
            "flows": ["ingress", "egress"],
            "messages": _READ,
            "key_exprs": [f"{keys.ROOT}/**"],
        },
        {  # what the router passes on to its sessions (samples, workers' liveliness)
            "id": "deliver",
            "permission": "allow",
            "flows": ["egress"],
            "messages": ["put", "liveliness_token"],
            "key_exprs": [f"{keys.ROOT}/**"],
        },
    ]
    for role, suffixes in ROLES.items():
        messages = ["put", "liveliness_token"] if role == "worker" else ["put"]
        rule_keys = [f"{keys.ROOT}/{c}/{s}" for c in cells for s in suffixes]
        if role == "worker":
            rule_keys += [f"{keys.ROOT}/{c}/worker/*" for c in cells]
        rules.append(
            {
                "id": f"{role}-publish",
                "permission": "allow",
                "flows": ["ingress"],
                "messages": messages,
                "key_exprs": rule_keys,
            }
        )
    subjects = [{"id": role, "usernames": [role]} for role in ROLES]
    policies = [{"rules": ["read", "deliver", f"{role}-publish"], "subjects": [role]}
                for role in ROLES]  # fmt: skip
    return {
        "transport": {
            "auth": {
                "usrpwd": {
                    "user": ROUTER_USER,
                    "password": credentials.password(ROUTER_USER),
                    "dictionary_file": str(credentials.path),
                }
            }
        },
        "access_control": {
            "enabled": True,
            "default_permission": "deny",
            "rules": rules,
            "subjects": subjects,
            "policies": policies,
        },
    }


def client_auth(role: str, credentials: Credentials) -> dict[str, Any]:
    """A client's ``transport.auth`` config for ``role``."""
    return {"auth": {"usrpwd": {"user": role, "password": credentials.password(role)}}}
