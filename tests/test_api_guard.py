"""The REST service's front door: Host check (DNS rebinding), body size limit, tokens for
changes (the user is the token's), and every mutating request audited, refused ones included."""

from __future__ import annotations

import json
import warnings
from pathlib import Path

import pytest

with warnings.catch_warnings():
    warnings.filterwarnings("ignore", message=".*httpx.*deprecated")
    from fastapi.testclient import TestClient

from api_stand_ins import AnsweringRegistry

from sara_app.api import CellRegistry, create_app
from sara_app.api.guard import MAX_BODY_BYTES, load_tokens
from sara_app.errors import ParameterError
from sara_app.ops.audit import AuditLog

TOKEN = "t" * 24


def _client(tmp_path: Path, registry: CellRegistry | None = None, **kw) -> TestClient:
    reg = registry if registry is not None else CellRegistry(None)
    app = create_app(reg, audit=AuditLog(tmp_path / "audit.sqlite"), **kw)
    return TestClient(app)


def test_foreign_host_large_body_and_missing_token_are_refused_and_audited(
    tmp_path: Path,
) -> None:
    c = _client(tmp_path, tokens={TOKEN: "anna"}, require_token=True)
    assert c.get("/api/health").status_code == 200  # reading needs no token
    r = c.get("/api/health", headers={"host": "evil.example:8000"})
    assert r.status_code == 421  # a rebound DNS name
    r = c.put("/api/scenarios/x", content=b"{}", headers={"content-type": "application/json"})
    assert r.status_code == 401  # a change without a token
    big = b'{"name": "' + b"x" * (MAX_BODY_BYTES + 10) + b'"}'
    auth = {"authorization": f"Bearer {TOKEN}", "content-type": "application/json"}
    r = c.put("/api/scenarios/big", content=big, headers=auth)
    assert r.status_code == 413
    chunks = (b"x" * 65536 for _ in range(MAX_BODY_BYTES // 65536 + 2))  # no Content-Length
    r = c.put("/api/scenarios/big", content=chunks, headers=auth)
    assert r.status_code == 413 and "over" in r.json()["detail"]  # not FastAPI's 400
    r = c.put("/api/scenarios/x", content=b"{not json", headers=auth)
    assert r.status_code == 422  # refused by validation: audited too
    rows = c.get("/api/requests/audit").json()
    assert [(x["method"], x["status"], x["user"]) for x in rows] == [
        ("PUT", 422, "anna"),
        ("PUT", 413, "anna"),
        ("PUT", 413, "anna"),
        ("PUT", 401, "local"),
    ]
    assert rows[1]["body_bytes"] > MAX_BODY_BYTES and rows[2]["body_bytes"] > MAX_BODY_BYTES


def test_the_token_names_the_user_in_the_threshold_audit(tmp_path: Path) -> None:
    """Without a cell the edit fails (404), but the request row carries the token's user."""
    c = _client(tmp_path, tokens={TOKEN: "anna"})
    body = {"region": "hand", "contact": "constrained", "shape": "blunt", "energy_J": 0.2,
            "user": "mallory"}  # fmt: skip
    r = c.put("/api/cells/c1/thresholds", json=body, headers={"authorization": f"Bearer {TOKEN}"})
    assert r.status_code == 404
    assert c.get("/api/requests/audit").json()[0]["user"] == "anna"


@pytest.mark.parametrize("token", [TOKEN, None])
def test_every_audit_row_of_a_request_names_the_same_user(
    tmp_path: Path, token: str | None
) -> None:
    """A threshold edit and a retire naming "mallory" in the body: the threshold audit, the
    people audit, the worker's retire request and the request log all name the request's user,
    the token's ("anna"), or "local" without a token."""
    reg = AnsweringRegistry()
    reg.status("c1", "empty_cell")
    c = _client(tmp_path, tokens={TOKEN: "anna"}, registry=reg)
    headers = {"authorization": f"Bearer {token}"} if token else {}
    want = "anna" if token else "local"
    edit = {"region": "hand", "contact": "constrained", "shape": "blunt", "energy_J": 0.1,
            "user": "mallory"}  # fmt: skip
    assert c.put("/api/cells/c1/thresholds", json=edit, headers=headers).status_code == 200
    retire = {"user": "mallory", "reason": "tracker replaced"}
    r = c.post("/api/cells/c1/humans/h1/retire", json=retire, headers=headers)
    assert r.status_code == 200, r.text
    assert [x["user"] for x in c.get("/api/cells/c1/thresholds/audit").json()] == [want]
    assert [x["user"] for x in c.get("/api/cells/c1/humans/audit").json()] == [want]
    assert reg.retired_by == [want]
    assert [x["user"] for x in c.get("/api/requests/audit").json()] == [want, want]


def test_tokens_file(tmp_path: Path) -> None:
    made = load_tokens(tmp_path / "tokens.json", create=True)
    assert list(made.values()) == ["operator"] and len(next(iter(made))) >= 16
    assert load_tokens(tmp_path / "tokens.json") == made
    (tmp_path / "bad.json").write_text(json.dumps({"short": "x"}))
    with pytest.raises(ParameterError, match="16 characters"):
        load_tokens(tmp_path / "bad.json")
    (tmp_path / "long.json").write_text(json.dumps({"t" * 16: "u" * 65}))
    with pytest.raises(ParameterError, match="65 characters; at most 64"):
        load_tokens(tmp_path / "long.json")  # a user an audit row or bus message cannot hold
    with pytest.raises(ParameterError):
        create_app(CellRegistry(None), audit=AuditLog(tmp_path / "a.sqlite"), require_token=True)
