"""What every message of the contract shares: its header (version, sequence number, stamp) and
the validated number and name types."""

from __future__ import annotations

from typing import Annotated, Literal

from pydantic import BaseModel, ConfigDict, Field, field_validator
from pydantic_core import PydanticCustomError

from sara_app.bus.keys import NAME_PATTERN

SCHEMA_VERSION = 1
"""The schema version of every message kind but those in ``SCHEMA_VERSIONS``."""

Finite = Annotated[float, Field(allow_inf_nan=False)]
NonNeg = Annotated[float, Field(ge=0.0, allow_inf_nan=False)]
Pos = Annotated[float, Field(gt=0.0, allow_inf_nan=False)]
Vec3 = Annotated[list[Finite], Field(min_length=3, max_length=3)]
Name = Annotated[str, Field(pattern=f"^{NAME_PATTERN}$")]
MAX_JOINTS = 64
JointVector = Annotated[list[Finite], Field(min_length=1, max_length=MAX_JOINTS)]
Mode = Literal["intended", "failsafe", "rest", "fault"]


def contract_error(kind: str, message: str) -> PydanticCustomError:
    """A validation error of the contract, counted by the decoder under ``kind``."""
    return PydanticCustomError(kind, message)


class MsgBase(BaseModel):
    """The header of every message: ``schema_version``, ``seq``, ``stamp_s`` (see the package's
    notes); strict, frozen, no unknown fields."""

    model_config = ConfigDict(strict=True, extra="forbid", frozen=True)

    schema_version: Literal[1] = 1  # required on the wire (checked by the decoder)
    seq: Annotated[int, Field(ge=0, le=2**63 - 1)]
    stamp_s: NonNeg

    @field_validator("schema_version", mode="before", check_fields=False)
    @classmethod
    def _version_is_int(cls, v: object) -> object:
        if type(v) is not int:  # JSON true would otherwise equal 1
            raise contract_error("schema_version", f"schema_version {v!r} is not an int")
        return v
