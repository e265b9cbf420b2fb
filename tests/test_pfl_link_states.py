"""The PFL check's link states in one compiled call (``sara_app.safety.pfl_link_states``): equal,
bit for bit, to the composition of the Python methods (link energies and twists, interval
energy bound, Thm VI.2 error) on shielded trajectories of real followers and on random
trajectories with non-finite samples; buffers per length do not clobber each other; shapes
are checked; the compiled kernel's cache key carries its callees' sources."""

from __future__ import annotations

from types import SimpleNamespace

import numpy as np
import pytest

from sara_app.errors import InputError
from sara_app.kernel_types import source_digest
from sara_app.robot import crba_kernels, energy, occupancy_kernels
from sara_app.robot.energy import LinkMotion, path_interval_energy_J
from sara_app.robot.model import load_robot
from sara_app.robot.shielded import shielded_trajectory
from sara_app.robot.trajectory import PathFollower
from sara_app.safety import contact_kernels
from sara_app.safety.pfl_link_states import PathLinkStates, path_states_kernel
from sara_app.safety.velocity_error import VelocityErrorBound


@pytest.fixture(scope="module", params=["panda", "ur5e"])
def states(request: pytest.FixtureRequest) -> PathLinkStates:
    model = load_robot(request.param)
    return PathLinkStates(LinkMotion(model), VelocityErrorBound(model))


def reference(states: PathLinkStates, traj: object) -> tuple:
    """What ``states.evaluate`` computes, composed of :meth:`LinkMotion.evaluate_path`,
    :func:`~sara_app.robot.energy.path_interval_energy_J` and
    :meth:`VelocityErrorBound.eps_from_bounds` (the readable reference)."""
    q, dq, sd, sd_max, times, v_bound, a_bound = states.inputs(traj)
    smp = states.motion.evaluate_path(q, dq, sd)
    E_int = path_interval_energy_J(smp.g_J, smp.energy_J, sd, sd_max)
    dt = times[1:] - times[:-1]
    eps = states.velocity_error.eps_from_bounds(
        dt, v_bound, a_bound, states.motion.model.limits.j_max
    )
    return smp, E_int, eps


def _outputs(out: tuple) -> list[np.ndarray]:
    smp, E_int, eps = out
    return [a.copy() for a in (smp.energy_J, smp.ends, smp.p1_dot, smp.omega, smp.g_J, E_int, eps)]


def _assert_same(states: PathLinkStates, traj: object) -> list[np.ndarray]:
    got = _outputs(states.evaluate(traj))
    ref = _outputs(reference(states, traj))
    names = ("energy_J", "ends", "p1_dot", "omega", "g_J", "E_int", "eps_v")
    for name, a, b in zip(names, got, ref):
        assert a.shape == b.shape, name
        np.testing.assert_array_equal(a, b, err_msg=name)  # NaN equals NaN here
    return got


def test_equal_to_the_reference_on_shielded_trajectories(states: PathLinkStates) -> None:
    model = states.motion.model
    lim = model.limits
    rng = np.random.default_rng(5)
    lo = lim.q_min + 0.2 * (lim.q_max - lim.q_min)
    hi = lim.q_max - 0.2 * (lim.q_max - lim.q_min)
    moving = 0
    for _ in range(8):
        f = PathFollower(rng.uniform(lo, hi, (3, model.n_dof)), lim)
        for _ in range(int(rng.integers(1, 200))):
            if rng.uniform() < 0.1:
                f.speed_cap = float(rng.uniform(0.05, 3.0))
            f.step(0.001)
        traj = shielded_trajectory(f, 0.001, max_interval_s=0.01)
        got = _assert_same(states, traj)
        moving += bool(np.any(got[0] > 0.0))
    assert moving >= 4  # the trajectories carry energy: the comparison is not of zeros


