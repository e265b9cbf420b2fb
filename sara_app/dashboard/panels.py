"""GUI panels of the dashboard: live status, model toggles, live plots, scenario editing.

The scenario tab only collects input; what an edit does is decided by the owner through three
callbacks (set them as attributes or constructor arguments):

- ``on_select_scenario(name: str)``: the "Load" button, with the dropdown's scenario name;
- ``on_save_as(name: str)``: the "Save as" button, with the typed name;
- ``on_params_edit(params: dict)``: the "Apply parameters" button, with the full (nested)
  parameter dict as last given to :meth:`DashboardPanels.set_params`, edited values in place.

A callback that raises :class:`~sara_app.errors.SaraError` or ``ValueError`` (pydantic's
``ValidationError`` is one) is reported in the tab's message area as refused; otherwise "done"
is shown. :meth:`DashboardPanels.show_message` lets the owner report later outcomes.
"""

from __future__ import annotations

import json
import time
from collections.abc import Callable
from typing import Any

import numpy as np
import viser

from sara_app.dashboard.frame import MODEL_NAMES
from sara_app.errors import SaraError

NO_SCENARIO = "(no scenarios)"
LEGEND_MD = (
    "**Robot occupancy**: green = verified, red = failsafe / unverified. "
    "With contact colours: amber = unconstrained contact, magenta = clamping against the "
    "environment, blue = clamping between robot links."
)


def _fmt(value: Any, fmt: str, unit: str = "") -> str:
    if isinstance(value, dict):
        return ", ".join(f"{k}: {_fmt(v, fmt, unit)}" for k, v in value.items()) or "none"
    try:
        x = float(value)
    except (TypeError, ValueError):
        return "n/a"
    return f"{x:{fmt}}{unit}" if np.isfinite(x) else ("inf" if x > 0 else "n/a")


def status_markdown(status: dict[str, Any]) -> str:
    """Markdown table of a frame's status dict (keys documented on ``DisplayFrame``)."""
    rows = [
        ("Mode", str(status.get("mode", "n/a"))),
        ("Safety mode", str(status.get("safety_mode", "n/a"))),
        ("Min. distance", _fmt(status.get("min_distance_m"), ".3f", " m")),
        (
            "Cycle p50 / p99",
            f"{_fmt(status.get('cycle_p50_us'), '.0f')} / "
            f"{_fmt(status.get('cycle_p99_us'), '.0f', ' us')}",
        ),
        ("Skeleton age", _fmt(status.get("skeleton_age_ms"), ".1f", " ms")),
        ("Dropped messages", _fmt(status.get("dropped"), ".0f")),
    ]
    return "| | |\n|---|---|\n" + "\n".join(f"| {k} | {v} |" for k, v in rows)


def flatten(params: dict[str, Any], prefix: str = "") -> dict[str, Any]:
    """Nested dict to ``{"a.b.c": leaf}``."""
    out: dict[str, Any] = {}
    for k, v in params.items():
        key = f"{prefix}{k}"
        if isinstance(v, dict):
            out.update(flatten(v, key + "."))
        else:
            out[key] = v
    return out


def unflatten(flat: dict[str, Any]) -> dict[str, Any]:
    """Inverse of :func:`flatten`."""
    out: dict[str, Any] = {}
    for key, v in flat.items():
        node = out
        *path, leaf = key.split(".")
        for p in path:
            node = node.setdefault(p, {})
        node[leaf] = v
    return out


class RollingSeries:
    """Time series of a fixed number of channels within a time window: ``t (n,)``,
    ``y (channels, n)``; storage of ``capacity`` samples reused (shifted when full)."""

    def __init__(self, channels: int, window_s: float, capacity: int = 2048) -> None:
        self.window_s = window_s
        self._t = np.zeros(capacity)
        self._y = np.zeros((channels, capacity))
        self._n = 0

    def append(self, t_s: float, values: np.ndarray) -> None:
        """Add one sample; non-finite samples are skipped; older than the window dropped."""
        if not (np.isfinite(t_s) and np.all(np.isfinite(values))):
            return
        if self._n and t_s < self._t[self._n - 1]:
            self._n = 0  # time went back (new run): restart the plot
        if self._n == self._t.shape[0]:
            half = self._n // 2
            self._t[:half] = self._t[self._n - half : self._n]
            self._y[:, :half] = self._y[:, self._n - half : self._n]
            self._n = half
        self._t[self._n] = t_s
        self._y[:, self._n] = values
        self._n += 1

    def data(self) -> tuple[np.ndarray, ...]:
        """``(t, y_0, y_1, ...)`` within the window ending at the last sample."""
        t = self._t[: self._n]
        i0 = int(np.searchsorted(t, t[-1] - self.window_s)) if self._n else 0
        return (t[i0:].copy(), *(y[i0 : self._n].copy() for y in self._y))


