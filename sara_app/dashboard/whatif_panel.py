"""What-if runs and the evidence report from the dashboard, per browser.

Each browser gets a "What-if and evidence report" folder of its own: the safety engineer edits
parameters in the Scenario tab (and may pick another safety mode here), runs them offline
beside the settings in force (a background job, :mod:`sara_app.ops.jobs`: never in the worker, at
the lowest CPU priority), follows a progress bar, reads both runs side by side, scrubs through
the edited run as a translucent ghost robot and skeletons drawn in this browser only, and
applies the edit with one more click (through the same validated, audited path as "Apply
parameters"). "Evidence report" makes the report of the scenario in force and downloads it.
"""

from __future__ import annotations

import logging
import threading
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import viser
import yourdfpy
from viser.extras import ViserUrdf

from sara_app.dashboard.access import on_event
from sara_app.dashboard.from_messages import BONES
from sara_app.dashboard.panels import CONFIRM_LABEL
from sara_app.dashboard.view import ORDER
from sara_app.errors import SaraError
from sara_app.ops.jobs import Job, JobRunner
from sara_app.ops.loosening import LooseningRefusedError
from sara_app.robot.model import urdf_path
from sara_app.sim.whatif_table import table_markdown

log = logging.getLogger("sara_app.dashboard")
MODES = ("as edited", "SSM", "PFL", "JSSA")
PEOPLE = ("as edited", "recording 02_01 (CMU walk)")
"""Who is in the what-if: the scenario's people, or them replaced by a shipped recording."""
WALKER = {"id": "walker", "type": "recording", "recording": "02_01", "offset_m": [0.9, 0.0, 0.0],
          "start_s": 1.0}  # fmt: skip
"""The recorded walk passing the cell (as the shipped ``cmu_walk`` scenario places it)."""
POLL_S = 0.3
GHOST_RGBA = (0.25, 0.45, 1.0, 0.45)
INTRO = (
    "Edit parameters in the **Scenario** tab, then run them offline beside the settings in "
    "force (nothing reaches the robot)."
)


@dataclass
class WhatIfHooks:
    """What the panel needs from the cell's view: ``edited(mode)`` the scenario in force with
    the Scenario tab's parameters (and ``mode``, or None) as a dict (``SaraError`` if
    invalid); ``current()`` the scenario in force as a dict; ``apply(data)`` sends a scenario
    through the validated, audited edit path (``apply(data, confirm)``: an edit that loosens
    what the verdict assumes only with ``confirm``); ``audit_path`` for the report."""

    current: Callable[[], dict[str, Any]]
    edited: Callable[[str | None], dict[str, Any]]
    apply: Callable[[dict[str, Any], bool], None]
    cell: str
    robot: str
    T_world_base: np.ndarray
    audit_path: Path | None = None


@dataclass
class _Browser:
    client: viser.ClientHandle
    gui: dict[str, Any] = field(default_factory=dict)
    job: Job | None = None
    edited: dict[str, Any] | None = None
    frames: list[dict[str, Any]] = field(default_factory=list)
    ghost: ViserUrdf | None = None
    root: Any = None


