"""The fitted capsules' disk cache (``sara_app.robot.capsule_fit``): a second process gets the
same capsules bit for bit without fitting; an entry that is wrong, foreign or corrupt can never
make a capsule miss its link's collision primitives (the radius is recomputed from the ends);
an unusable cache folder only means fitting again. The fit itself: tests/test_robot_model.py."""

from __future__ import annotations

import xml.etree.ElementTree as ET
from collections.abc import Iterator
from pathlib import Path

import numpy as np
import pytest

from sara_app.geometry.shapes import point_segment_distance
from sara_app.robot import capsule_fit
from sara_app.robot.capsule_fit import fit_cache_dir, fitted_capsules
from sara_app.robot.model import urdf_path
from sara_app.robot.urdf import link_supports


def _fit(name: str) -> tuple[tuple[str, ...], np.ndarray, np.ndarray]:
    capsule_fit._FIT_CACHE.clear()  # as a new process
    path = urdf_path(name)
    return fitted_capsules(path, ET.parse(path).getroot())


def _supports(name: str) -> dict[str, tuple[np.ndarray, np.ndarray, np.ndarray]]:
    path = urdf_path(name)
    return link_supports(ET.parse(path).getroot(), path.parent)


def _contained(name: str, fit: tuple[tuple[str, ...], np.ndarray, np.ndarray]) -> None:
    names, ends, radii = fit
    for i, link in enumerate(names):
        points, rho, _ = _supports(name)[link]
        assert (point_segment_distance(points, ends[i]) + rho).max() <= radii[i], link


@pytest.fixture()
def cache(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> Iterator[Path]:
    monkeypatch.setenv("XDG_CACHE_HOME", str(tmp_path))
    yield fit_cache_dir()
    capsule_fit._FIT_CACHE.clear()


def test_a_second_load_reads_the_same_capsules(
    cache: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    first = _fit("panda")
    assert len(list(cache.glob("*.npy"))) == len(first[0])
    monkeypatch.setattr(capsule_fit, "fit_capsule", None)  # a fit now would raise
    second = _fit("panda")
    assert second[0] == first[0]
    np.testing.assert_array_equal(second[1], first[1])
    np.testing.assert_array_equal(second[2], first[2])


def test_a_wrong_entry_costs_volume_never_containment(cache: Path) -> None:
    good = _fit("panda")
    rng = np.random.default_rng(0)
    for f in cache.glob("*.npy"):  # another link's segment, moved: a foreign entry
        np.save(f, rng.uniform(-1.0, 1.0, (2, 3)))
    bad = _fit("panda")
    _contained("panda", bad)
    assert (bad[2] > good[2]).all()


@pytest.mark.parametrize("content", [b"", b"not an array", b"\x93NUMPY garbage"])
def test_a_corrupt_entry_is_fitted_anew(cache: Path, content: bytes) -> None:
    good = _fit("panda")
    for f in cache.glob("*.npy"):
        f.write_bytes(content)
    again = _fit("panda")
    np.testing.assert_array_equal(again[1], good[1])
    np.testing.assert_array_equal(again[2], good[2])
    wrong_shape = next(iter(cache.glob("*.npy")))
    np.save(wrong_shape, np.full((3, 3), np.nan))
    _contained("panda", _fit("panda"))


def test_an_unusable_cache_folder_fits_every_time(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    blocker = tmp_path / "file"
    blocker.write_text("a file where the cache folder would be")
    monkeypatch.setenv("XDG_CACHE_HOME", str(blocker))
    first = _fit("ur5e")
    second = _fit("ur5e")
    _contained("ur5e", second)
    np.testing.assert_array_equal(first[1], second[1])
    capsule_fit._FIT_CACHE.clear()
