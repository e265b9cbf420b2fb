"""CMU motion capture: Acclaim ASF (skeleton) + AMC (motion) files to a
:class:`~sara_app.human.recordings.Recording` of the project's joints.

The ASF file holds the skeleton (bone directions and lengths in the rest pose, the local axes of
each bone and its degrees of freedom), the AMC file one line per bone and frame with the root
translation and the Euler angles of each bone. AMC files store no frame rate; CMU records at
120 Hz, the default of :func:`load_cmu`.

Units: ``:units length L`` means one ASF length unit is ``1/L`` inch, i.e. ``0.0254 / L`` m
(CMU: ``L = 0.45``, 1 unit = 0.056444 m). The root translation of the AMC uses the same unit.
Angles are degrees unless the ASF says ``angle rad`` (or the AMC says ``:RADIANS``).

Forward kinematics (the Acclaim convention, written for column vectors):

- an Euler rotation with order ``XYZ`` rotates about x first, then y, then z:
  ``R = Rz(c) @ Ry(b) @ Rx(a)``; in general the first letter of the order acts first, and the
  three ``axis`` angles of a bone are read in the order of the letters;
- ``C`` is the rotation of the bone's ``axis`` (its local frame in the rest pose), ``M`` the
  rotation of the bone's AMC dof angles (in the order the ``dof`` line lists them, which is how
  they act); a bone without a dof value for an axis gets angle 0 about it;
- the bone's global rotation is ``G = G_parent @ C @ M @ C^-1`` (the root's ``G`` is
  ``C_root @ M_root @ C_root^-1`` with ``C_root`` from ``orientation`` and the root ``axis``);
- the end of a bone is ``end_parent + G @ (direction * length)`` (``direction`` is given in the
  world frame of the rest pose); the root's end is ``position + (TX, TY, TZ)``.

Axis convention: CMU data are y up. The world frame of the project is z up, obtained by a proper
rotation of +90 degrees about the x axis::

    (x, y, z)_world = (x, -z, y)_cmu,   W = [[1, 0, 0], [0, 0, -1], [0, 1, 0]],   det W = +1

so handedness and lengths are kept (no mirroring: left stays left).

Joint mapping, CMU bone -> project joint (``full`` skeleton):

=============  ==========================================================================
project joint  CMU point
=============  ==========================================================================
head           midpoint of the ``upperneck`` end (skull base) and the ``head`` end
neck           ``thorax`` end = start of ``lowerneck`` and of both clavicles: the base of
               the neck, between the shoulders (where a mid-shoulder neck point lies too)
pelvis         ``root``
l/r_shoulder   ``l/rclavicle`` end = ``l/rhumerus`` start
l/r_elbow      ``l/rhumerus`` end
l/r_wrist      ``l/rradius`` end (start of the CMU ``l/rwrist`` bone, which carries the
               forearm twist and reaches the hand; in the usual CMU -> BVH conversion this
               point is the hand joint)
l/r_hip        ``l/rhipjoint`` end = ``l/rfemur`` start
l/r_knee       ``l/rfemur`` end
l/r_ankle      ``l/rtibia`` end
=============  ==========================================================================
"""

from __future__ import annotations

import math
import os
from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from sara_app.errors import InputError, RecordingError
from sara_app.human.recording import Recording
from sara_app.human.skeleton import FULL_JOINTS

__all__ = ["CMU_FPS", "CMU_TO_WORLD", "INCH_M", "cmu_rest_bones", "load_cmu", "load_cmu_bones"]

INCH_M = 0.0254
CMU_FPS = 120.0

# world = W @ cmu: a +90 degree rotation about x (y up -> z up), det +1.
CMU_TO_WORLD = np.array([[1.0, 0.0, 0.0], [0.0, 0.0, -1.0], [0.0, 1.0, 0.0]])

_AXES = "xyz"


# --- ASF -----------------------------------------------------------------------------------


@dataclass(frozen=True)
class _Bone:
    name: str
    direction: np.ndarray  # (3,) unit vector, CMU frame of the rest pose
    length: float  # ASF units
    axis: tuple[float, float, float]  # angles, in the order of axis_order
    axis_order: str  # e.g. "xyz"
    dof: tuple[str, ...]  # e.g. ("rx", "ry", "rz")


