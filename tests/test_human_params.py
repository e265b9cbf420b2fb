"""Human parameter sets on disk (sara_app.human.params): what a command writes loads again.
``model_copy`` does not validate, so a fit from a bad number produced a set the loader refuses
after the file was written; the writer now checks first and writes nothing."""

from __future__ import annotations

import math

import pytest

from sara_app.errors import ParameterError
from sara_app.human.params import load_param_set, save_param_set


def test_a_set_that_would_not_load_is_never_written(tmp_path) -> None:
    ps = load_param_set("bench_work")
    out = tmp_path / "ok.json"
    save_param_set(ps, out)
    assert load_param_set(out) == ps  # the round trip the commands rely on
    head = ps.joints["head"].model_copy(update={"v_max_mps": math.inf})
    for bad in (
        ps.model_copy(update={"delta_y_m": math.nan}),
        ps.model_copy(update={"delta_y_m": -0.004}),
        ps.model_copy(update={"joints": {**ps.joints, "head": head}}),
    ):
        path = tmp_path / "bad.json"
        with pytest.raises(ParameterError, match=r"'bench_work' \(not written to .*bad\.json\)"):
            save_param_set(bad, path)
        assert not path.exists()
