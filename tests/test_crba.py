"""Compiled CRBA (sara_app/robot/crba_kernels.py) against ``pin.crba``, through ``LinkMotion``.

Reference: pinocchio's own CRBA per configuration, upper triangle mirrored. Relative error is
measured against the largest entry of each matrix (entries near zero are cancellations).
"""

from __future__ import annotations

import numpy as np
import pinocchio as pin
import pytest

from sara_app.errors import InputError, ParameterError
from sara_app.robot.crba_kernels import CompiledCrba
from sara_app.robot.energy import LinkMotion
from sara_app.robot.model import RobotModel, load_robot

RTOL = 1e-10


@pytest.fixture(scope="module", params=["panda", "ur5e"])
def robot(request: pytest.FixtureRequest) -> tuple[RobotModel, LinkMotion]:
    """The robot on a rotated, shifted base (the inertia matrix does not depend on it)."""
    base = pin.SE3(pin.rpy.rpyToMatrix(0.3, -0.2, 0.9), np.array([0.4, -0.3, 0.75]))
    model = load_robot(request.param, T_world_base=base.homogeneous)
    return model, LinkMotion(model)


def _reference(pm: pin.Model, Q: np.ndarray) -> np.ndarray:
    data = pm.createData()
    out = np.empty((Q.shape[0], pm.nv, pm.nv))
    for s in range(Q.shape[0]):
        U = np.triu(pin.crba(pm, data, Q[s]))
        out[s] = U + np.triu(U, 1).T
    return out


def _assert_close(M: np.ndarray, ref: np.ndarray) -> None:
    scale = np.abs(ref).max(axis=(1, 2))
    err = np.abs(M - ref).max(axis=(1, 2))
    assert np.all(err <= RTOL * scale), float(np.max(err / scale))


def _configs(model: RobotModel, S: int, seed: int) -> np.ndarray:
    lim = model.limits
    return np.random.default_rng(seed).uniform(lim.q_min, lim.q_max, (S, model.n_dof))


@pytest.mark.parametrize("S", [1, 10, 40, 300])
def test_compiled_crba_equals_pinocchio(robot: tuple[RobotModel, LinkMotion], S: int) -> None:
    model, motion = robot
    # S = 40 and 300 exceed the initial buffer (16)
    Q = _configs(model, S, seed=S)
    ref = _reference(model.pin_model, Q)
    _assert_close(motion.mass_matrices(Q).copy(), ref)
    U = motion._crba(Q)  # what the energy kernels read: the upper triangle
    iu = np.triu_indices(model.n_dof)
    _assert_close(np.triu(U) + np.triu(U, 1).transpose(0, 2, 1), ref)
    assert np.array_equal(U[:, iu[0], iu[1]], motion.mass_matrices(Q)[:, iu[0], iu[1]])


def test_energies_use_the_same_matrices(robot: tuple[RobotModel, LinkMotion]) -> None:
    model, motion = robot
    Q = _configs(model, 12, seed=5)
    V = np.random.default_rng(6).uniform(-1, 1, Q.shape) * model.limits.v_max
    T = motion.energies(Q, V)[:, -1]
    ref = _reference(model.pin_model, Q)
    np.testing.assert_allclose(T, 0.5 * np.einsum("si,sij,sj->s", V, ref, V), rtol=1e-10)


def test_non_finite_rows(robot: tuple[RobotModel, LinkMotion]) -> None:
    model, motion = robot
    Q = _configs(model, 6, seed=7)
    V = np.random.default_rng(8).uniform(-1, 1, Q.shape)
    clean = motion.energies(Q, V).copy()
    Q[1, 3], V[4, 0], Q[5, 0] = np.nan, np.inf, -np.inf
    T = motion.energies(Q, V)
    bad = np.array([False, True, False, False, True, True])
    assert np.all(np.isinf(T[bad][:, 1:]))
    assert np.array_equal(T[~bad], clean[~bad])
    M = motion.mass_matrices(Q)  # no exception; the bad rows are not finite
    assert not np.isfinite(M[1]).all() and not np.isfinite(M[5]).all()
    _assert_close(M[[0, 2, 3, 4]], _reference(model.pin_model, Q[[0, 2, 3, 4]]))
    with pytest.raises(InputError, match="expected"):
        motion.mass_matrices(Q[:, :3])