@dataclass(frozen=True)
class _Asf:
    length_unit_m: float
    angle_deg: bool
    root_order: tuple[str, ...]  # e.g. ("tx", "ty", "tz", "rx", "ry", "rz")
    root_axis: str
    root_position: np.ndarray
    root_orientation: np.ndarray
    bones: dict[str, _Bone]
    parent: dict[str, str]  # bone -> parent bone or "root"
    order: tuple[str, ...]  # bones, every parent before its children


def _floats(tokens: list[str], where: str, n: int | None = None) -> list[float]:
    try:
        vals = [float(t) for t in tokens]
    except ValueError:
        raise RecordingError(f"{where}: expected numbers, got {' '.join(tokens)!r}") from None
    if n is not None and len(vals) != n:
        raise RecordingError(f"{where}: expected {n} numbers, got {len(vals)}: {tokens}")
    return vals


def _parse_asf(path: Path) -> _Asf:
    try:
        text = path.read_text(encoding="utf-8", errors="replace")
    except OSError as exc:
        raise RecordingError(f"cannot read ASF file {str(path)!r}: {exc}") from None
    units: dict[str, str] = {}
    root: dict[str, list[str]] = {}
    bones: dict[str, _Bone] = {}
    parent: dict[str, str] = {}
    children: dict[str, list[str]] = {}
    section = ""
    cur: dict[str, list[str]] | None = None
    for lineno, raw in enumerate(text.splitlines(), 1):
        line = raw.split("#", 1)[0].strip()
        if not line:
            continue
        where = f"{path.name} line {lineno}"
        if line.startswith(":"):
            section = line[1:].split()[0].lower()
            cur = None
            continue
        tok = line.split()
        key = tok[0].lower()
        if section == "units" and len(tok) >= 2:
            units[key] = tok[1]
        elif section == "root":
            root[key] = tok[1:]
        elif section == "bonedata":
            if key == "begin":
                cur = {}
            elif key == "end":
                if cur is None:
                    raise RecordingError(f"{where}: 'end' without 'begin'")
                bone = _make_bone(cur, where)
                bones[bone.name] = bone
                cur = None
            elif cur is not None and not line.startswith("("):
                cur[key] = tok[1:]
        elif section == "hierarchy":
            if key in ("begin", "end"):
                continue
            par = tok[0]
            for child in tok[1:]:
                if child in parent:
                    raise RecordingError(f"{where}: bone {child!r} has two parents")
                parent[child] = par
                children.setdefault(par, []).append(child)
    if "length" not in units:
        raise RecordingError(
            f"{path.name}: no ':units length' line; expected e.g. 'length 0.45' "
            "(1 unit = 1/length inch)"
        )
    length = _floats([units["length"]], f"{path.name} units length", 1)[0]
    if not length > 0:
        raise RecordingError(f"{path.name}: units length {length} must be > 0")
    angle = units.get("angle", "deg").lower()
    if angle not in ("deg", "rad"):
        raise RecordingError(f"{path.name}: units angle {angle!r}; expected 'deg' or 'rad'")
    order = tuple(t.lower() for t in root.get("order", "TX TY TZ RX RY RZ".split()))
    bad = [t for t in order if t not in ("tx", "ty", "tz", "rx", "ry", "rz")]
    if bad or len(set(order)) != len(order):
        raise RecordingError(
            f"{path.name}: root order {order}; expected distinct TX TY TZ RX RY RZ entries"
        )
    root_axis = _axis_order(root.get("axis", ["XYZ"])[0], f"{path.name} root axis")
    pos = _floats(root.get("position", ["0", "0", "0"]), f"{path.name} root position", 3)
    ori = _floats(root.get("orientation", ["0", "0", "0"]), f"{path.name} root orientation", 3)
    if not bones:
        raise RecordingError(f"{path.name}: no bones in ':bonedata'")
    for child, par in parent.items():
        for b in (child, par):
            if b != "root" and b not in bones:
                raise RecordingError(f"{path.name}: hierarchy names unknown bone {b!r}")
    # Parents before children: breadth-first from the root.
    ordered: list[str] = []
    queue = list(children.get("root", []))
    while queue:
        b = queue.pop(0)
        ordered.append(b)
        queue.extend(children.get(b, []))
    unreached = sorted(set(bones) - set(ordered))
    if unreached:
        raise RecordingError(f"{path.name}: bones not connected to the root: {unreached}")
    return _Asf(
        length_unit_m=INCH_M / length,
        angle_deg=angle == "deg",
        root_order=order,
        root_axis=root_axis,
        root_position=np.array(pos),
        root_orientation=np.array(ori),
        bones=bones,
        parent=parent,
        order=tuple(ordered),
    )


