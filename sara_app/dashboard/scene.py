"""The cell's 3D scene in viser: robot (URDF), skeletons, human and robot capsules, boxes.

Every part that can be shown or hidden lives under its own frame ``/view/<name>`` (``name`` one
of :data:`VIEW_NAMES`): ``/view/robot/base`` (URDF via :class:`viser.extras.ViserUrdf`),
``/view/skeletons/bones`` (line segments) and ``/view/skeletons/joints`` (points),
``/view/<model>/capsules`` (one translucent capsule group per set of :data:`MODEL_NAMES`) and
``/view/<model>/cut`` (its capsules cut by a height bound, one mesh:
:mod:`sara_app.dashboard.cut_capsules`),
``/view/occupancy/capsules`` (robot capsules in the verdict colour) and
``/view/occupancy_contact/capsules`` (the same, coloured by contact class),
``/view/boxes/batch`` (batched unit boxes), ``/view/contacts/capsules`` (the body parts in
possible contact, coloured by contact class), ``/view/critical_pair/line`` (a line, red while
JSSA intervenes). Each browser shadows the ``/view/<name>`` frames with its own
(:mod:`sara_app.dashboard.view`), so what one browser hides stays shown in another;
:meth:`CellScene.set_visible` says whether any browser shows a part, and parts no browser shows
are not sent at all. :meth:`CellScene.update` sends one :class:`DisplayFrame` in one
``server.atomic()`` block; the robot's URDF pose is only recomputed when ``q`` changed.
"""

from __future__ import annotations

import numpy as np
import viser
import yourdfpy
from viser.extras import ViserUrdf

from sara_app.dashboard.capsules import CapsuleGroup, InstanceBatch, rotation_to_wxyz
from sara_app.dashboard.cut_capsules import CutCapsules
from sara_app.dashboard.frame import (
    CONTACT_ENV,
    CONTACT_SELF,
    CONTACT_UNCONSTRAINED,
    EFFECTIVE,
    MODEL_NAMES,
    ContactParts,
    DisplayFrame,
    EnvBoxes,
    HumanDisplay,
    LinkEnergy,
)
from sara_app.errors import InputError, UnknownNameError
from sara_app.geometry.capsule_mesh import capsule_arrays, unit_box
from sara_app.human.anatomy import UNMEASURED_LEG_REACH_M
from sara_app.human.skeleton import FULL_JOINTS
from sara_app.robot.model import urdf_path

MODEL_COLORS: dict[str, tuple[int, int, int]] = {
    "effective": (245, 150, 110),
    "pos": (70, 110, 230),
    "vel": (0, 170, 210),
    "acc": (150, 80, 220),
    "iso13855": (240, 140, 30),
    "arm": (230, 200, 0),
    "combined": (40, 160, 90),
}
VERIFIED_RGB = (30, 190, 60)
UNVERIFIED_RGB = (225, 30, 30)
CONTACT_RGB: dict[int, tuple[int, int, int]] = {
    CONTACT_UNCONSTRAINED: (255, 190, 0),
    CONTACT_ENV: (220, 0, 220),
    CONTACT_SELF: (40, 90, 255),
}
"""Occupancy colours by contact class; class 'none' keeps the verdict colour."""
CRITICAL_ACTIVE_RGB = (230, 20, 20)
CRITICAL_IDLE_RGB = (110, 110, 130)
"""JSSA critical pair line: red while JSSA modifies the command, grey otherwise."""

LAYERS: tuple[str, ...] = (
    "robot",
    "occupancy",
    "occupancy_contact",
    "skeletons",
    "contacts",
    "boxes",
    "critical_pair",
)
"""Scene parts that can be shown or hidden besides the human sets (``occupancy``: the robot's
capsules in the verdict colour; ``occupancy_contact``: the same coloured by contact class)."""
VIEW_NAMES: tuple[str, ...] = MODEL_NAMES + LAYERS
DEFAULT_VISIBLE: dict[str, bool] = {
    **{m: m == EFFECTIVE for m in MODEL_NAMES},
    **dict.fromkeys(LAYERS, True),
    "occupancy": False,
}
"""What a new browser shows: each person's effective set, the skeletons, the robot's mesh and
its occupancy coloured by contact class (the verdict colour where no contact is possible)."""


