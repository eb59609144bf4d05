"""mks_sim.threads: BLAS limited to one thread inside a localization, restored after."""

from __future__ import annotations

import numpy as np
import pytest
from threadpoolctl import threadpool_info

from mks_sim.threads import one_blas_thread, with_one_blas_thread


def _blas_threads() -> list[int]:
    return [int(i["num_threads"]) for i in threadpool_info() if i["user_api"] == "blas"]


def test_one_blas_thread_limits_every_blas_and_restores_it() -> None:
    with one_blas_thread():  # loads numpy's, scipy's and OpenCV's BLAS
        pass
    before = _blas_threads()
    assert len(before) >= 1
    rng = np.random.default_rng(0)
    d = rng.normal(size=(200_000, 3))
    R = rng.normal(size=(3, 3))
    with one_blas_thread():
        assert set(_blas_threads()) == {1}
        one = (d @ R, d.T @ d)
    assert _blas_threads() == before
    # the products are the same on one thread (the split is over rows, not over sums)
    for a, b in zip(one, (d @ R, d.T @ d), strict=True):
        np.testing.assert_array_equal(a, b)


def test_the_localization_entry_points_run_on_one_blas_thread(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    import mks_sim.localization.pipeline as pipeline
    from mks_sim.geometry.meshes import box_mesh
    from mks_sim.geometry.scan import synthetic_scan
    from mks_sim.geometry.transforms import make_transform
    from mks_sim.localization.workstation import localize_object

    seen: list[list[int]] = []
    find_table = pipeline.find_table

    def spy(*args, **kwargs):  # noqa: ANN002, ANN003, ANN202
        seen.append(_blas_threads())
        return find_table(*args, **kwargs)

    monkeypatch.setattr(pipeline, "find_table", spy)
    mesh = box_mesh(0.05)
    table = (box_mesh((0.6, 0.6, 0.02)), make_transform(np.eye(3), [0.0, 0.0, -0.01]))
    pts = synthetic_scan(
        mesh, make_transform(np.eye(3), [0.0, 0.0, 0.025]), np.array([0.3, 0.1, 0.35]),
        [0.0, 0.0, 0.0], width=80, height=60, fov_deg=30, extra=[table],
    )  # fmt: skip
    pipeline.localize_cloud(mesh, pts, viewpoint=[0.3, 0.1, 0.35])
    assert seen and all(set(s) == {1} for s in seen)
    # the workstation's entry point is the same wrapper
    assert localize_object.__code__ is with_one_blas_thread(lambda: None).__code__
