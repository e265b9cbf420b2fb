"""Human motion recordings on disk: the project's own CSV format, the data folder and loading by
name (the type: :mod:`sara_app.human.recording`; CMU ASF/AMC motion capture:
:mod:`sara_app.human.cmu`).

A :class:`~sara_app.human.recording.Recording` is a time series of the project's skeleton joints
(see :mod:`sara_app.human.skeleton`) in the world frame: metres, right-handed, **z up**.

CSV format
----------
A header line ``time_s,<joint>_x,<joint>_y,<joint>_z,...`` with the project's joint names,
then one line per frame (seconds, metres, world frame, z up). The skeleton kind is inferred
from the columns: ``full`` when every joint of the full skeleton has its three columns,
``upper`` when the upper-body joints have theirs and no lower-body joint has any; otherwise the
missing columns are named in the error. Columns of other names are ignored; the column order
does not matter.
"""

from __future__ import annotations

import csv
import os
from pathlib import Path

import numpy as np

from sara_app.errors import InputError, RecordingError
from sara_app.human.bvh import load_bvh
from sara_app.human.cmu import load_cmu
from sara_app.human.recording import Recording, check_frame_interval, validate
from sara_app.human.skeleton import FULL_JOINTS, UPPER_JOINTS, skeleton

_AXES = "xyz"


# --- the data folder -----------------------------------------------------------------------

# The CMU walk 02_01 ships with the package (see its README) for machines without shared/.
PACKAGED_DATA_DIR = Path(__file__).resolve().parent.parent / "data" / "cmu"


def shared_data_dir() -> Path:
    """The folder with the CMU motion capture files: ``SARA_DATA_DIR`` (the ``cmu_mocap``
    folder itself, its parent ``data`` folder or the folder above that). Nothing else is
    searched: recordings that shipped scenarios use ship in the package
    (:data:`PACKAGED_DATA_DIR` and its siblings). Raises RecordingError when it is not set.
    """
    env = os.environ.get("SARA_DATA_DIR")
    if env:
        base = Path(env).expanduser()
        for cand in (base / "cmu_mocap", base / "data" / "cmu_mocap", base):
            if cand.is_dir():
                return cand.resolve()
        raise RecordingError(
            f"SARA_DATA_DIR={env!r} is not a folder; expected the cmu_mocap folder, "
            "shared/data or shared"
        )
    raise RecordingError(
        "no data folder given: set SARA_DATA_DIR to a folder of recordings (one holding "
        "cmu_mocap, or data/cmu_mocap) to use recordings the package does not ship"
    )


# --- CSV -----------------------------------------------------------------------------------


def _csv_columns(joints: tuple[str, ...]) -> list[str]:
    return ["time_s"] + [f"{j}_{c}" for j in joints for c in _AXES]


def save_csv(rec: Recording, path: str | os.PathLike[str]) -> None:
    """Write ``rec`` as CSV (header ``time_s,<joint>_x,...``; values with 17 significant
    digits, so a round trip is exact)."""
    validate(rec)
    sk = skeleton(rec.kind)
    data = np.concatenate(
        [rec.times_s[:, None], rec.positions_m.reshape(rec.n_frames, sk.n_joints * 3)], axis=1
    )
    p = Path(path)
    try:
        with p.open("w", newline="", encoding="utf-8") as fh:
            fh.write(",".join(_csv_columns(sk.joints)) + "\n")
            np.savetxt(fh, data, fmt="%.17g", delimiter=",")
    except OSError as exc:
        raise RecordingError(f"cannot write CSV file {str(p)!r}: {exc}") from None