def _random_traj(rng: np.random.Generator, n: int, S: int) -> SimpleNamespace:
    times = np.concatenate([[0.0], np.cumsum(rng.uniform(0.001, 0.01, S - 1))])
    sd = rng.uniform(0.0, 2.0, S)
    return SimpleNamespace(
        q=rng.uniform(-2.0, 2.0, (S, n)),
        dq=rng.uniform(-1.0, 1.0, (S, n)),
        sd=sd,
        sd_max=np.maximum(sd[:-1], sd[1:]) + rng.uniform(0.0, 0.3, S - 1),
        times=times,
        v_bound=rng.uniform(0.0, 2.0, (S - 1, n)),
        a_bound=rng.uniform(0.0, 10.0, (S - 1, n)),
    )


@pytest.mark.parametrize("field", ["q", "dq", "sd", "sd_max", "none"])
def test_equal_to_the_reference_with_non_finite_samples(states: PathLinkStates, field: str) -> None:
    """A non-finite ``q``, ``dq/ds`` or ``s'`` makes its sample bad (infinite energy, NaN twist
    and ends); a NaN peak speed makes its interval's energy bound infinite; as the reference."""
    rng = np.random.default_rng(len(field))
    n, L = states.n_dof, states.n_links
    for S in (2, 7, 12):
        traj = _random_traj(rng, n, S)
        k = int(rng.integers(S - 1 if field == "sd_max" else S))
        if field in ("q", "dq"):
            getattr(traj, field)[k, int(rng.integers(n))] = np.nan
        elif field != "none":
            getattr(traj, field)[k] = np.inf if field == "sd" else np.nan
        T, ends, pd, w, g, E_int, eps = _assert_same(states, traj)
        assert np.isfinite(eps).all()
        if field == "none":
            assert np.isfinite(E_int).all() and np.isfinite(ends).all()
        elif field == "sd_max":
            assert np.isinf(E_int[k]).all() and np.isfinite(T).all()
        else:
            assert np.isinf(T[k, 1:]).all() and np.isnan(pd[k]).all() and np.isnan(ends[k]).all()
            assert np.isinf(E_int[max(k - 1, 0)]).all()
            assert np.isfinite(np.delete(T, k, axis=0)).all() and L == T.shape[1]


def test_buffers_of_other_lengths_are_kept(states: PathLinkStates) -> None:
    """Outputs are views of buffers per number of samples: a call for another length leaves
    them as they were (a call for the same length overwrites them, as documented)."""
    rng = np.random.default_rng(9)
    a, b = _random_traj(rng, states.n_dof, 6), _random_traj(rng, states.n_dof, 9)
    out_a = states.evaluate(a)
    before = _outputs(out_a)
    states.evaluate(b)
    for x, y in zip(_outputs(out_a), before):
        np.testing.assert_array_equal(x, y)


def test_shapes_are_checked(states: PathLinkStates) -> None:
    rng = np.random.default_rng(2)
    traj = _random_traj(rng, states.n_dof, 5)
    traj.a_bound = traj.a_bound[:-1]
    with pytest.raises(InputError, match="a_bound"):
        states.evaluate(traj)
    one = _random_traj(rng, states.n_dof, 2)
    one.q, one.dq, one.sd, one.times = one.q[:1], one.dq[:1], one.sd[:1], one.times[:1]
    one.sd_max, one.v_bound, one.a_bound = one.sd_max[:0], one.v_bound[:0], one.a_bound[:0]
    with pytest.raises(InputError, match="S >= 2"):
        states.evaluate(one)


def test_cache_key_carries_the_callees_sources() -> None:
    """The kernel calls compiled functions of four other files; numba's cache checks only its
    own, so its closure (hashed into the cache key) must hold their source digests."""
    cells = [c.cell_contents for c in path_states_kernel.py_func.__closure__ or ()]
    text = "".join(c for c in cells if isinstance(c, str))
    for module in (occupancy_kernels, crba_kernels, energy, contact_kernels):
        assert source_digest(module) in text, module.__name__
