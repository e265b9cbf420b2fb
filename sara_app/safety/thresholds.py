"""Admissible contact energies for power and force limiting (Thumm et al. 2024 Sec. VII, Table I).

A threshold set (``sara_app/params/<name>.json``, default ``thresholds_thumm2024``) holds, per
Table I body *region* (``hand``, ``lower_arm``, ``upper_arm``, ``torso_legs``, ``head``), per
contact type (``constrained`` = clamping, ``unconstrained`` = free collision) and per worst-case
contact shape (``blunt``, ``wedge``, ``edge``, ``sheet``) an energy in joules and the key of its
source. It also holds the body-part diameters of the human-diameter relaxation (Thumm et al. 2024
eq. 33-34) and, for reference only, the ISO/TS 15066 Annex A values with ``E = F^2 / (2 k)``.

Body parts of the project's skeleton (:mod:`sara_app.human.skeleton`) map to Table I regions BY
NAME in :data:`BODY_PART_REGION` (feet, thighs and shins are "torso and legs"). Robot links are
``blunt`` unless a shape is given per link name (the end effector's shape depends on the tool).

:func:`threshold_arrays` turns a set into the ``(L, P)`` arrays the PFL check uses, built once.
"""

from __future__ import annotations

import json
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Annotated

import numpy as np
from pydantic import Field, ValidationError, model_validator

from sara_app.errors import ParameterError, UnknownNameError, describe_validation
from sara_app.human.skeleton import FULL_BODY_PARTS
from sara_app.settings import Strict

PARAM_DIR = Path(__file__).resolve().parent.parent / "params"
DEFAULT_SET = "thresholds_thumm2024"
RENAMED = {"thresholds_seed003": DEFAULT_SET}
"""Shipped set names before 2026-11-25 (scenarios and saved cell states that still name them)."""

REGIONS: tuple[str, ...] = ("hand", "lower_arm", "upper_arm", "torso_legs", "head")
CONTACTS: tuple[str, ...] = ("constrained", "unconstrained")
SHAPES: tuple[str, ...] = ("blunt", "wedge", "edge", "sheet")

BODY_PART_REGION: dict[str, str] = {
    "head": "head",
    "torso": "torso_legs",
    "l_upper_arm": "upper_arm",
    "r_upper_arm": "upper_arm",
    "l_lower_arm": "lower_arm",
    "r_lower_arm": "lower_arm",
    "l_hand": "hand",
    "r_hand": "hand",
    "l_thigh": "torso_legs",
    "r_thigh": "torso_legs",
    "l_shin": "torso_legs",
    "r_shin": "torso_legs",
    "l_foot": "torso_legs",
    "r_foot": "torso_legs",
}
"""Skeleton body part -> Thumm et al. 2024 Table I region, by name (every full-skeleton part)."""

_missing = set(FULL_BODY_PARTS) ^ set(BODY_PART_REGION)
if _missing:  # pragma: no cover - a development error, caught by any import
    raise ParameterError(f"BODY_PART_REGION and the skeleton disagree on {sorted(_missing)}")

Pos = Annotated[float, Field(gt=0.0, allow_inf_nan=False)]


class EnergyLimit(Strict):
    """One admissible energy (J) and the key of its source in ``ThresholdSet.sources``."""

    energy_J: Pos
    source: str


class Diameters(Strict):
    """Body-part diameters (m) for the human-diameter relaxation, keyed by body-part name."""

    source: str
    diameters_m: dict[str, Pos]


class IsoRegion(Strict):
    """ISO/TS 15066 Annex A values of one body region (reference only)."""

    force_quasi_static_N: Pos
    spring_k_N_per_mm: Pos
    effective_mass_kg: Pos

    @property
    def energy_J(self) -> float:
        """Quasi-static ``E = F^2 / (2 k)`` with k in N/m."""
        return self.force_quasi_static_N**2 / (2.0 * self.spring_k_N_per_mm * 1e3)

    @property
    def transient_energy_J(self) -> float:
        """With the transient force ``2 F``: ``(2 F)^2 / (2 k)``."""
        return 4.0 * self.energy_J


class IsoReference(Strict):
    source: str
    regions: dict[str, IsoRegion]


Table = dict[str, dict[str, dict[str, EnergyLimit]]]


def _check_keys(got: Sequence[str], valid: Sequence[str], kind: str) -> None:
    for name in got:
        if name not in valid:
            raise ValueError(f"unknown {kind} {name!r}; valid choices: {', '.join(valid)}")
    missing = [v for v in valid if v not in got]
    if missing:
        raise ValueError(f"missing {kind} {', '.join(missing)}")


