"""SaRA cell: formally sound human reachable occupancy and robot shielding."""

__version__ = "0.1.0"
