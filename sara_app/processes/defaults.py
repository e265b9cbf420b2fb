"""What ``sara-app serve`` runs when told nothing: the demo cell and the local ports, apart from
the processes themselves so that ``--help`` shows them without starting anything heavy."""

from __future__ import annotations

DEFAULT_SCENARIO = "punches"
"""The built-in default cell: a person punching toward a Panda on a bench (scenarios/)."""
ZENOH_PORT = 7447
VIEWER_PORT = 8080
API_PORT = 8000
LOG_LEVELS = ("debug", "info", "warning")
"""``serve --log-level``: info says what a user needs, debug adds implementation details."""