class ThresholdSet(Strict):
    """A named, complete threshold set (the JSON file format)."""

    name: str
    description: str = ""
    sources: dict[str, str]
    table: Table
    body_part_diameters: Diameters
    iso_ts_15066_annex_a: IsoReference | None = None

    @model_validator(mode="after")
    def _complete(self) -> ThresholdSet:
        _check_keys(list(self.table), REGIONS, "body region")
        for region, by_contact in self.table.items():
            _check_keys(list(by_contact), CONTACTS, f"contact type of region {region!r}")
            for contact, by_shape in by_contact.items():
                _check_keys(list(by_shape), SHAPES, f"shape of {region}/{contact}")
                for shape, lim in by_shape.items():
                    if lim.source not in self.sources:
                        raise ValueError(
                            f"{region}/{contact}/{shape}: source {lim.source!r} is not one of "
                            f"the set's sources {', '.join(self.sources)}"
                        )
        _check_keys(list(self.body_part_diameters.diameters_m), list(FULL_BODY_PARTS), "body part")
        return self

    def limit(self, region: str, contact: str, shape: str) -> EnergyLimit:
        """The entry for a Table I region (or a skeleton body-part name), contact and shape."""
        region = BODY_PART_REGION.get(region, region)
        if region not in REGIONS:
            valid = REGIONS + tuple(p for p in BODY_PART_REGION if p not in REGIONS)
            raise UnknownNameError("body region or body part", region, valid)
        if contact not in CONTACTS:
            raise UnknownNameError("contact type", contact, CONTACTS)
        if shape not in SHAPES:
            raise UnknownNameError("contact shape", shape, SHAPES)
        return self.table[region][contact][shape]

    def energy_J(self, region: str, contact: str, shape: str) -> float:
        return self.limit(region, contact, shape).energy_J

    def with_energy(
        self, region: str, contact: str, shape: str, energy_J: float
    ) -> tuple[ThresholdSet, bool]:
        """A copy with one value replaced, and whether it exceeds the value of the shipped
        default set for that entry (the editor must then ask for an explicit confirmation)."""
        old = self.limit(region, contact, shape)
        region = BODY_PART_REGION.get(region, region)
        data = self.model_dump()
        data["table"][region][contact][shape] = {"energy_J": energy_J, "source": old.source}
        new = _validated(data, f"{self.name} edited at {region}/{contact}/{shape}")
        default = load_thresholds(DEFAULT_SET).energy_J(region, contact, shape)
        return new, bool(energy_J > default)


def _validated(data: object, what: str) -> ThresholdSet:
    try:
        return ThresholdSet.model_validate(data)
    except ValidationError as exc:  # without the values: a file's content is not repeated
        raise ParameterError(
            f"threshold set {what} is invalid: {describe_validation(exc, with_input=False)}"
        ) from None


def threshold_set_names() -> tuple[str, ...]:
    return tuple(sorted(p.stem for p in PARAM_DIR.glob("thresholds_*.json")))


def load_thresholds(name_or_path: str | Path = DEFAULT_SET) -> ThresholdSet:
    """Load a threshold set by name (``sara_app/params/<name>.json``) or by path."""
    text = RENAMED.get(str(name_or_path), str(name_or_path))
    path = Path(text)
    if text in threshold_set_names():
        path = PARAM_DIR / f"{text}.json"
    elif not path.is_file():
        raise UnknownNameError("threshold set", text, threshold_set_names())
    try:
        data = json.loads(path.read_text())
    except (OSError, json.JSONDecodeError) as exc:
        raise ParameterError(f"threshold set {str(path)!r} cannot be read: {exc}") from None
    return _validated(data, repr(str(path)))


def body_part_regions(part_names: Sequence[str]) -> list[str]:
    """Table I region of each body-part name; an unknown name raises naming it."""
    out = []
    for name in part_names:
        if name not in BODY_PART_REGION:
            raise UnknownNameError("body part", name, BODY_PART_REGION)
        out.append(BODY_PART_REGION[name])
    return out


def link_shapes(link_names: Sequence[str], shapes: Mapping[str, str] | None = None) -> list[str]:
    """Worst-case contact shape per link: ``blunt`` unless given by link name in ``shapes``."""
    shapes = dict(shapes or {})
    for name, shape in shapes.items():
        if name not in link_names:
            raise UnknownNameError("robot link", name, link_names)
        if shape not in SHAPES:
            raise UnknownNameError(f"contact shape of link {name!r}", shape, SHAPES)
    return [shapes.get(n, "blunt") for n in link_names]


def threshold_arrays(
    ts: ThresholdSet,
    link_names: Sequence[str],
    part_names: Sequence[str],
    shapes: Mapping[str, str] | None = None,
) -> tuple[np.ndarray, np.ndarray]:
    """``(T_free (L, P), T_clamp (L, P))`` in J: Thumm et al. 2024 eq. 47-48's
    ``T_type,i^(h_j)``."""
    regions = body_part_regions(part_names)
    per_link = link_shapes(link_names, shapes)
    T_free = np.empty((len(per_link), len(regions)))
    T_clamp = np.empty_like(T_free)
    for i, shape in enumerate(per_link):
        for j, region in enumerate(regions):
            T_free[i, j] = ts.table[region]["unconstrained"][shape].energy_J
            T_clamp[i, j] = ts.table[region]["constrained"][shape].energy_J
    return T_free, T_clamp


def diameters_m(ts: ThresholdSet, part_names: Sequence[str]) -> np.ndarray:
    """``(P,)`` body-part diameters (m) by name."""
    table = ts.body_part_diameters.diameters_m
    out = np.empty(len(part_names))
    for j, name in enumerate(part_names):
        if name not in table:
            raise UnknownNameError("body part", name, table)
        out[j] = table[name]
    return out
