"""The names of the reachable-set models (:mod:`sara_app.human.reach` builds them), apart from the
models themselves so that the command line can list them without compiling any kernel."""

from __future__ import annotations

MODELS: tuple[str, ...] = ("pos", "vel", "acc", "iso13855", "arm", "combined")
"""Every model: SaRA's position, velocity and acceleration models (Schepp et al. 2022), the
ISO 13855 expansion, Pereira's arm model, the combined speed-and-acceleration model."""
SARA_MODELS: tuple[str, ...] = ("pos", "vel", "acc")

MOVING_MODELS: tuple[str, ...] = ("acc", "combined")
"""The models that need the measured joint velocities and their error bounds."""
