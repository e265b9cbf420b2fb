"""View settings per browser: which human sets and scene layers each browser shows.

Every browser that connects gets its own "View (this browser)" folder and its own copies of
the scene's ``/view/<name>`` frames (viser's client-side nodes shadow the shared ones of the
same name), so unticking a set in one browser hides it there only. The shared scene is told
which parts *any* browser shows (:meth:`CellScene.set_visible
<sara_app.dashboard.scene.CellScene.set_visible>`): a part nobody shows costs nothing per frame.
A new browser starts from :data:`~sara_app.dashboard.scene.DEFAULT_VISIBLE`.
"""

from __future__ import annotations

import threading
from collections.abc import Callable
from dataclasses import dataclass, field

import viser

from sara_app.dashboard.frame import EFFECTIVE, MODEL_NAMES
from sara_app.dashboard.scene import DEFAULT_VISIBLE, VIEW_NAMES, view_node

CHECKBOXES: tuple[tuple[str, str], ...] = (
    (EFFECTIVE, "Effective set (what the verdict uses)"),
    *((m, f"Model: {m}") for m in MODEL_NAMES if m != EFFECTIVE),
    ("robot", "Robot"),
    ("occupancy", "Robot occupancy"),
    ("skeletons", "Skeletons"),
    ("contacts", "Body parts in contact"),
    ("boxes", "Environment boxes"),
    ("critical_pair", "JSSA critical pair"),
)
"""The folder's checkboxes: view name (``occupancy`` stands for both occupancy colourings) and
label."""
BY_CONTACT = "Colour occupancy by contact class"
ORDER = 1000.0
"""The folder's place in the control panel: below the shared tabs."""


@dataclass
class _Browser:
    frames: dict[str, viser.FrameHandle]
    boxes: dict[str, viser.GuiCheckboxHandle] = field(default_factory=dict)
    by_contact: viser.GuiCheckboxHandle | None = None

    def shows(self) -> dict[str, bool]:
        """What this browser shows, per view name."""
        out = {name: bool(box.value) for name, box in self.boxes.items()}
        occupancy = out.pop("occupancy", True)
        contact = self.by_contact is None or bool(self.by_contact.value)
        out["occupancy"] = occupancy and not contact
        out["occupancy_contact"] = occupancy and contact
        return out


class BrowserViews:
    """The per-browser view settings of one viser server; ``set_shown(name, any_browser)``
    receives what any browser shows (the scene's :meth:`set_visible`)."""

    def __init__(self, server: viser.ViserServer, set_shown: Callable[[str, bool], None]) -> None:
        self.server, self.set_shown = server, set_shown
        self._browsers: dict[int, _Browser] = {}
        self._lock = threading.Lock()
        self._demand = dict(DEFAULT_VISIBLE)
        server.on_client_connect(self._connect)
        server.on_client_disconnect(self._disconnect)

    def shows(self, client_id: int) -> dict[str, bool]:
        """What the browser ``client_id`` shows (a :class:`KeyError` for an unknown one)."""
        with self._lock:
            return self._browsers[client_id].shows()

    def _connect(self, client: viser.ClientHandle) -> None:
        frames = {
            name: client.scene.add_frame(
                view_node(name), show_axes=False, visible=DEFAULT_VISIBLE[name]
            )
            for name in VIEW_NAMES
        }
        b = _Browser(frames)
        with client.gui.add_folder("View (this browser)", order=ORDER):
            for name, label in CHECKBOXES:
                initial = DEFAULT_VISIBLE[name] or (
                    name == "occupancy" and DEFAULT_VISIBLE["occupancy_contact"]
                )
                b.boxes[name] = client.gui.add_checkbox(label, initial)
            b.by_contact = client.gui.add_checkbox(BY_CONTACT, DEFAULT_VISIBLE["occupancy_contact"])
        for box in (*b.boxes.values(), b.by_contact):
            box.on_update(self._on_change(b))
        with self._lock:
            self._browsers[client.client_id] = b
        self._changed(b)

    def _on_change(self, b: _Browser) -> Callable[[object], None]:
        return lambda _event: self._changed(b)

    def _disconnect(self, client: viser.ClientHandle) -> None:
        with self._lock:
            self._browsers.pop(client.client_id, None)
        self._publish()

    def _changed(self, b: _Browser) -> None:
        for name, shown in b.shows().items():
            b.frames[name].visible = shown
        self._publish()

    def _publish(self) -> None:
        """Tell the scene what any browser shows (with none connected: the defaults)."""
        with self._lock:
            views = [b.shows() for b in self._browsers.values()]
        demand = (
            {name: any(v[name] for v in views) for name in VIEW_NAMES}
            if views
            else dict(DEFAULT_VISIBLE)
        )
        for name, shown in demand.items():
            if self._demand.get(name) != shown:
                self.set_shown(name, shown)
        self._demand = demand
