"""GUI panels of the dashboard: live status, model toggles, live plots, scenario editing.

The scenario tab only collects input; what an edit does is decided by the owner through three
callbacks (set them as attributes or constructor arguments):

- ``on_select_scenario(name: str)``: the "Load" button, with the dropdown's scenario name;
- ``on_save_as(name: str)``: the "Save as" button, with the typed name;
- ``on_params_edit(params: dict)``: the "Apply parameters" button, with the full (nested)
  parameter dict as last given to :meth:`DashboardPanels.set_params`, edited values in place;
- ``on_set_mode(mode: str)``: the status tab's safety-mode dropdown (``'ssm'``, ``'pfl'`` or
  ``'jssa'``); on refusal the dropdown goes back to the last accepted mode;
- ``on_replan(q_rad: list[float])``: the status tab's "Plan from where the robot stands", with
  the joint positions the tab shows (where the controller reports the robot).

A callback that raises :class:`~sara_app.errors.SaraError` or ``ValueError`` (pydantic's
``ValidationError`` is one) is reported in the tab's message area as refused; otherwise "done"
is shown. :meth:`DashboardPanels.show_message` lets the owner report later outcomes.
"""

from __future__ import annotations

import json
import math
import time
from collections.abc import Callable
from typing import Any

import numpy as np
import viser

from sara_app.dashboard.access import on_event
from sara_app.dashboard.frame import LinkEnergy
from sara_app.dashboard.human_set_text import human_set_markdown
from sara_app.dashboard.status_text import (
    LEGEND_MD,
    as_float,
    banner_html,
    link_energy_markdown,
    robot_q_markdown,
    status_markdown,
)
from sara_app.dashboard.tracking_text import md_cell, totals_markdown
from sara_app.errors import SaraError
from sara_app.safety.settings import MODE_FACTS, SAFETY_MODES

NO_SCENARIO = "(no scenarios)"
CONFIRM_LABEL = "Confirm loosening"
"""The box that confirms an edit loosening what the verdict assumes
(:mod:`sara_app.ops.loosening`): in the Scenario tab, and in the what-if folder once one is
refused there."""
CONFIRM_HOW = f"tick '{CONFIRM_LABEL}' and apply again"
REPLAN_LABEL = "Plan from where the robot stands"


def flatten(params: dict[str, Any], prefix: str = "") -> dict[str, Any]:
    """Nested dict to ``{"a.b.c": leaf}`` (an empty dict is a leaf); a non-empty list of
    objects (the people, the boxes) is flattened item by item as ``"humans[0].position_m"``, so
    each field gets its own input."""
    out: dict[str, Any] = {}
    for k, v in params.items():
        key = f"{prefix}{k}"
        if isinstance(v, dict) and v:
            out.update(flatten(v, key + "."))
        elif isinstance(v, list) and v and all(isinstance(x, dict) for x in v):
            for i, item in enumerate(v):
                out.update(flatten(item, f"{key}[{i}]."))
        else:
            out[key] = v
    return out


def unflatten(flat: dict[str, Any]) -> dict[str, Any]:
    """Inverse of :func:`flatten`."""
    out: dict[str, Any] = {}
    for key, v in flat.items():
        node: Any = out
        *path, leaf = key.split(".")
        for p in path:
            name, _, index = p.partition("[")
            if index:  # "humans[0]": item 0 of the list "humans"
                items = node.setdefault(name, [])
                i = int(index.rstrip("]"))
                while len(items) <= i:
                    items.append({})
                node = items[i]
            else:
                node = node.setdefault(p, {})
        node[leaf] = v
    return out


def _integral(value: float) -> int | float:
    """An integer field's value: its integer when it is a whole finite number, else the number
    as it is (the scenario's validation refuses it and names the field)."""
    return int(value) if math.isfinite(value) and float(value).is_integer() else value


def _is_vector(v: Any, n: int) -> bool:
    return (isinstance(v, list | tuple) and len(v) == n
            and all(isinstance(x, int | float) and not isinstance(x, bool) for x in v))  # fmt: skip


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

    def plot_data(self) -> tuple[np.ndarray, ...]:
        """As :meth:`data` with times in seconds relative to the newest sample (``<= 0``): an
        axis a person reads ("2 s ago"), not Unix time."""
        t, *ys = self.data()
        return (t - t[-1] if t.shape[0] else t, *ys)