def load_csv(path: str | os.PathLike[str]) -> Recording:
    """Read a recording written by :func:`save_csv` (or any CSV with the same columns).

    The kind is inferred from the columns (see the module docstring). Raises RecordingError
    naming the file, row and column of a missing column, a non-numeric or non-finite value, a
    ragged row or times that do not strictly increase.
    """
    p = Path(path)
    try:
        with p.open(newline="", encoding="utf-8") as fh:
            rows = [r for r in csv.reader(fh) if r and any(c.strip() for c in r)]
    except (OSError, UnicodeDecodeError, csv.Error) as exc:
        raise RecordingError(f"cannot read CSV file {str(p)!r}: {exc}") from None
    if not rows:
        raise RecordingError(f"CSV file {p.name!r} is empty; expected a header 'time_s,...'")
    header = [h.strip() for h in rows[0]]
    body = rows[1:]
    dup = sorted({h for h in header if header.count(h) > 1})
    if dup:
        raise RecordingError(f"CSV file {p.name!r}: duplicate columns {dup}")
    col = {h: i for i, h in enumerate(header)}
    full_cols = _csv_columns(FULL_JOINTS)
    upper_cols = _csv_columns(UPPER_JOINTS)
    lower_cols = [c for c in full_cols if c not in upper_cols]
    if all(c in col for c in full_cols):
        kind, cols = "full", full_cols
    else:
        missing = [c for c in upper_cols if c not in col]
        present_lower = [c for c in lower_cols if c in col]
        if present_lower:
            missing += [c for c in lower_cols if c not in col]
        if missing:
            expect = "full" if present_lower else "upper (or full)"
            raise RecordingError(
                f"CSV file {p.name!r} lacks columns {missing} needed for a {expect} skeleton; "
                f"expected a header 'time_s,<joint>_x,<joint>_y,<joint>_z,...' with joints "
                f"{list(FULL_JOINTS if present_lower else UPPER_JOINTS)}"
            )
        kind, cols = "upper", upper_cols
    if not body:
        raise RecordingError(f"CSV file {p.name!r} has a header but no data rows")
    idx = [col[c] for c in cols]
    data = np.empty((len(body), len(cols)))
    for r, row in enumerate(body):
        line = r + 2
        if len(row) != len(header):
            raise RecordingError(
                f"CSV file {p.name!r} line {line}: {len(row)} fields; the header has {len(header)}"
            )
        for k, i in enumerate(idx):
            try:
                data[r, k] = float(row[i])
            except ValueError:
                raise RecordingError(
                    f"CSV file {p.name!r} line {line} column {cols[k]!r}: {row[i]!r} is not a "
                    "number"
                ) from None
    bad = ~np.isfinite(data)
    if bad.any():
        r, k = (int(v) for v in np.argwhere(bad)[0])
        raise RecordingError(
            f"CSV file {p.name!r} line {r + 2} column {cols[k]!r}: {body[r][idx[k]]!r} is not "
            f"finite; expected a finite number ({int(bad.sum())} such values)"
        )
    times = data[:, 0]
    dt = np.diff(times)
    if (dt <= 0).any():
        r = int(np.argmax(dt <= 0))
        raise RecordingError(
            f"CSV file {p.name!r}: time_s not strictly increasing: {times[r]!r} at line {r + 2} "
            f"then {times[r + 1]!r} at line {r + 3}"
        )
    if len(dt):
        check_frame_interval(float(np.median(dt)), f"CSV file {p.name!r}", "time_s")
    n_j = skeleton(kind).n_joints
    try:
        return Recording(
            name=p.stem,
            kind=kind,
            times_s=times,
            positions_m=data[:, 1:].reshape(len(body), n_j, 3),
            source=f"CSV {p.name}",
        )
    except InputError as exc:
        raise RecordingError(f"CSV file {p.name!r}: {exc}") from None


# --- dispatch ------------------------------------------------------------------------------

MIN_FRAMES = 3
"""Frames a recording needs to be analysed (containment, volumes, fits): a velocity takes two,
an acceleration three; with fewer, no model's containment, volume or bound says anything."""


def require_frames(rec: Recording) -> Recording:
    """``rec``, refused (:class:`RecordingError`) with fewer than :data:`MIN_FRAMES` frames."""
    if rec.n_frames < MIN_FRAMES:
        raise RecordingError(
            f"recording {rec.name!r} has {rec.n_frames} frame(s); its analysis needs at least "
            f"{MIN_FRAMES} (a velocity takes two frames, an acceleration three)"
        )
    return rec


