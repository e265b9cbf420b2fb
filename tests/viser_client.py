"""A viser client that is not a browser, for the tests that try the dashboard as a hostile user
would: it connects as a page of the view's own origin (what a script on the operator's machine
can do), reads which GUI fields viser sent it, and sends field values that no browser sends,
such as a number beyond the field's bounds (viser checks them only in the browser)."""

from __future__ import annotations

import time
from typing import Any

import msgspec
import viser
import zstandard
from websockets.sync.client import connect


def _messages(frame: bytes) -> list[dict[str, Any]]:
    """The messages of one frame viser's server sent: ``[8 bytes: msgpack length][8 bytes:
    compressed length][zstd msgpack]...`` (viser's ``_message_producer``)."""
    n_inner = int.from_bytes(frame[:8], "little")
    n_comp = int.from_bytes(frame[8:16], "little")
    inner = zstandard.ZstdDecompressor().decompress(frame[16 : 16 + n_comp], n_inner)
    return list(msgspec.msgpack.decode(inner)["messages"])


class ViserClient:
    """One websocket to a viser server at ``port`` on 127.0.0.1; :meth:`field` finds a GUI
    field by its label, :meth:`send` sets its properties as a browser's edit would."""

    def __init__(self, port: int) -> None:
        self.ws = connect(
            f"ws://127.0.0.1:{port}", origin=f"http://127.0.0.1:{port}",
            subprotocols=[f"viser-v{viser.__version__}"], max_size=None, open_timeout=10,
        )  # type: ignore[list-item]  # fmt: skip
        self.fields: dict[str, str] = {}
        """label -> uuid of every GUI field sent so far."""
        # viser counts a client as connected (and builds its per-browser fields) on its first
        # camera message, which a browser sends as soon as its view is drawn
        camera = {"type": "ViewerCameraMessage", "wxyz": (1.0, 0.0, 0.0, 0.0),
                  "position": (2.0, -2.0, 1.5), "fov": 1.0, "near": 0.01, "far": 100.0,
                  "image_height": 600, "image_width": 800, "look_at": (0.0, 0.0, 0.5),
                  "up_direction": (0.0, 0.0, 1.0)}  # fmt: skip
        self.ws.send(msgspec.msgpack.encode(camera))

    def field(self, label: str, timeout_s: float = 30.0) -> str:
        """The uuid of the GUI field labelled ``label``, reading what the server sends until
        it comes."""
        t_end = time.monotonic() + timeout_s
        while label not in self.fields:
            if time.monotonic() > t_end:
                raise AssertionError(f"no GUI field {label!r} within {timeout_s} s")
            try:
                frame = self.ws.recv(timeout=0.5)
            except TimeoutError:
                continue
            for m in _messages(frame if isinstance(frame, bytes) else frame.encode()):
                props = m.get("props")
                if str(m.get("type", "")).startswith("Gui") and isinstance(props, dict):
                    if "uuid" in m and "label" in props:
                        self.fields[str(props["label"])] = str(m["uuid"])
        return self.fields[label]

    def send(self, label: str, /, **updates: Any) -> None:
        """Set properties of the field ``label`` (``value=True`` clicks a button; a browser
        sends nothing else)."""
        msg = {"type": "GuiUpdateMessage", "uuid": self.field(label), "updates": updates}
        self.ws.send(msgspec.msgpack.encode(msg))

    def close(self) -> None:
        self.ws.close()