def _uplot(
    gui: viser.GuiApi, title: str, labels: tuple[str, ...], strokes: tuple[str, ...], unit: str
) -> viser.GuiUplotHandle:
    series: list[dict[str, Any]] = [{"label": "t [s]"}]
    series += [
        {"label": lab, "stroke": s, "width": 2, "scale": "y"} for lab, s in zip(labels, strokes)
    ]
    return gui.add_uplot(
        data=tuple(np.zeros(2) for _ in range(len(labels) + 1)),
        series=tuple(series),  # type: ignore[arg-type]
        title=title,
        scales={"x": {"time": False, "auto": True}, "y": {"auto": True}},
        axes=({"scale": "x"}, {"scale": "y", "label": unit}),
        aspect=1.6,
    )


class DashboardPanels:
    """The GUI of one dashboard. ``on_toggle(name, visible)`` (one checkbox per name of
    ``toggle_names``) and ``on_color_by_contact(flag)`` act on the scene; the scenario callbacks
    on the owner."""

    def __init__(
        self,
        server: viser.ViserServer,
        on_toggle: Callable[[str, bool], None],
        on_color_by_contact: Callable[[bool], None],
        window_s: float = 30.0,
        plot_period_s: float = 0.2,
        on_select_scenario: Callable[[str], None] | None = None,
        on_save_as: Callable[[str], None] | None = None,
        on_params_edit: Callable[[dict[str, Any]], None] | None = None,
        toggle_names: tuple[str, ...] = MODEL_NAMES,
    ) -> None:
        self.server = server
        self.on_select_scenario = on_select_scenario
        self.on_save_as = on_save_as
        self.on_params_edit = on_params_edit
        self.plot_period_s = plot_period_s
        self._last_plot = -np.inf
        self.min_sep = RollingSeries(1, window_s)
        self.cycle = RollingSeries(2, window_s)
        self._params: dict[str, Any] = {}
        self._param_inputs: dict[str, Any] = {}
        gui = server.gui
        tabs = gui.add_tab_group()
        with tabs.add_tab("Status"):
            self.status = gui.add_markdown(status_markdown({}))
            self.error = gui.add_markdown("", visible=False)
            with gui.add_folder("Show"):
                self.toggles = {m: gui.add_checkbox(m, True) for m in toggle_names}
            for m, box in self.toggles.items():
                _forward_toggle(box, m, on_toggle)
            self.contact_toggle = gui.add_checkbox("Colour by contact state", True)
            self.contact_toggle.on_update(lambda _e: on_color_by_contact(self.contact_toggle.value))
            gui.add_markdown(LEGEND_MD)
            self.plot_sep = _uplot(gui, "Minimum separation", ("min dist [m]",), ("green",), "m")
            self.plot_cycle = _uplot(
                gui, "Cycle time", ("p50 [us]", "p99 [us]"), ("royalblue", "crimson"), "us"
            )
        with tabs.add_tab("Scenario"):
            self._build_scenario_tab(gui)

    # ------------------------------------------------------------------------------------------
    def _build_scenario_tab(self, gui: viser.GuiApi) -> None:
        self.scenario = gui.add_dropdown("Scenario", (NO_SCENARIO,))
        gui.add_button("Load").on_click(_click(self.load_selected))
        self.save_name = gui.add_text("Save as", "")
        gui.add_button("Save as").on_click(_click(self.save_as))
        self.params_folder = gui.add_folder("Parameters")
        gui.add_button("Apply parameters").on_click(_click(self.apply_params))
        self.message = gui.add_markdown("")
        self._messages_shown = 0

    def load_selected(self) -> bool:
        """The "Load" button: ``on_select_scenario(dropdown value)``; True if accepted."""
        return self._invoke("Load", self.on_select_scenario, lambda: self.scenario.value)

    def save_as(self) -> bool:
        """The "Save as" button: ``on_save_as(typed name)``; True if accepted."""
        return self._invoke("Save", self.on_save_as, lambda: self.save_name.value.strip())

    def apply_params(self) -> bool:
        """The "Apply parameters" button: ``on_params_edit(params())``; True if accepted."""
        return self._invoke("Parameters", self.on_params_edit, self.params)

    def _invoke(
        self, what: str, callback: Callable[[Any], None] | None, arg: Callable[[], Any]
    ) -> bool:
        if callback is None:
            self.show_message(f"{what}: not available", error=True)
            return False
        shown = self._messages_shown
        try:
            callback(arg())
        except (SaraError, ValueError) as exc:
            self.show_message(f"{what} refused: {exc}", error=True)
            return False
        if self._messages_shown == shown:  # keep what the callback reported itself
            self.show_message(f"{what}: done")
        return True

    def show_message(self, text: str, error: bool = False) -> None:
        """Show ``text`` in the scenario tab (bold with a warning sign when ``error``)."""
        self.message.content = f"**⚠ {text}**" if error else text
        self._messages_shown += 1

    def set_scenarios(self, names: list[str], current: str | None = None) -> None:
        """Replace the dropdown's scenario names; select ``current`` if given."""
        options = tuple(names) or (NO_SCENARIO,)
        self.scenario.options = options
        if current in options:
            self.scenario.value = current  # type: ignore[misc]

    def set_params(self, params: dict[str, Any]) -> None:
        """Show editable inputs for ``params`` (nested dict of numbers, bools, strings, lists;
        keys must not contain '.'). Replaces the previous inputs."""
        for handle in self._param_inputs.values():
            handle.remove()
        self._params = flatten(params)
        gui = self.server.gui
        inputs: dict[str, Any] = {}
        with self.params_folder:
            for key, v in self._params.items():
                if isinstance(v, bool):
                    inputs[key] = gui.add_checkbox(key, v)
                elif isinstance(v, int | float):
                    inputs[key] = gui.add_number(key, v, step=1 if isinstance(v, int) else None)
                else:
                    text = v if isinstance(v, str) else json.dumps(v)
                    inputs[key] = gui.add_text(key, text)
        self._param_inputs = inputs

    def params(self) -> dict[str, Any]:
        """Current parameter values (nested); a list field that is not valid JSON raises
        ``ValueError`` (reported as refused)."""
        out: dict[str, Any] = {}
        for key, orig in self._params.items():
            value = self._param_inputs[key].value
            if not isinstance(orig, bool | int | float | str):
                value = json.loads(value)
            out[key] = value
        return unflatten(out)

    # ------------------------------------------------------------------------------------------
    def update(self, t_s: float, status: dict[str, Any]) -> None:
        """Refresh the status table; append to the plots, sent at most every plot period."""
        self.status.content = status_markdown(status)
        self.min_sep.append(t_s, np.array([_float(status.get("min_distance_m"))]))
        self.cycle.append(
            t_s,
            np.array([_float(status.get("cycle_p50_us")), _float(status.get("cycle_p99_us"))]),
        )
        now = time.monotonic()
        if now - self._last_plot >= self.plot_period_s:
            self._last_plot = now
            for plot, series in ((self.plot_sep, self.min_sep), (self.plot_cycle, self.cycle)):
                data = series.data()
                if data[0].shape[0] >= 2:
                    plot.data = data

    def show_error(self, text: str | None) -> None:
        """Show (or clear, with None) a rendering error under the status table."""
        self.error.visible = text is not None
        if text is not None:
            self.error.content = f"**⚠ display error:** {text}"


def _click(action: Callable[[], bool]) -> Callable[[Any], None]:
    def handler(_event: Any) -> None:
        action()

    return handler


def _forward_toggle(
    box: viser.GuiCheckboxHandle, model: str, on_toggle: Callable[[str, bool], None]
) -> None:
    box.on_update(lambda _e: on_toggle(model, box.value))


def _float(value: Any) -> float:
    try:
        return float(value)
    except (TypeError, ValueError):
        return float("nan")