def view_node(name: str) -> str:
    """The scene frame that holds view part ``name`` (one of :data:`VIEW_NAMES`)."""
    return f"/view/{name}"


HUMAN_OPACITY = 0.25
CONTACT_PART_OPACITY = 0.6
ROBOT_OPACITY = 0.35
"""Light enough that the robot's mesh shows through its occupancy, dense enough that the verdict
colour reads over a white background."""
BOX_OPACITY = 0.5
LEGS_BOUND_OPACITY = 0.3
LEGS_REACH_M = UNMEASURED_LEG_REACH_M["ankle"]
"""Half the width of the square drawn where unmeasured legs are bounded: a leg's reach."""
PELVIS = FULL_JOINTS.index("pelvis")
MAX_CUT_CAPSULES = 256
"""At most this many capsules of one set are drawn cut (a mesh built in numpy, 0.15 ms and 3.5
kB each), the others whole (larger than the set, never smaller): 16 upper-body people's legs
in seven sets are 672, but the effective set alone, the default, is 96; a bound on what one
message can cost the dashboard."""
Q_EPS_RAD = 1e-4
"""Joint change below which the URDF pose is not redrawn (0.1 mm at 1 m; it costs ~3 ms)."""


def occupancy_colors(
    n: int, verified: bool, contact_class: np.ndarray | None, by_contact: bool
) -> np.ndarray:
    """Colours ``(n, 3)`` uint8 of ``n`` occupancy capsules: verdict colour, then contact class.

    ``contact_class (n,)`` overrides the verdict colour for classes other than 'none' when
    ``by_contact`` is set.
    """
    rgb = np.empty((n, 3), dtype=np.uint8)
    rgb[:] = VERIFIED_RGB if verified else UNVERIFIED_RGB
    if by_contact and contact_class is not None:
        for cls, color in CONTACT_RGB.items():
            rgb[contact_class == cls] = color
    return rgb


def _skeleton(humans: list[HumanDisplay]) -> tuple[np.ndarray, np.ndarray]:
    """Bone segments ``(S, 2, 3)`` and joint points ``(P, 3)`` of all humans; bones touching a
    non-finite joint and non-finite joints dropped."""
    segs, points = [np.zeros((0, 2, 3))], [np.zeros((0, 3))]
    for h in humans:
        y = np.asarray(h.joint_positions, dtype=float)
        pairs = np.asarray(h.bone_pairs, dtype=np.intp).reshape(-1, 2)
        if y.ndim != 2 or y.shape[1] != 3:
            raise InputError(f"human {h.id!r}: joint positions shape {y.shape}; expected (J, 3)")
        if pairs.size and (pairs.min() < 0 or pairs.max() >= y.shape[0]):
            raise InputError(
                f"human {h.id!r}: bone index range [{pairs.min()}, {pairs.max()}] is outside "
                f"the {y.shape[0]} joints"
            )
        seg = y[pairs]
        segs.append(seg[np.isfinite(seg).all(axis=(1, 2))])
        points.append(y[np.isfinite(y).all(axis=1)])
    return np.concatenate(segs), np.concatenate(points)


