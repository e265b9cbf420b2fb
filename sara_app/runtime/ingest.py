"""A skeleton message into one person's state: the message is decoded (joints mapped to the
full skeleton, missing and low-confidence joints, stated uncertainties) and taken through the
one path every measurement takes (:func:`sara_app.cell.intake.take_measurement`). The history
property test drives this function (``tests/test_ingest_history.py``), so what is tested is what
runs.
"""

from __future__ import annotations

import numpy as np

from sara_app.bus.messages import SkeletonMsg
from sara_app.cell.build import Cell
from sara_app.cell.intake import Track, take_measurement
from sara_app.human.skeleton import full_body


def ingest_skeleton(cell: Cell, track: Track, msg: SkeletonMsg) -> str | None:
    """Take ``msg`` into ``track``; None when taken, else the contract's reason for refusing
    it (``out_of_range``, ``stamp_not_advancing``, ``tracking_inconsistent``, ``repeated``)."""
    y, v = full_body(*msg.to_arrays())
    missing, low = (np.pad(a, (0, len(y) - len(a))) for a in msg.joint_states())
    return take_measurement(
        cell, track, msg.stamp_s, y, v=v, missing=missing, low=low,
        unc_m=msg.position_uncertainty_m, unc_v_mps=msg.velocity_uncertainty_mps,
        legs_measured=msg.kind == "full",
    )  # fmt: skip