def _uplot(
    gui: viser.GuiApi, title: str, labels: tuple[str, ...], strokes: tuple[str, ...], unit: str
) -> viser.GuiUplotHandle:
    series: list[dict[str, Any]] = [{"label": "t - now [s]"}]
    series += [
        {"label": lab, "stroke": s, "width": 2, "scale": "y"} for lab, s in zip(labels, strokes)
    ]
    return gui.add_uplot(
        data=tuple(np.zeros(2) for _ in range(len(labels) + 1)),
        series=tuple(series),  # type: ignore[arg-type]
        title=title,
        scales={"x": {"time": False, "auto": True}, "y": {"auto": True}},
        axes=({"scale": "x", "label": "seconds before now"}, {"scale": "y", "label": unit}),
        aspect=1.6,
    )


class DashboardPanels:
    """The shared GUI of one dashboard (status, plots, scenario, thresholds); the scenario
    callbacks act on the owner. What each browser shows is its own
    (:mod:`sara_app.dashboard.view`)."""

    def __init__(
        self,
        server: viser.ViserServer,
        window_s: float = 30.0,
        plot_period_s: float = 0.2,
        on_select_scenario: Callable[[str], None] | None = None,
        on_save_as: Callable[[str], None] | None = None,
        on_params_edit: Callable[[dict[str, Any]], None] | None = None,
        on_set_mode: Callable[[str], None] | None = None,
        on_replan: Callable[[list[float]], None] | None = None,
    ) -> None:
        self.server = server
        self.on_select_scenario = on_select_scenario
        self.on_save_as = on_save_as
        self.on_params_edit = on_params_edit
        self.on_set_mode = on_set_mode
        self.on_replan = on_replan
        self._robot_q_shown: list[float] | None = None
        self._mode = "ssm"
        self._syncing = False
        self._shown_mode: str | None = None
        self._links_md = ""
        self.plot_period_s = plot_period_s
        self._last_plot = -np.inf
        self.min_sep = RollingSeries(1, window_s)
        self.cycle = RollingSeries(2, window_s)
        self.phi = RollingSeries(1, window_s)
        self.speed = RollingSeries(1, window_s)
        self._params: dict[str, Any] = {}
        self._param_inputs: dict[str, Any] = {}
        gui = server.gui
        self._banner_html = ""
        self.banner = gui.add_html(banner_html({}))  # the verdict in words, above the tabs
        self.tabs = tabs = gui.add_tab_group()
        with tabs.add_tab("Status"):
            self.safety_mode = gui.add_dropdown(
                "Safety mode", tuple(m.upper() for m in SAFETY_MODES), initial_value="SSM"
            )
            self.safety_mode.on_update(on_event(self._mode_selected))
            self.mode_message = gui.add_markdown("")
            self.status = gui.add_markdown(status_markdown({}))
            self.error = gui.add_markdown("", visible=False)
            self.links_folder = gui.add_folder("PFL: link energies and thresholds")
            with self.links_folder:
                self.links = gui.add_markdown(link_energy_markdown([]))
            with gui.add_folder("Tracking flag totals", expand_by_default=False):
                self.totals = gui.add_markdown(totals_markdown({}))
            with gui.add_folder("Robot position", expand_by_default=False):
                self.robot_q = gui.add_markdown(robot_q_markdown(None))
                gui.add_button(
                    REPLAN_LABEL,
                    hint="After a protective stop or hand guiding moved the robot away from "
                    "the plan (a tracking fault): confirms the position shown; the cell plans "
                    "from there only if the robot stands there at rest. Recorded in the audit "
                    "log",
                ).on_click(on_event(self.replan))
                self.replan_message = gui.add_markdown("")
            gui.add_markdown(LEGEND_MD)
            self.plot_sep = _uplot(gui, "Minimum separation", ("min dist [m]",), ("green",), "m")
            self.plot_cycle = _uplot(
                gui, "Cycle time", ("p50 [us]", "p99 [us]"), ("royalblue", "crimson"), "us"
            )
            self.plot_phi = _uplot(gui, "JSSA safety index", ("phi [m²]",), ("crimson",), "m²")
            self.plot_speed = _uplot(gui, "PFL speed scale", ("scale",), ("darkorange",), "-")
        with tabs.add_tab("Scenario"):
            self._build_scenario_tab(gui)
        self._show_mode_plots("")

    # ------------------------------------------------------------------------------------------
    def _build_scenario_tab(self, gui: viser.GuiApi) -> None:
        self.scenario = gui.add_dropdown("Scenario", (NO_SCENARIO,))
        gui.add_button("Load").on_click(on_event(self.load_selected))
        self.save_name = gui.add_text("Save as", "")
        gui.add_button("Save as").on_click(on_event(self.save_as))
        self.params_folder = gui.add_folder("Parameters")
        self.confirm_loosening = gui.add_checkbox(
            CONFIRM_LABEL, False,
            hint="Load, apply or drag an edit that loosens what the safety verdict assumes "
            "(another human model, a box moved or removed, a longer timeout, ...); recorded in "
            "the audit log",
        )  # fmt: skip
        gui.add_button("Apply parameters").on_click(on_event(self.apply_params))
        self.message = gui.add_markdown("")
        self._messages_shown = 0
        with gui.add_folder("Human set in force: what it is sound on", expand_by_default=False):
            self.human_set = gui.add_markdown(human_set_markdown(None, "no scenario yet"))

    def loosening_confirmed(self) -> bool:
        """Whether "Confirm loosening" is ticked (cleared by :meth:`clear_confirmation`)."""
        return bool(self.confirm_loosening.value)

    def clear_confirmation(self) -> None:
        self.confirm_loosening.value = False  # type: ignore[misc]

    def add_tab(self, title: str) -> Any:
        """A new tab after the others (``with panels.add_tab("x"): gui.add_...``)."""
        return self.tabs.add_tab(title)

    def load_selected(self) -> bool:
        """The "Load" button: ``on_select_scenario(dropdown value)``; True if accepted."""
        return self._invoke("Load", self.on_select_scenario, lambda: self.scenario.value)

    def save_as(self) -> bool:
        """The "Save as" button: ``on_save_as(typed name)``; True if accepted."""
        return self._invoke("Save", self.on_save_as, lambda: self.save_name.value.strip())

    def apply_params(self) -> bool:
        """The "Apply parameters" button: ``on_params_edit(params())``; True if accepted."""
        return self._invoke("Parameters", self.on_params_edit, self.params)

    def select_mode(self, mode: str) -> bool:
        """Choose a safety mode as the dropdown does (``'ssm'``, ``'pfl'``, ``'jssa'``); True
        if accepted."""
        self.safety_mode.value = mode.upper()  # type: ignore[misc]
        return self._mode == mode

    def replan(self) -> bool:
        """The "Plan from where the robot stands" button: ``on_replan(position shown)``; True
        if accepted."""
        shown = self._robot_q_shown
        if shown is None:
            self.show_message("Re-plan refused: no robot position reported", error=True)
            ok = False
        else:
            ok = self._invoke("Re-plan", self.on_replan, lambda: list(shown))
        self.replan_message.content = self.message.content
        return ok

    def _mode_selected(self) -> None:
        if self._syncing:
            return
        mode = str(self.safety_mode.value).lower()
        if mode == self._mode:
            return
        if self._invoke("Safety mode", self.on_set_mode, lambda: mode):
            self._mode = mode
            self.mode_message.content = self.message.content
        else:
            self.mode_message.content = self.message.content
            self.set_safety_mode(self._mode)  # back to the accepted mode

    def set_safety_mode(self, mode: str) -> None:
        """Show ``mode`` as the accepted safety mode (no callback)."""
        if mode not in SAFETY_MODES:
            return
        self._mode = mode
        self._syncing = True
        try:
            self.safety_mode.value = mode.upper()  # type: ignore[misc]
        finally:
            self._syncing = False

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
        self.message.content = f"**⚠ {md_cell(text)}**" if error else md_cell(text)
        self._messages_shown += 1

    def set_scenarios(self, names: list[str], current: str | None = None) -> None:
        """Replace the dropdown's scenario names; select ``current`` if given."""
        options = tuple(names) or (NO_SCENARIO,)
        self.scenario.options = options
        if current in options:
            self.scenario.value = current  # type: ignore[misc]

    def set_human_set(self, markdown: str) -> None:
        """Show what the human set in force is sound on
        (:mod:`~sara_app.dashboard.human_set_text`)."""
        if self.human_set.content != markdown:
            self.human_set.content = markdown

    def set_params(self, params: dict[str, Any]) -> None:
        """Show editable inputs for ``params`` (nested dict of numbers, bools, strings, lists;
        keys must not contain '.' or '['): a number box, checkbox or text per field, 2- and
        3-vectors as vector inputs, the fields of each person and box on their own, other lists
        as JSON text. Replaces the previous inputs."""
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
                    # a float field for an integer too: viser casts what a client sends to the
                    # field's type, and an integer field took int(1e300), which msgpack cannot
                    # encode: every browser's connection to the view failed from then on
                    inputs[key] = gui.add_number(
                        key, float(v), step=1.0 if isinstance(v, int) else None
                    )
                elif _is_vector(v, 2):  # positions on the floor, e.g. a person's
                    inputs[key] = gui.add_vector2(key, (float(v[0]), float(v[1])), step=0.01)
                elif _is_vector(v, 3):  # box centres and sizes, targets, offsets
                    xyz = (float(v[0]), float(v[1]), float(v[2]))
                    inputs[key] = gui.add_vector3(key, xyz, step=0.01)
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
            if _is_vector(orig, 2) or _is_vector(orig, 3):
                value = [float(x) for x in value]
            elif isinstance(orig, int) and not isinstance(orig, bool):
                value = _integral(value)
            elif not isinstance(orig, bool | int | float | str):
                value = json.loads(value)
            out[key] = value
        return unflatten(out)

    # ------------------------------------------------------------------------------------------
    def update(
        self, t_s: float, status: dict[str, Any], links: list[LinkEnergy] | None = None
    ) -> None:
        """Refresh the status table and the link-energy table; append to the plots, sent at
        most every plot period; show the plots of the worker's safety mode."""
        self.status.content = status_markdown(status)
        totals = totals_markdown(status)
        if totals != self.totals.content:
            self.totals.content = totals
        html = banner_html(status)
        if html != self._banner_html:
            self.banner.content = self._banner_html = html
        q = status.get("robot_q_measured")
        q_md = robot_q_markdown(q)
        if q_md != self.robot_q.content:
            self.robot_q.content = q_md
            self._robot_q_shown = None if q is None else [float(x) for x in q]
        links_md = link_energy_markdown(links or [])
        if links_md != self._links_md:
            self.links.content = self._links_md = links_md
        self.min_sep.append(t_s, np.array([as_float(status.get("min_distance_m"))]))
        self.cycle.append(
            t_s,
            np.array([as_float(status.get("cycle_p50_us")), as_float(status.get("cycle_p99_us"))]),
        )
        jssa = status.get("jssa")
        phi = jssa.get("phi_m2") if isinstance(jssa, dict) else None
        self.phi.append(t_s, np.array([as_float(phi)]))
        self.speed.append(t_s, np.array([as_float(status.get("speed_scale"))]))
        self._show_mode_plots(str(status.get("safety_mode", "")).lower())
        now = time.monotonic()
        if now - self._last_plot >= self.plot_period_s:
            self._last_plot = now
            for plot, series in (
                (self.plot_sep, self.min_sep),
                (self.plot_cycle, self.cycle),
                (self.plot_phi, self.phi),
                (self.plot_speed, self.speed),
            ):
                data = series.plot_data()
                if plot.visible and data[0].shape[0] >= 2:
                    plot.data = data

    def show_waiting(self, status: dict[str, Any]) -> None:
        """The status table before the cell's first verdict (only when it changes)."""
        md = status_markdown(status)
        if md != self.status.content:
            self.status.content = md

    def _show_mode_plots(self, mode: str) -> None:
        if mode == self._shown_mode:
            return
        self._shown_mode = mode
        facts = MODE_FACTS.get(mode)  # none yet (or unknown): no mode's plots
        self.plot_phi.visible = facts is not None and facts.safety_index
        energies = facts is not None and facts.contact_allowed  # link speeds vs energy limits
        self.plot_speed.visible = energies
        self.links_folder.visible = energies

    def show_error(self, text: str | None) -> None:
        """Show (or clear, with None) a rendering error under the status table."""
        self.error.visible = text is not None
        if text is not None:
            self.error.content = f"**⚠ display error:** {text}"