def _axis_order(s: str, where: str) -> str:
    o = s.lower()
    if len(o) != 3 or set(o) != set(_AXES):
        raise RecordingError(f"{where}: axis order {s!r}; expected a permutation of XYZ")
    return o


def _make_bone(d: Mapping[str, list[str]], where: str) -> _Bone:
    if "name" not in d or not d["name"]:
        raise RecordingError(f"{where}: bone without a name")
    name = d["name"][0]
    w = f"{where} (bone {name!r})"
    for k in ("direction", "length", "axis"):
        if k not in d:
            raise RecordingError(f"{w}: missing '{k}'")
    direction = np.array(_floats(d["direction"], f"{w} direction", 3))
    norm = float(np.linalg.norm(direction))
    if not norm > 0:
        raise RecordingError(f"{w}: direction is zero")
    length = _floats(d["length"], f"{w} length", 1)[0]
    ax = d["axis"]
    if len(ax) != 4:
        raise RecordingError(f"{w}: axis {ax}; expected three angles and an order, e.g. XYZ")
    angles = _floats(ax[:3], f"{w} axis")
    dof = tuple(t.lower() for t in d.get("dof", []))
    bad = [t for t in dof if t not in ("rx", "ry", "rz")]
    if bad:
        raise RecordingError(f"{w}: unsupported dof {bad}; only rotations rx, ry, rz are supported")
    return _Bone(
        name=name,
        direction=direction / norm,
        length=length,
        axis=(angles[0], angles[1], angles[2]),
        axis_order=_axis_order(ax[3], f"{w} axis"),
        dof=dof,
    )


# --- AMC -----------------------------------------------------------------------------------


def _parse_amc(path: Path, asf: _Asf) -> tuple[dict[str, np.ndarray], bool]:
    """Per bone (and ``root``) an array (T, n_dof) of the AMC values; and whether in degrees."""
    try:
        text = path.read_text(encoding="utf-8", errors="replace")
    except OSError as exc:
        raise RecordingError(f"cannot read AMC file {str(path)!r}: {exc}") from None
    n_dof = {b.name: len(b.dof) for b in asf.bones.values() if b.dof}
    n_dof["root"] = len(asf.root_order)
    expected = set(n_dof)
    values: dict[str, list[list[float]]] = {k: [] for k in n_dof}
    degrees = asf.angle_deg
    frame_no: int | None = None
    seen: set[str] = set()
    n_frames = 0

    def close_frame(lineno: int) -> None:
        if frame_no is not None and seen != expected:
            raise RecordingError(
                f"{path.name}: frame {frame_no} (ending before line {lineno}) lacks values for "
                f"{sorted(expected - seen)}"
            )

    lines = text.splitlines()
    for lineno, raw in enumerate(lines, 1):
        line = raw.strip()
        if not line or line[0] == "#":
            continue
        if line[0] == ":":
            flag = line[1:].strip().upper()
            if flag == "RADIANS":
                degrees = False
            elif flag == "DEGREES":
                degrees = True
            continue
        tok = line.split()
        if len(tok) == 1 and tok[0].isdigit():
            close_frame(lineno)
            frame_no = int(tok[0])
            seen = set()
            n_frames += 1
            continue
        name = tok[0]
        if frame_no is None:
            raise RecordingError(f"{path.name} line {lineno}: values before the first frame")
        if name not in n_dof:
            raise RecordingError(
                f"{path.name} line {lineno}: bone {name!r} has no dof in the ASF skeleton"
            )
        if name in seen:
            raise RecordingError(f"{path.name} line {lineno}: bone {name!r} twice in frame")
        vals = _floats(tok[1:], f"{path.name} line {lineno} ({name})", n_dof[name])
        values[name].append(vals)
        seen.add(name)
    close_frame(len(lines) + 1)
    if n_frames == 0:
        raise RecordingError(f"{path.name}: no frames")
    arrays = {k: np.array(v, dtype=float).reshape(n_frames, n_dof[k]) for k, v in values.items()}
    return arrays, degrees