def test_a_model_the_compiled_crba_does_not_support_is_refused(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    """Link energies run on the compiled CRBA only: a robot with a joint it does not support
    (here the Panda's kinematics handed a spherical joint) is refused when its
    :class:`LinkMotion` is built, naming the robot and the joint: no silent switch to
    another implementation."""
    from sara_app.robot import energy

    bad = pin.Model()
    jid = bad.addJoint(0, pin.JointModelSpherical(), pin.SE3.Identity(), "ball")
    bad.appendBodyToJoint(jid, pin.Inertia.Random(), pin.SE3.Identity())
    monkeypatch.setattr(energy, "CompiledCrba", lambda pm: CompiledCrba(bad))
    with pytest.raises(ParameterError, match="robot 'panda'.*compiled CRBA.*'ball'"):
        LinkMotion(load_robot("panda"))


def _tree_model(joints: list[tuple[int, pin.JointModel]], seed: int) -> pin.Model:
    """A hand-built tree: each entry ``(parent id, joint)``, random placements and inertias."""
    rng = np.random.default_rng(seed)
    pm = pin.Model()
    for k, (parent, joint) in enumerate(joints):
        placement = pin.SE3(pin.rpy.rpyToMatrix(*rng.uniform(-3, 3, 3)), rng.uniform(-0.4, 0.4, 3))
        jid = pm.addJoint(parent, joint, placement, f"j{k}")
        A = rng.normal(size=(3, 3))
        inertia = pin.Inertia(rng.uniform(0.2, 5.0), rng.uniform(-0.2, 0.2, 3), A @ A.T + 0.01)
        pm.appendBodyToJoint(jid, inertia, pin.SE3.Identity())
    return pm


def test_all_supported_joint_kinds_on_a_branching_tree() -> None:
    axis = np.array([0.3, -0.5, 0.8]) / np.linalg.norm([0.3, -0.5, 0.8])
    joints = [  # depth-first, as pinocchio requires (a subtree's velocities are contiguous)
        (0, pin.JointModelRX()),
        (1, pin.JointModelPY()),
        (2, pin.JointModelRevoluteUnaligned(axis)),
        (3, pin.JointModelRY()),
        (1, pin.JointModelRZ()),  # a second branch from joint 1
        (5, pin.JointModelPrismaticUnaligned(axis)),
        (0, pin.JointModelPZ()),  # a second root
    ]
    pm = _tree_model(joints, seed=1)
    pm.armature = np.linspace(0.1, 0.7, pm.nv)
    crba = CompiledCrba(pm)
    assert crba.supported, crba.reason
    Q = np.random.default_rng(2).uniform(-2.5, 2.5, (50, pm.nq))
    M = np.empty((50, pm.nv, pm.nv))
    crba.compute(Q, M)
    _assert_close(M, _reference(pm, Q))
    pm.gravity.setZero()  # independent reference: columns of the inverse dynamics at v = 0
    data, zero = pm.createData(), np.zeros(pm.nv)
    for s in range(3):
        cols = [pin.rnea(pm, data, Q[s], zero, e) for e in np.eye(pm.nv)]
        _assert_close(M[s : s + 1], np.column_stack(cols)[None])


@pytest.mark.parametrize(
    "joint", [pin.JointModelRUBZ(), pin.JointModelSpherical(), pin.JointModelHX(0.05)]
)
def test_unsupported_joints_are_named(joint: pin.JointModel) -> None:
    pm = _tree_model([(0, pin.JointModelRX()), (1, joint)], seed=3)
    crba = CompiledCrba(pm)
    assert not crba.supported
    assert "'j1'" in crba.reason
