"""Human motion recordings: the :class:`Recording`, the project's own CSV format, the data folder
and loading by name (CMU ASF/AMC motion capture: :mod:`sara_app.human.cmu`).

A :class:`Recording` is a time series of the project's skeleton joints (see
:mod:`sara_app.human.skeleton`) in the world frame: metres, right-handed, **z up**.

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
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from sara_app.errors import InputError, RecordingError
from sara_app.human.skeleton import FULL_JOINTS, KINDS, UPPER_JOINTS, skeleton

_AXES = "xyz"


# --- the recording -------------------------------------------------------------------------


@dataclass(frozen=True, eq=False)
class Recording:
    """Joint positions over time of one skeleton kind.

    Equality and hashing are by identity (``eq=False``): field-wise ``==`` of arrays is
    ambiguous. Compare arrays with ``np.array_equal`` instead.

    ``times_s`` (T,) strictly increasing seconds; ``positions_m`` (T, J, 3) metres, world frame,
    z up, joints in the order of ``skeleton(kind).joints``. Arrays are converted to float arrays
    and checked with :func:`validate` on construction.
    """

    name: str
    kind: str
    times_s: np.ndarray
    positions_m: np.ndarray
    source: str = field(default="")

    def __post_init__(self) -> None:
        try:
            times = np.asarray(self.times_s, dtype=float)
            positions = np.asarray(self.positions_m, dtype=float)
        except (TypeError, ValueError) as exc:
            raise InputError(f"recording {self.name!r}: arrays are not numeric: {exc}") from None
        object.__setattr__(self, "times_s", times)
        object.__setattr__(self, "positions_m", positions)
        validate(self)

    @property
    def n_frames(self) -> int:
        return int(self.times_s.shape[0])

    @property
    def joints(self) -> tuple[str, ...]:
        return skeleton(self.kind).joints

    @property
    def duration_s(self) -> float:
        return float(self.times_s[-1] - self.times_s[0])

    @property
    def frame_period_s(self) -> float:
        """The median time between frames (s); needs at least two frames."""
        if self.n_frames < 2:
            raise InputError(
                f"recording {self.name!r} has {self.n_frames} frame; a frame period needs >= 2"
            )
        return float(np.median(np.diff(self.times_s)))

    def slice(self, start: int, stop: int) -> Recording:
        """Frames ``start`` to ``stop - 1`` (Python slice semantics, negative indices allowed).

        Times are kept as they are (not shifted to start at 0); arrays are copied.
        """
        idx = range(self.n_frames)[start:stop]
        if len(idx) == 0:
            raise InputError(
                f"slice [{start}:{stop}] of recording {self.name!r} is empty; "
                f"it has {self.n_frames} frames"
            )
        a, b = idx.start, idx.stop
        return Recording(
            name=self.name,
            kind=self.kind,
            times_s=self.times_s[a:b].copy(),
            positions_m=self.positions_m[a:b].copy(),
            source=f"{self.source}; frames {a}:{b}" if self.source else f"frames {a}:{b}",
        )


def validate(rec: Recording) -> None:
    """Raise InputError unless ``rec`` is a well-formed recording.

    Checks: a known kind; ``times_s`` of shape (T,) with T >= 1, finite, strictly increasing;
    ``positions_m`` of shape (T, J, 3) for the kind's J joints, finite. Accepts any object with
    the attributes of :class:`Recording`.
    """
    name = getattr(rec, "name", "?")
    kind = rec.kind
    if kind not in KINDS:
        raise InputError(
            f"recording {name!r}: unknown skeleton kind {kind!r}; valid choices: {', '.join(KINDS)}"
        )
    times = np.asarray(rec.times_s)
    pos = np.asarray(rec.positions_m)
    if times.ndim != 1 or times.shape[0] < 1:
        raise InputError(
            f"recording {name!r}: times_s has shape {times.shape}; expected (T,) with T >= 1"
        )
    n_j = skeleton(kind).n_joints
    t = times.shape[0]
    if pos.shape != (t, n_j, 3):
        raise InputError(
            f"recording {name!r}: positions_m has shape {pos.shape}; expected ({t}, {n_j}, 3) "
            f"(T frames, {n_j} joints of the {kind!r} skeleton, xyz)"
        )
    if not (np.issubdtype(times.dtype, np.number) and np.issubdtype(pos.dtype, np.number)):
        raise InputError(
            f"recording {name!r}: arrays must be numeric, got {times.dtype} and {pos.dtype}"
        )
    bad_t = ~np.isfinite(times)
    if bad_t.any():
        i = int(np.argmax(bad_t))
        raise InputError(f"recording {name!r}: times_s[{i}] = {times[i]} is not finite")
    bad_p = ~np.isfinite(pos)
    if bad_p.any():
        f, j, c = (int(v) for v in np.argwhere(bad_p)[0])
        joint = skeleton(kind).joints[j]
        raise InputError(
            f"recording {name!r}: position of joint {joint!r} ({'xyz'[c]}) at frame {f} "
            f"is {pos[f, j, c]}; expected a finite number ({int(bad_p.sum())} such values)"
        )
    dt = np.diff(times)
    if (dt <= 0).any():
        i = int(np.argmax(dt <= 0))
        raise InputError(
            f"recording {name!r}: times_s not strictly increasing: times_s[{i}] = {times[i]} "
            f"then times_s[{i + 1}] = {times[i + 1]}"
        )


# --- the data folder -----------------------------------------------------------------------

_CMU_SUBDIR = Path("shared") / "data" / "cmu_mocap"


# The CMU walk 02_01 ships with the package (see its README) for machines without shared/.
PACKAGED_DATA_DIR = Path(__file__).resolve().parent.parent / "data" / "cmu"


def shared_data_dir() -> Path:
    """The folder with the CMU motion capture files.

    ``SARA_DATA_DIR`` if set (the ``cmu_mocap`` folder itself, ``shared/data`` or ``shared``);
    else the first ``<ancestor>/shared/data/cmu_mocap`` found walking up from this package (the
    repository) and then from the working directory. A CI clone with
    ``shared/`` beside it is found that way (``<clone>/../shared/data/cmu_mocap``).
    Raises RecordingError when there is none.
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
    starts = [Path(__file__).resolve().parent, Path.cwd().resolve()]
    looked: list[str] = []
    for start in starts:
        for anc in (start, *start.parents):
            cand = anc / _CMU_SUBDIR
            if cand.is_dir():
                return cand
            looked.append(str(cand))
    raise RecordingError(
        f"no CMU data folder found: set SARA_DATA_DIR or place {_CMU_SUBDIR} in an ancestor of "
        f"the repository; looked at {looked[:3]} ... ({len(looked)} places)"
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

_SUFFIXES = (".amc", ".csv")


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


def load_recording(path_or_name: str | os.PathLike[str]) -> Recording:
    """Load a recording by file path or by name.

    ``.amc``: a CMU motion, its skeleton the ``<subject>.asf`` beside it (``02_01.amc`` ->
    ``02.asf``), 120 Hz. ``.csv``: the project's CSV format. A bare name such as ``'02_01'``
    (or a file name that is not found) is looked up in :func:`shared_data_dir`.
    """
    p = find_recording(path_or_name)
    if p.suffix.lower() == ".csv":
        return load_csv(p)
    from sara_app.human.cmu import load_cmu  # cmu builds Recordings: imported on use

    return load_cmu(_asf_beside(p), p)


def find_recording(path_or_name: str | os.PathLike[str]) -> Path:
    """The file :func:`load_recording` would read (without reading it); raises
    :class:`RecordingError` naming the name when there is none."""
    p = Path(path_or_name)
    if not p.is_file() and not p.is_absolute() and len(p.parts) == 1:
        cand = (
            [p] if p.suffix.lower() in _SUFFIXES else [p.with_name(p.name + s) for s in _SUFFIXES]
        )
        try:
            bases = [shared_data_dir(), PACKAGED_DATA_DIR]
        except RecordingError:
            bases = [PACKAGED_DATA_DIR]
        found = [b / c for b in bases for c in cand if (b / c).is_file()]
        if found:
            p = found[0]
    suffix = p.suffix.lower()
    if suffix not in _SUFFIXES:
        raise RecordingError(
            f"recording {str(path_or_name)!r}: unknown file type {suffix!r}; expected one of "
            f"{', '.join(_SUFFIXES)} (or a CMU trial name such as '02_01')"
        )
    if not p.is_file():
        raise RecordingError(f"recording file {str(p)!r} does not exist")
    return p
