"""The pydantic base types every settings model of the package is built from (the scenario file,
the safety modes' settings, parameter sets, threshold sets): one place for what "strict" means."""

from __future__ import annotations

from typing import Annotated

from pydantic import BaseModel, ConfigDict, Field

Vec3 = tuple[float, float, float]
Finite = Annotated[float, Field(allow_inf_nan=False)]
Pos = Annotated[float, Field(gt=0.0, allow_inf_nan=False)]
NonNeg = Annotated[float, Field(ge=0.0, allow_inf_nan=False)]
Name = Annotated[str, Field(pattern=r"^[A-Za-z0-9_\-]+$", min_length=1, max_length=64)]
CELL_EXTENT_M = 100.0
"""How far from the world origin a cell's positions may lie (m): a robot cell is a room; a
position of 1e300 m passed validation and overflowed the dashboard's float32 meshes."""
Coord = Annotated[float, Field(ge=-CELL_EXTENT_M, le=CELL_EXTENT_M, allow_inf_nan=False)]
Extent = Annotated[float, Field(gt=0.0, le=2 * CELL_EXTENT_M, allow_inf_nan=False)]


class Strict(BaseModel):
    """A settings model: an unknown field is an error, not ignored."""

    model_config = ConfigDict(extra="forbid")


class StrictFinite(Strict):
    """A settings model whose floats must all be finite (NaN and infinity are refused)."""

    model_config = ConfigDict(extra="forbid", allow_inf_nan=False)
