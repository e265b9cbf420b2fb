"""The live viser dashboard: 3D cell scene, status panel, live plots and scenario-editing GUI.

- :mod:`.frame`: :class:`DisplayFrame`, the plain-numpy input of one rendered instant;
- :mod:`.capsules`: batched capsule rendering (tube + hemisphere instances);
- :mod:`.scene`: :class:`CellScene` (robot URDF, skeletons, capsules, boxes);
- :mod:`.panels`: :class:`DashboardPanels` (status, toggles, plots, scenario tab callbacks);
- :mod:`.viewer`: :class:`Dashboard` (server + scene + panels; start / update / stop).

Only :mod:`.frame` is imported here, so converting bus messages needs no viser import.
"""

from sara_app.dashboard.frame import MODEL_NAMES, DisplayFrame, EnvBoxes, HumanDisplay

__all__ = ["MODEL_NAMES", "DisplayFrame", "EnvBoxes", "HumanDisplay"]
