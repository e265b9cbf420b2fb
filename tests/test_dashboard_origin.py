"""The 3D view refuses a page or WebSocket handshake from another site or for another host name
(``sara_app.dashboard.origin``): a real viser server, real HTTP and WebSocket clients."""

from __future__ import annotations

import http.client
from collections.abc import Iterator

import pytest
import viser
from websockets.exceptions import InvalidStatus
from websockets.sync.client import connect

from sara_app.bus.session import free_port
from sara_app.dashboard.origin import refusal
from sara_app.dashboard.viewer import Dashboard

PROTOCOL = f"viser-v{viser.__version__}"


@pytest.fixture(scope="module")
def port() -> Iterator[int]:
    dash = Dashboard()
    dash.start(port=free_port())
    assert dash.server is not None
    try:
        yield dash.server.get_port()
    finally:
        dash.stop()


def _get(port: int, host: str) -> int:
    c = http.client.HTTPConnection("127.0.0.1", port, timeout=10)
    try:
        c.request("GET", "/", headers={"Host": host})
        return c.getresponse().status
    finally:
        c.close()


def test_pages_only_for_this_machines_names(port: int) -> None:
    assert _get(port, f"127.0.0.1:{port}") == 200
    assert _get(port, f"localhost:{port}") == 200
    assert _get(port, "evil.example") == 403  # a DNS-rebound name


def test_websocket_from_another_site_is_refused(port: int) -> None:
    uri = f"ws://127.0.0.1:{port}"
    for origin in (
        "http://evil.example", "http://127.0.0.1.evil.example:8080", "null",
        f"http://127.0.0.1:{port + 1}", "http://localhost:8000",  # another local service
    ):  # fmt: skip
        with pytest.raises(InvalidStatus) as e:
            connect(uri, origin=origin, subprotocols=[PROTOCOL], open_timeout=10)  # type: ignore[list-item,arg-type]
        assert e.value.response.status_code == 403, origin
    with connect(uri, origin=f"http://127.0.0.1:{port}", subprotocols=[PROTOCOL],  # type: ignore[list-item,arg-type]
                 open_timeout=10) as ws:  # fmt: skip
        assert ws.recv(timeout=10)  # the scene comes
    with connect(uri, subprotocols=[PROTOCOL], open_timeout=10) as ws:  # type: ignore[list-item]
        assert ws.recv(timeout=10)  # no Origin: not a browser page, Host checked


def test_refusal_rules() -> None:
    ok = {"Host": "127.0.0.1:8080", "Origin": "http://localhost:8080"}
    assert refusal(ok) is None and refusal({"Host": "[::1]:8080"}) is None
    assert refusal({"Host": "[::1]:8080", "Origin": "http://[::1]:8080"}) is None
    assert refusal({"Host": "127.0.0.1", "Origin": "http://127.0.0.1"}) is None  # port 80
    assert refusal({**ok, "Origin": "http://localhost:8000"}) is not None  # the API's page
    assert refusal({**ok, "Origin": "http://localhost"}) is not None
    assert refusal({**ok, "Origin": "ws://localhost:8080"}) is not None
    assert refusal({**ok, "Origin": "http://localhost:80x"}) is not None
    assert refusal({"Host": "evil.example:8080"}) is not None
    assert refusal({**ok, "Origin": "https://evil.example"}) is not None
    assert refusal({**ok, "Origin": "file://"}) is not None
    assert refusal({"Host": ""}) is not None
