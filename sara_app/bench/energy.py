"""``sara-app bench`` rows: inertia matrices, the compiled CRBA against pinocchio's loop."""

from __future__ import annotations

import numpy as np
import pinocchio as pin

from sara_app.robot.energy import LinkMotion


def bench_rows(n: int = 2000) -> list[tuple[str, float, float, str]]:
    """Inertia matrices of the Panda at 10 samples: ``pin.crba`` loop vs the compiled CRBA."""
    from sara_app.bench import timeit_us
    from sara_app.robot.model import load_robot

    model = load_robot("panda")
    motion = LinkMotion(model)
    lim = model.limits
    Q = np.random.default_rng(0).uniform(lim.q_min, lim.q_max, (10, model.n_dof))
    pm = model.pin_model
    data = pm.createData()
    med0, p990 = timeit_us(lambda: [pin.crba(pm, data, q) for q in Q], n)
    med1, p991 = timeit_us(lambda: motion.mass_matrices(Q), n)
    return [
        ("energy: inertia matrices, pin.crba loop (S=10)", med0, p990, "panda"),
        ("energy: inertia matrices, compiled CRBA (S=10)", med1, p991, "panda"),
    ]