_SUFFIXES = (".amc", ".bvh", ".csv")


def _asf_beside(amc: Path) -> Path:
    subject = amc.stem.split("_", 1)[0]
    asf = amc.with_name(f"{subject}.asf")
    if asf.is_file():
        return asf
    alt = amc.with_name(f"{subject}.ASF")
    if alt.is_file():
        return alt
    raise RecordingError(
        f"no skeleton for AMC file {amc.name!r}: expected {asf.name!r} (the subject's ASF) "
        f"beside it in {str(amc.parent)!r}"
    )


def load_recording(
    path_or_name: str | os.PathLike[str], *, unit: str | None = None, up: str | None = None
) -> Recording:
    """Load a recording by file path or by name.

    ``.amc``: a CMU motion, its skeleton the ``<subject>.asf`` beside it (``02_01.amc`` ->
    ``02.asf``), 120 Hz. ``.bvh``: a BVH file of a known skeleton (:mod:`sara_app.human.bvh`:
    units and up axis from the data). ``.csv``: the project's CSV format. A name such as
    ``'02_01'``, ``'62_03'`` or ``'CollaborativeHammering/0'`` (or a file name that is not found)
    is looked up in the data folders (:func:`find_recording`). ``unit`` and ``up`` override what
    a BVH file's data establish (an error for the other formats, which state theirs).
    """
    p = find_recording(path_or_name)
    suffix = p.suffix.lower()
    if (unit is not None or up is not None) and suffix != ".bvh":
        raise InputError(f"recording {p.name!r}: a unit or up axis is given only for BVH files")
    if suffix == ".csv":
        return load_csv(p)
    if suffix == ".bvh":
        # numbered takes of a collection (CollaborativeHammering/0.bvh) keep their folder's name
        name = f"{p.parent.name}_{p.stem}" if p.stem.isdigit() else p.stem
        return load_bvh(p, unit=unit, up=up, name=name)
    return load_cmu(_asf_beside(p), p)


def find_recording(path_or_name: str | os.PathLike[str]) -> Path:
    """The file :func:`load_recording` would read (without reading it); raises
    :class:`RecordingError` naming the name when there is none."""
    p = Path(path_or_name)
    if not p.is_file() and not p.is_absolute():
        cand = (
            [p] if p.suffix.lower() in _SUFFIXES else [p.with_name(p.name + s) for s in _SUFFIXES]
        )
        try:
            shared = shared_data_dir()
            bases = [shared, shared.parent, PACKAGED_DATA_DIR.parent]
        except RecordingError:
            shared, bases = None, [PACKAGED_DATA_DIR.parent]
        # a name is a file in a data folder or one of its subfolders (each folder a collection)
        found = list(dict.fromkeys(
            f.resolve() for b in bases for c in cand
            for f in (b / c, *b.glob(f"*/{c}"), *b.glob(f"*/*/{c}")) if f.is_file()
        ))  # fmt: skip
        if len(found) > 1 and len({f.read_bytes() for f in found}) > 1:
            raise RecordingError(
                f"recording name {str(path_or_name)!r} is ambiguous: {[str(f) for f in found]}; "
                "give its folder too (for example 'CollaborativeHammering/0')"
            )
        if found:
            p = found[0]
        elif not p.suffix:
            where = "SARA_DATA_DIR is not set" if shared is None else f"nor in {shared.parent}"
            raise RecordingError(
                f"no recording named {str(path_or_name)!r} among those the package ships "
                f"({where}); give a file's path, or set SARA_DATA_DIR to a folder of recordings"
            )
    suffix = p.suffix.lower()
    if suffix not in _SUFFIXES:
        raise RecordingError(
            f"recording {str(path_or_name)!r}: unknown file type {suffix!r}; expected one of "
            f"{', '.join(_SUFFIXES)} (or a CMU trial name such as '02_01')"
        )
    if not p.is_file():
        raise RecordingError(f"recording file {str(p)!r} does not exist")
    return p
