"""Serve an ASGI app with uvicorn in a background thread (next to viser in one process).

``ApiServer(app, host='127.0.0.1', port=8000)``; ``start() -> url`` returns the real address
(``port=0`` picks a free one) and raises ``ApiServerError`` when uvicorn did not start within
``start_timeout_s`` (port taken: uvicorn's thread dies at start-up, reported at once; the
timeout only ends a start that hangs: ``serve`` starts the API from its display side, niced below
the cell's real-time processes, so on a loaded machine binding can take many seconds (5 s was
once not enough for ``serve --cells 2`` beside a test suite)); ``stop()`` ends open event
streams, asks uvicorn to exit and joins its thread. Usable as a context manager.
"""

from __future__ import annotations

import threading
import time
from typing import Any

import uvicorn

from sara_app.errors import SaraError


class ApiServerError(SaraError):
    """The HTTP server could not start (port in use, bad host) or stop."""


class ApiServer:
    """uvicorn serving ``app`` on ``host:port`` from a daemon thread."""

    def __init__(
        self, app: Any, host: str = "127.0.0.1", port: int = 8000, start_timeout_s: float = 60.0
    ) -> None:
        if not isinstance(port, int) or not 0 <= port < 65536:
            raise ApiServerError(f"api port {port!r} is not in 0..65535")
        self.app, self.host, self.port = app, host, port
        self.start_timeout_s = float(start_timeout_s)
        self.url: str | None = None
        self._server: uvicorn.Server | None = None
        self._thread: threading.Thread | None = None

    def start(self) -> str:
        """Start serving; the URL (``http://host:port/``) once uvicorn listens."""
        if self.url is not None:
            return self.url
        stopping = self._stopping()
        if stopping is not None:
            stopping.clear()
        config = uvicorn.Config(
            self.app,
            host=self.host,
            port=self.port,
            log_config=None,  # leave the process's logging alone
            log_level="warning",
            access_log=False,
            timeout_graceful_shutdown=1,
        )
        server = uvicorn.Server(config)
        thread = threading.Thread(
            target=self._serve, args=(server,), name="sara-api-uvicorn", daemon=True
        )
        thread.start()
        deadline = time.monotonic() + self.start_timeout_s
        while not server.started and thread.is_alive() and time.monotonic() < deadline:
            time.sleep(0.01)
        if not server.started:
            server.should_exit = True
            thread.join(timeout=2.0)
            why = "it exited at start-up (port in use?)" if not thread.is_alive() else "timeout"
            raise ApiServerError(
                f"the API server did not start on http://{self.host}:{self.port}/: {why}"
            )
        self._server, self._thread = server, thread
        port = self.port
        for s in server.servers:
            for sock in s.sockets:
                port = int(sock.getsockname()[1])
        self.url = f"http://{self.host}:{port}/"
        return self.url

    def _stopping(self) -> threading.Event | None:
        """``create_app``'s event that ends open event streams (None for other apps)."""
        ev = getattr(getattr(self.app, "state", None), "stopping", None)
        return ev if isinstance(ev, threading.Event) else None

    @staticmethod
    def _serve(server: uvicorn.Server) -> None:
        try:
            server.run()
        except SystemExit:  # uvicorn exits at start-up when it cannot bind; start() reports it
            pass

    def stop(self) -> None:
        """End event streams, stop uvicorn and join its thread (idempotent)."""
        stopping = self._stopping()
        if stopping is not None:
            stopping.set()
        if self._server is not None:
            self._server.should_exit = True
        if self._thread is not None:
            self._thread.join(timeout=5.0)
            if self._thread.is_alive():
                raise ApiServerError("the API server thread did not stop within 5 s")
        self._server = self._thread = None
        self.url = None

    def __enter__(self) -> ApiServer:
        self.start()
        return self

    def __exit__(self, *exc: object) -> None:
        self.stop()