class WhatIfPanels:
    def __init__(self, server: viser.ViserServer, jobs: JobRunner, hooks: WhatIfHooks) -> None:
        self.server, self.jobs, self.hooks = server, jobs, hooks
        self._browsers: dict[int, _Browser] = {}
        self._lock = threading.Lock()
        self._stop = threading.Event()
        server.on_client_connect(self._connect)
        server.on_client_disconnect(self._disconnect)
        for client in server.get_clients().values():
            self._connect(client)
        threading.Thread(target=self._follow, daemon=True, name="whatif-follow").start()

    def close(self) -> None:
        self._stop.set()

    # -- building ----------------------------------------------------------------------------
    def _connect(self, client: viser.ClientHandle) -> None:
        b = _Browser(client)
        g, gui = b.gui, client.gui
        with gui.add_folder("What-if and evidence report", order=ORDER + 1,
                            expand_by_default=False):  # fmt: skip
            gui.add_markdown(INTRO)
            g["mode"] = gui.add_dropdown("Safety mode", MODES, initial_value=MODES[0])
            g["people"] = gui.add_dropdown("People", PEOPLE, initial_value=PEOPLE[0])
            g["duration"] = gui.add_number("Duration (s)", 10.0, min=1.0, max=60.0, step=1.0)
            g["run"] = gui.add_button("Run what-if")
            g["progress"] = gui.add_progress_bar(0.0, visible=False, animated=True)
            g["status"] = gui.add_markdown("")
            g["table"] = gui.add_markdown("")
            g["scrub"] = gui.add_slider("Edited run at (s)", 0.0, 1.0, 0.04, 0.0, disabled=True)
            g["ghost"] = gui.add_checkbox("Show it in the 3D view", False, disabled=True)
            g["confirm"] = gui.add_checkbox(CONFIRM_LABEL, False, visible=False)
            g["apply"] = gui.add_button("Apply the edit to the cell", disabled=True)
            g["report"] = gui.add_button("Evidence report (download)")
        g["run"].on_click(on_event(lambda: self._run(b)))
        g["apply"].on_click(on_event(lambda: self._apply(b)))
        g["report"].on_click(on_event(lambda: self._report(b)))
        g["scrub"].on_update(lambda _e: self._show(b))
        g["ghost"].on_update(lambda _e: self._show(b))
        with self._lock:
            self._browsers[client.client_id] = b

    def _disconnect(self, client: viser.ClientHandle) -> None:
        with self._lock:
            self._browsers.pop(client.client_id, None)

    # -- actions -----------------------------------------------------------------------------
    def _start(self, b: _Browser, kind: str, data: dict[str, Any], label: str) -> None:
        try:
            b.job = self.jobs.start(kind, data, label)
        except SaraError as e:
            b.gui["status"].content = f"**Not started**: {e}"
            return
        b.gui["progress"].value = 0.0
        b.gui["progress"].visible = True
        b.gui["status"].content = f"{label}: starting"

    def _run(self, b: _Browser) -> None:
        mode = str(b.gui["mode"].value)
        try:
            edited = self.hooks.edited(None if mode == MODES[0] else mode.lower())
        except (SaraError, ValueError) as e:
            b.gui["status"].content = f"**Not started**: the edit is invalid: {e}"
            return
        if str(b.gui["people"].value) != PEOPLE[0]:
            edited = {**edited, "humans": [dict(WALKER)]}
        b.edited, b.frames = edited, []
        for name in ("scrub", "ghost", "apply"):
            b.gui[name].disabled = True
        b.gui["table"].content = ""
        data = {"current": self.hooks.current(), "edited": edited,
                "duration_s": float(b.gui["duration"].value)}  # fmt: skip
        self._start(b, "whatif", data, "What-if")

    def _report(self, b: _Browser) -> None:
        audit = self.hooks.audit_path
        settings = {"cell": self.hooks.cell, "episodes": 3,
                    "audit_path": None if audit is None else str(audit)}  # fmt: skip
        self._start(b, "report", {"scenario": self.hooks.current(), "settings": settings},
                    "Evidence report")  # fmt: skip

    def _apply(self, b: _Browser) -> None:
        if b.edited is None:
            return
        try:
            self.hooks.apply(b.edited, bool(b.gui["confirm"].value))
        except LooseningRefusedError as e:
            b.gui["status"].content = f"**Not applied**: {e}"
            b.gui["confirm"].visible = True  # the engineer confirms, then applies again
            return
        except SaraError as e:
            b.gui["status"].content = f"**Not applied**: {e}"
            return
        b.gui["status"].content = "Applied: the cell runs the edited settings."
        b.gui["apply"].disabled = True
        b.gui["confirm"].value = False
        b.gui["confirm"].visible = False

    # -- following the job -------------------------------------------------------------------
    def _follow(self) -> None:
        while not self._stop.wait(POLL_S):
            with self._lock:
                browsers = list(self._browsers.values())
            for b in browsers:
                try:
                    self._update(b)
                except Exception as e:  # noqa: BLE001 - one browser's panel, never the rest
                    log.warning("what-if panel: %r", e)

    def _update(self, b: _Browser) -> None:
        job = b.job
        if job is None:
            return
        g = b.gui
        if job.state == "running":
            g["progress"].value = round(100.0 * job.progress, 1)
            g["status"].content = f"{job.label}: {job.what} ({100 * job.progress:.0f} %)"
            return
        b.job = None
        g["progress"].visible = False
        if job.state == "failed":
            g["status"].content = f"**{job.label} failed**: {job.error}"
            return
        if job.kind == "report":
            page = job.output.read_bytes()
            b.client.send_file_download(f"{self.hooks.cell}-evidence.html", page)
            g[
                "status"
            ].content = f"Evidence report downloaded (checksum {job.result()['checksum']})"
            return
        res = job.result()
        b.frames = res["edited"].get("frames", [])
        g["table"].content = table_markdown(res)
        g["status"].content = "What-if done: scrub through the edited run, or apply it."
        if b.frames:
            g["scrub"].max = b.frames[-1]["t_s"]
            g["scrub"].disabled = False
            g["ghost"].disabled = False
        g["apply"].disabled = False

    def _show(self, b: _Browser) -> None:
        """Draw (or hide) the edited run at the slider's time in this browser only."""
        on = bool(b.gui["ghost"].value) and bool(b.frames)
        if not on:
            if b.root is not None:
                b.root.visible = False
            return
        t = float(b.gui["scrub"].value)
        f = min(b.frames, key=lambda fr: abs(fr["t_s"] - t))
        scene = b.client.scene
        if b.root is None:
            T = self.hooks.T_world_base
            b.root = scene.add_frame("/whatif", show_axes=False)
            scene.add_frame("/whatif/base", position=T[:3, 3], show_axes=False,
                            wxyz=viser.transforms.SO3.from_matrix(T[:3, :3]).wxyz)  # fmt: skip
            urdf = yourdfpy.URDF.load(str(urdf_path(self.hooks.robot)))
            b.ghost = ViserUrdf(b.client, urdf, root_node_name="/whatif/base",
                                mesh_color_override=GHOST_RGBA)  # fmt: skip
        b.root.visible = True
        if b.ghost is not None:
            b.ghost.update_cfg(np.asarray(f["q"]))
        segs = [np.asarray(y)[BONES] for y in f["humans"]]
        if segs:
            scene.add_line_segments("/whatif/skeletons", np.concatenate(segs), (40, 90, 255),
                                    thickness=0.02)  # fmt: skip
