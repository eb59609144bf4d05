"""Scores and accuracy independent of scan density (issue 9, section 1)."""

from __future__ import annotations

import numpy as np
import pytest

from mks_sim.geometry.meshes import box_mesh
from mks_sim.geometry.scan import synthetic_scan
from mks_sim.geometry.transforms import cube_rotations, make_transform, pose_error
from mks_sim.localize import PolyhedralModel, localize_cloud

TABLE = (box_mesh((0.8, 0.8, 0.02)), make_transform(np.eye(3), [0.0, 0.0, -0.01]))


def _scan(width: int, height: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """One oblique view of a 5 cm cube resting on a table (0.5 mm range noise): the setting
    of ``benchmarks/localize.py``."""
    rng = np.random.default_rng(7)
    a = 0.7
    R = np.array([[np.cos(a), -np.sin(a), 0.0], [np.sin(a), np.cos(a), 0.0], [0.0, 0.0, 1.0]])
    T = make_transform(R, [0.02, -0.01, 0.025])
    eye = np.array([0.45 * np.cos(2.0), 0.45 * np.sin(2.0), 0.4])
    pts = synthetic_scan(
        box_mesh(0.05), T, eye, [0.0, 0.0, 0.0], width=width, height=height, fov_deg=22,
        noise_sigma=0.0005, rng=rng, extra=[TABLE],
    )  # fmt: skip
    return T, eye, pts


@pytest.fixture(scope="module")
def cube_model() -> PolyhedralModel:
    return PolyhedralModel.from_mesh(box_mesh(0.05), "cube")


@pytest.mark.parametrize(
    ("width", "height"),
    [
        (115, 87),
        (365, 274),
        (640, 480),
        # 2 M points (the densest case): averaged on a voxel grid to the
        # representation's point budget first; ~1 s of scan and ~2 s of localization idle
        pytest.param(1633, 1225, marks=pytest.mark.slow),
    ],
)
def test_cube_found_with_the_same_score_and_accuracy_at_any_density(
    cube_model: PolyhedralModel, width: int, height: int
) -> None:
    # ~10 k, 100 k, 307 k and 2 M points (the 640 x 480 one-view scan came back NOT FOUND with a
    # pose 0.07 mm from the truth when the score counted scene points)
    T, eye, pts = _scan(width, height)
    assert 0.9 * width * height <= len(pts) <= width * height
    loc = localize_cloud(cube_model, pts, viewpoint=eye)
    assert loc.found and loc.best is not None
    assert loc.best.score > 0.9, loc.best.score
    pos, rot = pose_error(loc.best.matrix, T, cube_rotations())
    assert pos < 0.5e-3 and rot < 0.5, (pos, rot)


@pytest.mark.parametrize("budget", [30000, 10000])
def test_dense_scan_found_at_a_small_point_budget(cube_model: PolyhedralModel, budget: int) -> None:
    # The table of this scan is the plane z = 0. On voxel cells that started at the origin its
    # noisy points averaged to two layers a fraction of a millimetre apart, the spacing
    # estimate halved and, at a 10,000-point budget, the SPG cut the cube into fragments
    # (not found); cells centred on the origin keep the table one layer.
    T, eye, pts = _scan(640, 480)
    loc = localize_cloud(cube_model, pts, viewpoint=eye, max_points=budget)
    assert loc.voxel > 0
    assert loc.spacing > 0.5 * loc.voxel, (loc.spacing, loc.voxel)
    assert loc.found and loc.best is not None
    pos, rot = pose_error(loc.best.matrix, T, cube_rotations())
    assert pos < 2e-3 and rot < 1.0, (pos, rot)


def test_a_plane_through_the_origin_averages_to_one_layer() -> None:
    """``voxel_average(shift=0.5)``: cells centred on the origin keep a noisy plane at z = 0
    in one layer (one centroid per column); cells starting at the origin split it in two."""
    from mks_sim.localization.representation import voxel_average

    rng = np.random.default_rng(3)
    v = 0.002
    xy = rng.uniform(0.0, 0.1, size=(40000, 2))
    pts = np.column_stack([xy, rng.normal(0.0, 0.05 * v, len(xy))])
    columns = len(np.unique(np.floor(xy / v + 0.5), axis=0))
    centred = voxel_average(pts, v, shift=0.5)
    assert len(centred) == columns
    assert np.all(np.abs(centred[:, 2]) < 0.5 * v)
    split = voxel_average(pts, v)
    assert len(split) > 1.8 * len(np.unique(np.floor(xy / v), axis=0))


# ---- the object averaged again before grouping (``object_points``)


def _noisy_view(mesh, seed: int, noise: float = 0.001) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """A 240 x 180 oblique view of ``mesh`` resting on the table (the benchmark's setting)."""
    rng = np.random.default_rng(seed)
    a = rng.uniform(0.0, 2.0 * np.pi)
    R = np.array([[np.cos(a), -np.sin(a), 0.0], [np.sin(a), np.cos(a), 0.0], [0.0, 0.0, 1.0]])
    z = -float(mesh.vertices[:, 2].min())
    T = make_transform(R, [rng.uniform(-0.02, 0.02), rng.uniform(-0.02, 0.02), z])
    az = rng.uniform(0.0, 2.0 * np.pi)
    eye = np.array([0.45 * np.cos(az), 0.45 * np.sin(az), 0.4])
    pts = synthetic_scan(
        mesh, T, eye, [0.0, 0.0, 0.0], width=240, height=180, fov_deg=22, noise_sigma=noise,
        rng=rng, extra=[TABLE],
    )  # fmt: skip
    return T, eye, pts


def test_feature_width_is_the_median_of_the_faces_least_widths() -> None:
    # a 50 x 30 x 20 mm box: faces 50 x 30 (twice), 50 x 20 and 30 x 20 (twice each); their
    # least widths 30, 30, 20, 20, 20, 20 (the samples' hulls reach the edges within ~1 mm)
    model = PolyhedralModel.from_mesh(box_mesh((0.05, 0.03, 0.02)), "box")
    widths = sorted(f.width for f in model.faces)
    assert np.allclose(widths, [0.02] * 4 + [0.03] * 2, atol=1e-3), widths
    assert abs(model.feature_width - 0.02) < 1e-3
    # scaled with the model
    assert abs(model.scaled(1000.0).feature_width - 1000.0 * model.feature_width) < 1e-6


@pytest.mark.parametrize("seed", [11, 12])
def test_a_dense_cube_is_grouped_on_coarser_cells_as_accurately(
    cube_model: PolyhedralModel, seed: int
) -> None:
    from mks_sim.localization.pipeline import FEATURE_CELLS
    from mks_sim.localization.representation import voxel_average

    T, eye, pts = _noisy_view(box_mesh(0.05), seed)
    loc = localize_cloud(cube_model, pts, viewpoint=eye)
    fine = localize_cloud(cube_model, pts, viewpoint=eye, object_points=None)
    assert fine.object_voxel == 0.0
    assert loc.voxel > 0 and 1.2 * loc.voxel <= loc.object_voxel
    assert loc.object_voxel <= cube_model.feature_width / FEATURE_CELLS
    for result in (loc, fine):  # both against the truth
        assert result.found and result.best is not None
        pos, rot = pose_error(result.best.matrix, T, cube_rotations())
        assert pos < 0.5e-3 and rot < 0.5, (pos, rot)
    # the segment's indices still name points of the averaged scene: the object's, as
    # without the coarser cells (nearly all within two coarser cells of the true surface;
    # a few stray points within the SPG's gap of 4 spacings join it, as they do without)
    scene = voxel_average(pts, loc.voxel, shift=0.5)
    ours, theirs = set(loc.segments[0].indices.tolist()), set(fine.segments[0].indices.tolist())
    assert len(ours & theirs) >= 0.95 * max(len(ours), len(theirs))
    local = (scene[loc.segments[0].indices] - T[:3, 3]) @ T[:3, :3]  # cube frame
    outside = np.abs(local).max(axis=1) - 0.025  # distance out of the cube's faces (> 0 out)
    assert np.mean(outside < 2.0 * loc.object_voxel) >= 0.99


def test_narrow_faces_cap_the_object_cells() -> None:
    # the industrial part's faces are 8-60 mm wide (median 21.5 mm): its object points are
    # averaged again on at most 2.39 mm cells, near the scene's (~1.8-2.2 mm)
    from mks_sim.geometry.meshes import industrial_part_mesh
    from mks_sim.localization.pipeline import FEATURE_CELLS

    part = industrial_part_mesh()
    model = PolyhedralModel.from_mesh(part, "part")
    assert 0.019 < model.feature_width < 0.023
    T, eye, pts = _noisy_view(part, 5, noise=0.0003)
    loc = localize_cloud(model, pts, viewpoint=eye)
    assert loc.voxel > 0
    assert loc.object_voxel <= model.feature_width / FEATURE_CELLS + 1e-12
    assert loc.found and loc.best is not None
    pos, rot = pose_error(loc.best.matrix, T)
    assert pos < 1e-3 and rot < 1.0, (pos, rot)


def test_a_box_it_was_not_tuned_on_is_found_on_coarser_cells() -> None:
    # a 90 x 60 x 50 mm box (faces 50-90 mm wide: cells up to 5.5 mm), 1 mm range noise:
    # averaged again and found against the truth, modulo the box's four symmetries
    from mks_sim.geometry.transforms import cube_rotations

    dims = np.array([0.09, 0.06, 0.05])
    mesh = box_mesh(tuple(dims))
    model = PolyhedralModel.from_mesh(mesh, "box")
    syms = np.stack([R for R in cube_rotations() if np.allclose(np.abs(R) @ dims, dims)])
    assert len(syms) == 4
    for seed in (31, 32):
        T, eye, pts = _noisy_view(mesh, seed)
        loc = localize_cloud(model, pts, viewpoint=eye)
        assert loc.object_voxel >= 1.2 * loc.voxel > 0
        assert loc.found and loc.best is not None
        pos, rot = pose_error(loc.best.matrix, T, syms)
        assert pos < 0.5e-3 and rot < 0.5, (seed, pos, rot)