# --- forward kinematics --------------------------------------------------------------------


def _axis_rot(axis: str, ang: np.ndarray) -> np.ndarray:
    """Rotation matrices (..., 3, 3) about ``axis`` ('x', 'y', 'z') by ``ang`` radians."""
    c, s = np.cos(ang), np.sin(ang)
    one, zero = np.ones_like(ang), np.zeros_like(ang)
    if axis == "x":
        rows = [[one, zero, zero], [zero, c, -s], [zero, s, c]]
    elif axis == "y":
        rows = [[c, zero, s], [zero, one, zero], [-s, zero, c]]
    else:
        rows = [[c, -s, zero], [s, c, zero], [zero, zero, one]]
    return np.stack([np.stack(r, axis=-1) for r in rows], axis=-2)


def _euler(angles: np.ndarray, order: str) -> np.ndarray:
    """``R = R_{order[-1]} @ ... @ R_{order[0]}``: the first axis of ``order`` acts first.

    ``angles`` (..., len(order)) radians; returns (..., 3, 3).
    """
    angles = np.asarray(angles, dtype=float)
    r = np.broadcast_to(np.eye(3), (*angles.shape[:-1], 3, 3)).copy()
    for i, a in enumerate(order):
        r = _axis_rot(a, angles[..., i]) @ r
    return r


def _fk(asf: _Asf, motion: dict[str, np.ndarray], degrees: bool) -> dict[str, np.ndarray]:
    """End points (T, 3) of every bone and of ``root``, ASF units, CMU frame (y up)."""
    to_rad = math.pi / 180.0 if degrees else 1.0
    asf_rad = math.pi / 180.0 if asf.angle_deg else 1.0
    root_vals = motion["root"]
    n = root_vals.shape[0]
    trans = np.zeros((n, 3))
    rot_axes: list[str] = []
    rot_cols: list[int] = []
    for i, entry in enumerate(asf.root_order):
        if entry[0] == "t":
            trans[:, _AXES.index(entry[1])] = root_vals[:, i]
        else:
            rot_axes.append(entry[1])
            rot_cols.append(i)
    c_root = _euler(asf.root_orientation * asf_rad, asf.root_axis)
    m_root = _euler(root_vals[:, rot_cols] * to_rad, "".join(rot_axes))
    glob: dict[str, np.ndarray] = {"root": c_root @ m_root @ c_root.T}
    ends: dict[str, np.ndarray] = {"root": asf.root_position + trans}
    for name in asf.order:
        bone = asf.bones[name]
        par = asf.parent[name]
        c = _euler(np.array(bone.axis) * asf_rad, bone.axis_order)
        if bone.dof:
            m = _euler(motion[name] * to_rad, "".join(d[1] for d in bone.dof))
            local = c @ m @ c.T
            g = glob[par] @ local
        else:
            g = glob[par]  # C @ I @ C^-1 = I
        glob[name] = g
        ends[name] = ends[par] + g @ (bone.direction * bone.length)
    return ends


# Project joint -> CMU bones whose end points' mean it is (see the module docstring).
_CMU_MAP: dict[str, tuple[str, ...]] = {
    "head": ("upperneck", "head"),
    "neck": ("thorax",),
    "pelvis": ("root",),
    "l_shoulder": ("lclavicle",),
    "r_shoulder": ("rclavicle",),
    "l_elbow": ("lhumerus",),
    "r_elbow": ("rhumerus",),
    "l_wrist": ("lradius",),
    "r_wrist": ("rradius",),
    "l_hip": ("lhipjoint",),
    "r_hip": ("rhipjoint",),
    "l_knee": ("lfemur",),
    "r_knee": ("rfemur",),
    "l_ankle": ("ltibia",),
    "r_ankle": ("rtibia",),
}
if tuple(_CMU_MAP) != FULL_JOINTS:  # a table edit that lost or reordered a joint
    raise RecordingError(
        f"CMU joint map {tuple(_CMU_MAP)}; expected the full skeleton's joints {FULL_JOINTS}"
    )


