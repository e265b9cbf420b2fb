"""The dashboard: one viser server with the cell scene and the GUI panels.

Usage (the owner converts bus messages into :class:`DisplayFrame` and calls ``update``)::

    dash = Dashboard(robot="panda")
    url = dash.start()            # 127.0.0.1; the port may move up if 8080 is taken
    dash.panels.on_save_as = ...  # scenario callbacks, see sara_app.dashboard.panels
    dash.update(frame)            # 20+ Hz
    dash.stop()
"""

from __future__ import annotations

import logging
from typing import Any

import numpy as np
import viser

from sara_app.dashboard import client_input, origin
from sara_app.dashboard.access import DashboardAccess
from sara_app.dashboard.frame import DisplayFrame
from sara_app.dashboard.panels import DashboardPanels
from sara_app.dashboard.scene import CellScene
from sara_app.dashboard.view import BrowserViews
from sara_app.errors import InputError, SaraError

log = logging.getLogger(__name__)


class Dashboard:
    """Server + scene + panels. Nothing runs before :meth:`start`."""

    def __init__(
        self,
        robot: str = "panda",
        T_world_base: np.ndarray | None = None,
        camera_position: tuple[float, float, float] = (1.9, -1.9, 1.6),
        camera_look_at: tuple[float, float, float] = (0.4, 0.0, 0.6),
        access: DashboardAccess | None = None,
    ) -> None:
        """``access``: who may change the cell from this dashboard (default: anyone on this
        machine, as ``local``; see :mod:`sara_app.dashboard.access`)."""
        self.robot, self.T_world_base = robot, T_world_base
        self.access = access if access is not None else DashboardAccess()
        self.camera = (camera_position, camera_look_at)
        self.server: viser.ViserServer | None = None
        self.scene: CellScene | None = None
        self.panels: DashboardPanels | None = None
        self.views: BrowserViews | None = None
        self.url: str | None = None
        self.frames_rejected = 0

    def start(self, host: str = "127.0.0.1", port: int = 8080, **callbacks: Any) -> str:
        """Start serving and return the real URL (viser moves to the next free port if
        ``port`` is taken). ``callbacks``: ``on_select_scenario``, ``on_save_as``,
        ``on_params_edit``, ``on_set_mode``, ``on_replan`` (see
        :mod:`sara_app.dashboard.panels`)."""
        if self.server is not None:
            raise InputError(f"dashboard already serving at {self.url}; call stop() first")
        origin.install()  # foreign Host / Origin refused (cross-site WebSocket hijacking)
        origin.allow_host(host)
        server = viser.ViserServer(host=host, port=port, label="SaRA cell", verbose=False)
        try:
            client_input.install(server)  # a client sets a field's value, nothing else
            server.initial_camera.position = self.camera[0]
            server.initial_camera.look_at = self.camera[1]
            server.gui.configure_theme(control_width="large")  # room for the tables
            self.access.attach(server)
            scene = CellScene(server, self.robot, self.T_world_base)
            self.panels = DashboardPanels(server, **callbacks)
            self.views = BrowserViews(server, scene.set_visible)
        except BaseException:
            server.stop()
            raise
        self.server, self.scene = server, scene
        self.url = f"http://{host}:{server.get_port()}"
        return self.url

    def update(self, frame: DisplayFrame) -> bool:
        """Render ``frame``; False (and a visible, logged message) if it was malformed."""
        if self.scene is None or self.panels is None:
            raise InputError("dashboard is not started; call start() first")
        try:
            self.scene.update(frame)
        except SaraError as exc:
            self.frames_rejected += 1
            log.warning("display frame rejected: %s", exc)
            self.panels.show_error(f"{exc} ({self.frames_rejected} frames rejected)")
            return False
        self.panels.update(frame.t_s, frame.status, frame.links)
        return True

    def client_count(self) -> int:
        """Connected browsers."""
        return 0 if self.server is None else len(self.server.get_clients())

    def stop(self) -> None:
        """Stop serving (idempotent)."""
        if self.server is not None:
            self.server.stop()
        self.server = self.scene = self.panels = self.views = None
        self.url = None