def _contact_parts(parts: ContactParts | None) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Checked ``ends (P, 2, 3)``, ``radius (P,)`` and colours ``(P, 3)`` (P = 0 for None)."""
    if parts is None:
        return np.zeros((0, 2, 3)), np.zeros(0), np.zeros((0, 3), dtype=np.uint8)
    ends, radius = capsule_arrays(parts.ends, parts.radius)
    cc = np.asarray(parts.contact_class)
    if cc.shape != radius.shape:
        raise InputError(f"contact_parts class has shape {cc.shape}; expected {radius.shape}")
    rgb = np.zeros((cc.shape[0], 3), dtype=np.uint8)
    rgb[:] = (128, 128, 128)
    for cls, color in CONTACT_RGB.items():
        rgb[cc == cls] = color
    return ends, radius, rgb


def _legs_bounds(humans: list[HumanDisplay]) -> np.ndarray:
    """``(n, 3)``: for each person with a finite bound on their unmeasured legs and a finite
    pelvis, the pelvis's x, y and the bound's height."""
    rows = [
        (*h.joint_positions[PELVIS, :2], h.legs_below_m)
        for h in humans
        if h.legs_below_m is not None
        and len(h.joint_positions) > PELVIS
        and np.isfinite(h.joint_positions[PELVIS]).all()
        and np.isfinite(h.legs_below_m)
    ]
    return np.array(rows, dtype=float).reshape(-1, 3)


def _boxes(boxes: EnvBoxes | None) -> tuple[np.ndarray, np.ndarray]:
    """Checked ``T_world_box (M, 4, 4)``, ``half_extents_m (M, 3)`` (M = 0 for None)."""
    if boxes is None:
        return np.zeros((0, 4, 4)), np.zeros((0, 3))
    T = np.asarray(boxes.T_world_box, dtype=float)
    half = np.asarray(boxes.half_extents_m, dtype=float)
    if T.ndim != 3 or T.shape[1:] != (4, 4) or half.shape != (T.shape[0], 3):
        raise InputError(
            f"boxes T_world_box {T.shape} / half_extents_m {half.shape}; expected "
            "(M, 4, 4) / (M, 3)"
        )
    return T, half


class CellScene:
    """The cell scene for one robot; ``update(frame)`` renders one :class:`DisplayFrame`.

    ``robot``: a shipped robot name or a URDF path (:func:`~sara_app.robot.model.urdf_path`);
    ``T_world_base (4, 4)``: robot base pose.
    """

    def __init__(
        self,
        server: viser.ViserServer,
        robot: str = "panda",
        T_world_base: np.ndarray | None = None,
    ) -> None:
        path = urdf_path(robot)  # a shipped name or a URDF file; UnknownNameError otherwise
        self.server = server
        server.scene.set_up_direction("+z")
        server.scene.add_grid("/grid", width=4.0, height=4.0, cell_size=0.25)
        for name in VIEW_NAMES:  # shadowed per browser (sara_app.dashboard.view)
            server.scene.add_frame(view_node(name), show_axes=False)
        T = np.eye(4) if T_world_base is None else np.asarray(T_world_base, dtype=float)
        self.robot_frame = server.scene.add_frame(
            "/view/robot/base",
            wxyz=rotation_to_wxyz(T[None, :3, :3])[0],
            position=T[:3, 3],
            show_axes=False,
        )
        urdf = yourdfpy.URDF.load(str(path))
        self.urdf = ViserUrdf(server, urdf, root_node_name="/view/robot/base")
        self.joint_names = self.urdf.get_actuated_joint_names()
        self._q_shown = np.full(len(self.joint_names), np.nan)
        self.skeleton = server.scene.add_line_segments(
            "/view/skeletons/bones", np.zeros((1, 2, 3)), (40, 40, 40), thickness=0.015,
            visible=False,
        )  # fmt: skip
        self.joints = server.scene.add_point_cloud(
            "/view/skeletons/joints",
            np.zeros((1, 3)),
            (20, 20, 20),
            point_size=0.04,
            point_shape="circle",
            visible=False,
        )
        self.models = {
            m: CapsuleGroup(server, f"{view_node(m)}/capsules", HUMAN_OPACITY, 16, MODEL_COLORS[m])
            for m in MODEL_NAMES
        }
        self.cut_models = {
            m: CutCapsules(server, f"{view_node(m)}/cut", HUMAN_OPACITY, MODEL_COLORS[m])
            for m in MODEL_NAMES
        }
        self.occupancy = CapsuleGroup(server, "/view/occupancy/capsules", ROBOT_OPACITY, 64)
        self.occupancy_contact = CapsuleGroup(
            server, "/view/occupancy_contact/capsules", ROBOT_OPACITY, 64
        )
        self.contact_parts = CapsuleGroup(
            server, "/view/contacts/capsules", CONTACT_PART_OPACITY, 8, CONTACT_RGB[1]
        )
        self.boxes = InstanceBatch(server, "/view/boxes/batch", unit_box(), BOX_OPACITY, 4)
        self.legs_bound = InstanceBatch(
            server, f"{view_node(EFFECTIVE)}/legs_bound", unit_box(), LEGS_BOUND_OPACITY, 4,
            color=MODEL_COLORS[EFFECTIVE],
        )  # fmt: skip
        self._boxes_shown: tuple[np.ndarray, np.ndarray] | None = None
        self.critical = server.scene.add_line_segments(
            "/view/critical_pair/line", np.zeros((1, 2, 3)), (255, 0, 0), thickness=0.02,
            visible=False,
        )  # fmt: skip
        self.layers = dict.fromkeys(LAYERS, True)
        self._layer_nodes: dict[str, tuple[viser.SceneNodeHandle, ...]] = {
            "skeletons": (self.skeleton, self.joints),
            "critical_pair": (self.critical,),
        }
        for name, shown in DEFAULT_VISIBLE.items():
            self.set_visible(name, shown)

    # ------------------------------------------------------------------------------------------
    def set_visible(self, name: str, visible: bool) -> None:
        """Whether any browser shows a human set (one of :data:`MODEL_NAMES`, all humans) or a
        layer (one of :data:`LAYERS`): a part no browser shows is hidden and not sent."""
        if name in self.models:
            self.models[name].visible = visible
            self.cut_models[name].visible = visible
            if name == EFFECTIVE:
                self.legs_bound.visible = visible
        elif name in LAYERS:
            self.layers[name] = bool(visible)
            if name == "robot":
                self.robot_frame.visible = bool(visible)
                if not visible:
                    self._q_shown[:] = np.nan  # redrawn when shown again
            elif name == "occupancy":
                self.occupancy.visible = visible
            elif name == "occupancy_contact":
                self.occupancy_contact.visible = visible
            elif name == "boxes":
                self.boxes.visible = visible
            elif name == "contacts":
                self.contact_parts.visible = visible
            else:  # skeletons, critical_pair: shown with the next frame that has data
                for handle in self._layer_nodes[name]:
                    handle.visible = handle.visible and bool(visible)
        else:
            raise UnknownNameError("layer or human set", name, VIEW_NAMES)

    def update(self, frame: DisplayFrame) -> None:
        """Render ``frame`` in one atomic batch of messages. The whole frame is checked first:
        bad shapes or names raise :class:`InputError` / :class:`UnknownNameError` and change
        nothing; non-finite capsules, joints and poses are hidden rather than raised on."""
        q = self._checked_q(frame.q)
        seg, joints = _skeleton(frame.humans)
        models = self._model_capsules(frame.humans)
        legs = _legs_bounds(frame.humans)
        occ = self._occupancy(frame)
        boxes = _boxes(frame.boxes)
        parts = _contact_parts(frame.contact_parts)
        pair = None if frame.critical_pair is None else np.asarray(frame.critical_pair, float)
        if pair is not None and pair.shape != (2, 3):
            raise InputError(f"critical_pair has shape {pair.shape}; expected (2, 3)")
        with self.server.atomic():
            self._update_robot(q)
            self._update_skeletons(seg, joints)
            for name, (ends, radius, below) in models.items():
                cut = np.isfinite(below)
                cut[np.flatnonzero(cut)[MAX_CUT_CAPSULES:]] = False  # the rest drawn whole
                self.models[name].set(ends[~cut], radius[~cut])
                self.cut_models[name].set(ends[cut], radius[cut], below[cut])
            self._update_legs_bound(legs)
            self.occupancy.set(*occ[:2], occ[2])
            self.occupancy_contact.set(*occ[:2], occ[3])
            self.contact_parts.set(*parts)
            self._update_boxes(*boxes)
            self._update_critical(pair, bool(frame.critical_active))

    # ------------------------------------------------------------------------------------------
    def _checked_q(self, q: np.ndarray) -> np.ndarray:
        q = np.asarray(q, dtype=float)
        if q.shape != self._q_shown.shape:
            raise InputError(
                f"q has shape {q.shape}; expected ({len(self.joint_names)},) for joints "
                f"{', '.join(self.joint_names)}"
            )
        return q

    def _model_capsules(
        self, humans: list[HumanDisplay]
    ) -> dict[str, tuple[np.ndarray, np.ndarray, np.ndarray]]:
        """Per model: all humans' capsules concatenated, ``(C, 2, 3)`` and ``(C,)``, and the
        height each is cut at ``(C,)`` (``inf``: whole)."""
        for h in humans:
            for m in (*h.models, *h.cuts):
                if m not in self.models:
                    raise UnknownNameError("human model", m, MODEL_NAMES)
        out = {}
        for name in self.models:
            ends, radius, below = [np.zeros((0, 2, 3))], [np.zeros(0)], [np.zeros(0)]
            for h in (h for h in humans if name in h.models):
                e, r = capsule_arrays(*h.models[name])
                z = np.asarray(h.cuts.get(name, np.full(r.shape, np.inf)), dtype=float)
                if z.shape != r.shape or np.isnan(z).any():
                    raise InputError(
                        f"human {h.id!r}: {name} cut heights have shape {z.shape} (NaN: "
                        f"{bool(np.isnan(z).any())}); expected {r.shape}, no NaN"
                    )
                ends.append(e)
                radius.append(r)
                below.append(z)
            out[name] = (np.concatenate(ends), np.concatenate(radius), np.concatenate(below))
        return out

    def _occupancy(
        self, frame: DisplayFrame
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """Occupancy capsules flattened: ends ``(K L, 2, 3)``, radii ``(K L,)``, colours by
        verdict and by contact class ``(K L, 3)``."""
        ends = np.asarray(frame.robot_ends, dtype=float)
        radius = np.asarray(frame.robot_radius, dtype=float)
        if ends.ndim != 4 or ends.shape[2:] != (2, 3) or radius.shape != ends.shape[:2]:
            raise InputError(
                f"robot occupancy ends {ends.shape} / radius {radius.shape}; expected "
                "(K, L, 2, 3) / (K, L)"
            )
        cc = frame.contact_class
        if cc is not None:
            cc = np.asarray(cc)
            if cc.shape != radius.shape:
                raise InputError(f"contact_class has shape {cc.shape}; expected {radius.shape}")
            cc = cc.reshape(-1)
        n, ok = radius.size, bool(frame.verified)
        by_verdict = occupancy_colors(n, ok, None, False)
        by_contact = occupancy_colors(n, ok, cc, True)
        return ends.reshape(n, 2, 3), radius.reshape(n), by_verdict, by_contact

    def _update_robot(self, q: np.ndarray) -> None:
        if not self.layers["robot"] or not np.all(np.isfinite(q)):
            return  # keep the last drawn pose
        if np.all(np.abs(q - self._q_shown) <= Q_EPS_RAD):
            return
        self.urdf.update_cfg(q)
        self._q_shown[:] = q

    def _update_skeletons(self, seg: np.ndarray, joints: np.ndarray) -> None:
        shown = self.layers["skeletons"] and bool(len(seg))
        self.skeleton.visible = self.joints.visible = shown
        if shown:
            self.skeleton.points = seg
            self.skeleton.colors = np.full(seg.shape, 40, dtype=np.uint8)
            self.joints.points = joints
            self.joints.colors = np.full(joints.shape, 20, dtype=np.uint8)

    def _update_boxes(self, T: np.ndarray, half: np.ndarray) -> None:
        last = self._boxes_shown
        if last is not None and np.array_equal(last[0], T) and np.array_equal(last[1], half):
            return
        m = T.shape[0]
        ok = np.asarray(np.isfinite(T).all(axis=(1, 2)) & np.isfinite(half).all(axis=1))
        b = self.boxes
        b.reserve(m)
        b.positions[:m] = np.where(ok[:, None], T[:, :3, 3], 0.0)
        if m:
            R = np.where(ok[:, None, None], T[:, :3, :3], np.eye(3))
            b.wxyzs[:m] = rotation_to_wxyz(R)
        b.scales[:m] = np.where(ok[:, None], 2.0 * np.abs(half), 0.0)
        b.colors[:m] = (150, 150, 160)
        b.push(m)
        self._boxes_shown = (T.copy(), half.copy())

    def _update_legs_bound(self, centres: np.ndarray) -> None:
        """One thin square per person at the height their unmeasured legs stay below,
        ``centres (n, 3)`` (pelvis x, y; the bound's z), as wide as a leg reaches."""
        b, n = self.legs_bound, centres.shape[0]
        b.reserve(n)
        b.positions[:n] = centres
        b.scales[:n] = (2.0 * LEGS_REACH_M, 2.0 * LEGS_REACH_M, 0.004)
        b.push(n)

    def _update_critical(self, p: np.ndarray | None, active: bool) -> None:
        if p is None:
            self.critical.visible = False
            return
        ok = bool(np.all(np.isfinite(p)))
        if ok:
            self.critical.points = p[None]
            rgb = CRITICAL_ACTIVE_RGB if active else CRITICAL_IDLE_RGB
            self.critical.colors = np.broadcast_to(np.array(rgb, np.uint8), (1, 2, 3))
        self.critical.visible = ok and self.layers["critical_pair"]


# ----------------------------------------------------------------------------------------------
# Synthetic frames and benchmark


def demo_frame(
    t_s: float,
    n_dof: int = 7,
    n_humans: int = 1,
    n_capsules: int = 14,
    K: int = 10,
    L: int = 8,
    verified: bool = True,
) -> DisplayFrame:
    """A synthetic frame that moves with ``t_s``: humans at x = 1 m walking in y, every model
    with ``n_capsules`` capsules, ``K x L`` occupancy capsules stacked above the robot base."""
    rng = np.random.default_rng(int(t_s * 1000) % 2**31)
    humans = []
    J = 15
    bones = np.stack([np.arange(1, J) - 1, np.arange(1, J)], axis=1)
    for i in range(n_humans):
        base = np.array([1.0 + 0.6 * i, 0.3 * np.sin(t_s), 0.0])
        y = base + np.column_stack(
            [0.1 * rng.standard_normal(J), 0.1 * rng.standard_normal(J), np.linspace(1.7, 0.1, J)]
        )
        models = {}
        for k, m in enumerate(MODEL_NAMES):
            a = base + np.array([0.0, 0.0, 0.2]) + rng.normal(scale=0.15, size=(n_capsules, 3))
            b = a + rng.normal(scale=0.2, size=(n_capsules, 3))
            models[m] = (np.stack([a, b], axis=1), np.full(n_capsules, 0.08 + 0.03 * k))
        humans.append(HumanDisplay(f"h{i}", y, bones, models))
    z = np.linspace(0.0, 1.0, L + 1)
    sway = 0.05 * np.arange(K)[:, None] + 0.1 * np.sin(t_s)
    a = np.stack([sway * z[None, :-1], np.zeros((K, L)), np.broadcast_to(z[:-1], (K, L))], -1)
    b = np.stack([sway * z[None, 1:], np.zeros((K, L)), np.broadcast_to(z[1:], (K, L))], -1)
    contact = np.zeros((K, L), dtype=np.int8)
    contact[-1, -3:] = (1, 2, 3)
    T_box = np.eye(4)
    T_box[:3, 3] = (0.6, -0.6, 0.35)
    y0 = humans[0].joint_positions if humans else np.zeros((J, 3))
    parts = ContactParts(
        np.stack([y0[[3, 5]], y0[[6, 6]]]), np.array([0.06, 0.08]), np.array([2, 1], np.int8)
    )
    links = [
        LinkEnergy(f"link{i}", 0.1 * i, 2.0 if i else None, 2.0 - 0.1 * i if i else None)
        for i in range(L)
    ]
    return DisplayFrame(
        t_s=t_s,
        q=0.1 * np.sin(t_s + np.arange(n_dof)) + np.array([0, 0, 0, -1.5, 0, 1.5, 0.8])[:n_dof],
        humans=humans,
        robot_ends=np.stack([a, b], axis=2),
        robot_radius=np.full((K, L), 0.07),
        verified=verified,
        contact_class=contact,
        status={
            "mode": "intended" if verified else "failsafe",
            "safety_mode": "SSM",
            "min_distance_m": 0.5 + 0.2 * np.sin(t_s),
            "cycle_p50_us": 800.0,
            "cycle_p99_us": 1300.0,
            "skeleton_age_ms": 12.0,
            "dropped": 0,
            "speed_scale": 0.5 + 0.5 * np.cos(t_s),
            "jssa": {"phi_m2": 0.1 * np.sin(t_s), "active": True, "d_min_m": 0.05},
        },
        critical_pair=np.array([[0.1, 0.0, 0.9], [1.0, 0.0, 1.2]]),
        critical_active=True,
        links=links,
        contact_parts=parts if humans else None,
        boxes=EnvBoxes(T_box[None], np.array([[0.3, 0.2, 0.35]])),
    )