def _check_cmu_path(p: str | os.PathLike[str], what: str) -> Path:
    path = Path(p)
    if not path.is_file():
        raise RecordingError(f"{what} file {str(path)!r} does not exist")
    return path


def load_cmu_bones(
    asf_path: str | os.PathLike[str], amc_path: str | os.PathLike[str]
) -> dict[str, np.ndarray]:
    """End points of every CMU bone (and ``root``): (T, 3) metres, world frame (z up)."""
    return _cmu_ends(asf_path, amc_path)[0]


def cmu_rest_bones(asf_path: str | os.PathLike[str]) -> dict[str, np.ndarray]:
    """End points (3,) of every CMU bone (and ``root``) in the ASF rest pose (all AMC values 0):
    metres, world frame (z up), root at the origin.

    The standing height of a subject is ``head`` z minus the lowest z (the toes).
    """
    asf = _parse_asf(_check_cmu_path(asf_path, "ASF"))
    motion = {b.name: np.zeros((1, len(b.dof))) for b in asf.bones.values() if b.dof}
    motion["root"] = np.zeros((1, len(asf.root_order)))
    ends = _fk(asf, motion, asf.angle_deg)
    scale = asf.length_unit_m * CMU_TO_WORLD.T
    return {k: (v @ scale)[0] for k, v in ends.items()}


def _cmu_ends(
    asf_path: str | os.PathLike[str], amc_path: str | os.PathLike[str]
) -> tuple[dict[str, np.ndarray], _Asf]:
    asf = _parse_asf(_check_cmu_path(asf_path, "ASF"))
    motion, degrees = _parse_amc(_check_cmu_path(amc_path, "AMC"), asf)
    ends = _fk(asf, motion, degrees)
    scale = asf.length_unit_m * CMU_TO_WORLD.T
    return {k: v @ scale for k, v in ends.items()}, asf


def load_cmu(
    asf_path: str | os.PathLike[str],
    amc_path: str | os.PathLike[str],
    *,
    fps: float = CMU_FPS,
    name: str | None = None,
) -> Recording:
    """A CMU ASF/AMC recording as a ``full`` skeleton recording (see the module docstring).

    ``fps`` is the frame rate (AMC files store none; CMU records at 120 Hz); frame ``i`` is at
    ``i / fps`` seconds. ``name`` defaults to the AMC file stem.
    """
    if not (isinstance(fps, int | float) and math.isfinite(fps) and fps > 0):
        raise InputError(f"fps {fps!r} must be a finite number > 0 (CMU: 120)")
    asf_p, amc_p = Path(asf_path), Path(amc_path)
    ends, asf = _cmu_ends(asf_p, amc_p)
    missing = sorted({b for pts in _CMU_MAP.values() for b in pts} - set(ends))
    if missing:
        raise RecordingError(
            f"{asf_p.name}: bones {missing} are missing; the CMU joint mapping needs them"
        )
    n = ends["root"].shape[0]
    pos = np.empty((n, len(FULL_JOINTS), 3))
    for j, pts in enumerate(_CMU_MAP.values()):
        pos[:, j] = np.mean([ends[p] for p in pts], axis=0)
    unit = INCH_M / asf.length_unit_m
    return Recording(
        name=name if name is not None else amc_p.stem,
        kind="full",
        times_s=np.arange(n) / float(fps),
        positions_m=pos,
        source=(
            f"CMU ASF/AMC {asf_p.name} + {amc_p.name}, {fps:g} Hz, 1 ASF unit = 0.0254/{unit:g} "
            "m, world (x, y, z) = CMU (x, -z, y)"
        ),
    )
