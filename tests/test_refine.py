"""ICP refinement, scoring, symmetric-equivalent grouping (mks_sim.models.refine)."""

from __future__ import annotations

import dataclasses
import itertools

import numpy as np
import pytest

from mks_sim.errors import DataError
from mks_sim.geometry.meshes import box_mesh, industrial_part_mesh, sample_surface
from mks_sim.geometry.transforms import (
    apply,
    cube_rotations,
    make_transform,
    pose_error,
    random_rotation,
)
from mks_sim.models.pose import PoseHypothesis
from mks_sim.models.refine import (
    ModelSurface,
    detect_symmetries,
    group_equivalent,
    icp_point_to_plane,
    score_pose,
    verify_hypotheses,
)


def _perturb(T: np.ndarray, deg: float, shift: float, rng: np.random.Generator) -> np.ndarray:
    axis = rng.normal(size=3)
    axis /= np.linalg.norm(axis)
    from scipy.spatial.transform import Rotation

    dR = Rotation.from_rotvec(np.radians(deg) * axis).as_matrix()
    d = rng.normal(size=3)
    return make_transform(dR @ T[:3, :3], T[:3, 3] + shift * d / np.linalg.norm(d))


def _part_scan(
    rng: np.random.Generator, n_model: int, n_scene: int
) -> tuple[ModelSurface, np.ndarray, np.ndarray]:
    """The industrial part's surface, a random true pose and a one-sided noisy scan of it
    (what faces +z in the model frame, placed)."""
    mesh = industrial_part_mesh()
    surface = ModelSurface.from_arrays(*sample_surface(mesh, n_model, rng=rng))
    T_true = make_transform(random_rotation(rng), rng.uniform(-0.2, 0.2, 3))
    scene_model, _ = sample_surface(mesh, n_scene, rng=rng)
    scene = apply(T_true, scene_model[scene_model[:, 2] > 0.004])
    scene += rng.normal(0, 0.0003, scene.shape)
    return surface, T_true, scene


def _paths() -> list[bool]:
    from mks_sim.models.refine import _compiled_available

    return [False, True] if _compiled_available() else [False]


@pytest.mark.parametrize("compiled", _paths())
@pytest.mark.parametrize("seed", [0, 1, 2])
def test_icp_converges_to_ground_truth_on_industrial_part(seed: int, compiled: bool) -> None:
    rng = np.random.default_rng(seed)
    surface, T_true, scene = _part_scan(rng, 4000, 2000)
    start = _perturb(T_true, 10.0, 0.006, rng)
    res = icp_point_to_plane(surface, scene, start, max_distance=0.02, compiled=compiled)
    pos, rot = pose_error(res.matrix, T_true)
    assert rot < 0.5 and pos < 0.001
    assert res.rmse < 0.001
    before = pose_error(start, T_true)
    assert before[1] > 5.0  # it really moved


@pytest.mark.parametrize("seed", [0, 1])
def test_icp_with_the_lookup_grid_converges_to_ground_truth(seed: int) -> None:
    """The same scans as above, correspondences from the nearest-sample grid: as accurate."""
    rng = np.random.default_rng(seed)
    surface, T_true, scene = _part_scan(rng, 4000, 2000)
    surface.with_lookup()
    assert surface.lookup is not None
    start = _perturb(T_true, 10.0, 0.006, rng)
    res = icp_point_to_plane(surface, scene, start, max_distance=0.02)
    pos, rot = pose_error(res.matrix, T_true)
    assert rot < 0.5 and pos < 0.001
    assert res.rmse < 0.001


@pytest.mark.parametrize("compiled", _paths())
def test_the_lookup_grid_answers_as_the_tree_within_a_cell(compiled: bool) -> None:
    """Brute force over every sample: a hit's distance is exact and under the bound, at most
    a cell diagonal farther than the true nearest; a query whose true nearest is a cell
    diagonal inside the bound is a hit; outside the grid the answer is the tree's."""
    rng = np.random.default_rng(3)
    mesh = industrial_part_mesh()
    surface = ModelSurface.from_arrays(*sample_surface(mesh, 3000, rng=rng))
    surface.with_lookup()
    lk = surface.lookup
    assert lk is not None
    lo, hi = surface.points.min(axis=0), surface.points.max(axis=0)
    q = rng.uniform(lo - 0.03, hi + 0.03, (4000, 3))  # inside the grid and beyond its margin
    true = np.sqrt(((q[:, None, :] - surface.points[None]) ** 2).sum(axis=2)).min(axis=1)
    diag = np.sqrt(3.0) * lk.cell
    for bound in (0.004, 0.012, 0.05):
        d, j = lk.query(q, bound, surface.points, surface.tree, compiled=compiled)
        hit = np.isfinite(d)
        assert np.all(j[~hit] == len(surface.points))
        assert np.allclose(d[hit], np.linalg.norm(q[hit] - surface.points[j[hit]], axis=1))
        assert np.all(d[hit] < bound)
        assert np.all(d[hit] <= true[hit] + diag + 1e-12)
        assert np.all(hit[true < bound - diag])
        assert np.all(d[hit] >= true[hit] - 1e-12)
    # beyond the margin with a bound past it: the tree's exact answer
    top = lk.origin + lk.cell * (np.array(lk.shape) - 0.5)
    far = q[np.any((q < lk.origin - lk.cell) | (q > top + lk.cell / 2), axis=1)]
    assert len(far) > 50
    d, j = lk.query(far, 1.0, surface.points, surface.tree, compiled=compiled)
    d0, j0 = surface.tree.query(far, distance_upper_bound=1.0)
    assert np.array_equal(j, j0) and np.allclose(d, d0)


def test_score_prefers_true_pose_and_reports_inliers() -> None:
    rng = np.random.default_rng(3)
    mesh = box_mesh(0.05)
    surface = ModelSurface.from_arrays(*sample_surface(mesh, 3000, rng=rng))
    T = make_transform(random_rotation(rng), [0.1, 0.0, 0.3])
    scene = apply(T, sample_surface(mesh, 1000, rng=rng)[0])
    score, frac, rmse = score_pose(surface, scene, T, 0.002)
    assert frac > 0.99 and rmse < 0.001 and score > 0.9
    off = T.copy()
    off[:3, 3] += [0.01, 0, 0]
    s2, f2, _ = score_pose(surface, scene, off, 0.002)
    assert s2 < score and f2 < 0.8


def test_cube_vertex_symmetries_are_the_24_rotations() -> None:
    corners = np.array(list(itertools.product((-1.0, 1.0), repeat=3)))
    syms = detect_symmetries(corners, cube_rotations(), 1e-6)
    assert len(syms) == 23  # identity excluded
    box = np.array(list(itertools.product((-1.0, 1.0), (-2.0, 2.0), (-3.0, 3.0))))
    assert len(detect_symmetries(box, cube_rotations(), 1e-6)) == 3  # the 180-degree turns


def test_group_equivalent_recognises_cube_symmetries() -> None:
    rng = np.random.default_rng(4)
    T = make_transform(random_rotation(rng), [1.0, 2.0, 3.0])
    rots = cube_rotations()
    mats = [make_transform(T[:3, :3] @ S, T[:3, 3]) for S in rots]
    other = make_transform(T[:3, :3], [1.5, 2.0, 3.0])
    labels = group_equivalent(mats + [other], rots, translation_tol=0.01)
    assert len(set(labels[:24])) == 1 and labels[24] == 24
    labels = group_equivalent(mats, None, translation_tol=0.01)
    assert len(set(labels)) == 24  # without symmetries they are distinct


@pytest.mark.parametrize(
    ("n", "how"),
    [(60, "kernel"), (60, "products"), (60, "products, loop"), (300, "kernel"), (300, "products")],
)  # the compiled pass over the representatives' pairs; numpy's products of every pair at
# once (the representatives compiled or by the Python loop); a pose at a time (300)
def test_group_equivalent_labels_as_the_first_representative_rule(
    n: int, how: str, monkeypatch: pytest.MonkeyPatch
) -> None:
    """Brute force: pose i joins the first earlier representative within the translation
    tolerance whose rotation times some symmetry is within the angle; else it represents."""
    import mks_sim.models.refine as refine
    from mks_sim.geometry.transforms import rotation_angle_deg

    if how == "kernel" and not refine._compiled_available():
        pytest.skip("numba unavailable")
    if how == "products, loop":
        monkeypatch.setattr(refine, "_GROUP_COMPILED_MIN", 10**9)

    rng = np.random.default_rng(5)
    rots = cube_rotations()
    base = [random_rotation(rng) for _ in range(4)]
    mats = []
    for _ in range(n):  # clusters: a few rotations up to symmetry, jittered by 0-5 deg
        R = base[rng.integers(4)] @ rots[rng.integers(24)]
        T = _perturb(make_transform(R, rng.integers(2, size=3) * 0.02), rng.uniform(0, 5), 0, rng)
        T[:3, 3] += rng.normal(0, 0.0015, 3)
        mats.append(T)
    for syms in (rots, None):
        labels = group_equivalent(
            mats, syms, rotation_tol_deg=5.0, translation_tol=0.006, compiled=how == "kernel"
        )
        all_s = [np.eye(3)] + ([] if syms is None else list(syms))
        reps: list[int] = []
        expect = []
        for i, M in enumerate(mats):
            hit = [
                r for r in reps
                if np.linalg.norm(mats[r][:3, 3] - M[:3, 3]) <= 0.006
                and min(rotation_angle_deg(mats[r][:3, :3] @ S, M[:3, :3]) for S in all_s) <= 5.0
            ]  # fmt: skip
            expect.append(hit[0] if hit else i)
            if not hit:
                reps.append(i)
        assert list(labels) == expect
        if syms is not None:
            assert 5 < len(reps) < n - 5  # both joins and new groups happen


def test_matching_symmetries_of_many_poses_are_each_poses_nearest_symmetry() -> None:
    """The batched symmetry search gives, per pose, the symmetry S minimising the angle
    between R_B S and R_A (brute force over the 24)."""
    from mks_sim.geometry.transforms import rotation_angle_deg
    from mks_sim.models.refine import _matching_symmetries

    rng = np.random.default_rng(6)
    rots = np.concatenate([np.eye(3)[None], cube_rotations()])
    B = make_transform(random_rotation(rng), [0.0, 0.0, 0.0])
    As = [_perturb(make_transform(B[:3, :3] @ rots[k], [0, 0, 0]), 3.0, 0.0, rng)
          for k in rng.integers(len(rots), size=40)]  # fmt: skip
    got = _matching_symmetries(As, B, rots)
    for A, S in zip(As, got, strict=True):
        angles = [rotation_angle_deg(B[:3, :3] @ R, A[:3, :3]) for R in rots]
        assert np.array_equal(S, rots[int(np.argmin(angles))])


def test_verify_ranks_true_pose_first_and_lists_equivalents() -> None:
    rng = np.random.default_rng(5)
    mesh = box_mesh(0.05)
    surface = ModelSurface.from_arrays(*sample_surface(mesh, 3000, rng=rng))
    T_true = make_transform(random_rotation(rng), [0.0, 0.1, 0.4])
    scene = apply(T_true, sample_surface(mesh, 1500, rng=rng)[0])
    rots = cube_rotations()
    hyps = [
        PoseHypothesis(
            _perturb(T_true @ make_transform(S, [0, 0, 0]), 4.0, 0.002, rng), [0, 0, 0], 8
        )
        for S in rots[:6]
    ]
    wrong = make_transform(random_rotation(rng), [0.03, 0.12, 0.4])
    hyps.append(PoseHypothesis(wrong, [0, 0, 0], votes=9))
    out = verify_hypotheses(hyps, surface, scene, inlier_distance=0.002, symmetries=rots)
    best = out[0]
    pos, rot = pose_error(best.hypothesis.matrix, T_true, rots)
    assert rot < 0.5 and pos < 0.0005
    assert best.inlier_fraction > 0.99
    assert len(best.equivalents) == 5
    for E in best.equivalents:
        assert pose_error(E, T_true, rots)[1] < 0.5
    assert all(v.hypothesis.score < best.hypothesis.score for v in out[1:])


def test_bad_inputs() -> None:
    with pytest.raises(DataError, match="same shape"):
        ModelSurface.from_arrays(np.zeros((5, 3)), np.zeros((4, 3)))
    surface = ModelSurface.from_arrays(np.eye(3), np.eye(3))
    with pytest.raises(DataError, match="scene points"):
        icp_point_to_plane(surface, np.zeros((3, 3)), np.eye(4), max_distance=1.0)
    with pytest.raises(DataError, match="initial transform"):
        icp_point_to_plane(surface, np.zeros((10, 3)), np.eye(3), max_distance=1.0)
    for stall in (0, -2, 2.5, True):
        with pytest.raises(DataError, match="stall"):
            icp_point_to_plane(surface, np.zeros((10, 3)), np.eye(4), max_distance=1.0, stall=stall)
    with pytest.raises(DataError, match=r"\(S, 3, 3\)"):
        group_equivalent([np.eye(4)], np.eye(3), translation_tol=1.0)


@pytest.mark.parametrize("compiled", _paths())
def test_icp_about_an_axis_turns_only_about_it(compiled: bool) -> None:
    """``axis``: a start with the true tilt and a wrong yaw and position converges to the
    true pose; a start tilted 4 deg stays tilted exactly as much (the relative rotation of
    start and result keeps the axis fixed), while the free ICP takes the tilt out."""
    from mks_sim.localization.hypotheses import rotation_about

    rng = np.random.default_rng(7)
    mesh = box_mesh((0.05, 0.05, 0.05))
    surface = ModelSurface.from_arrays(*sample_surface(mesh, 3000, rng=rng))
    T_true = make_transform(rotation_about(np.array([0.0, 0.0, 1.0]), 0.3), [0.1, 0.0, 0.8])
    pts, nrm = sample_surface(mesh, 3000, rng=rng)
    scene = apply(T_true, pts[(nrm[:, 2] > 0.5) | (nrm[:, 0] > 0.5) | (nrm[:, 1] > 0.5)])
    scene += rng.normal(0, 0.0002, scene.shape)
    down = np.array([0.0, 0.0, -1.0])  # the face the cube rests on (model frame)
    yawed = make_transform(
        T_true[:3, :3] @ rotation_about(down, np.radians(6.0)),
        T_true[:3, 3] + [0.004, -0.003, 0.002],
    )
    res = icp_point_to_plane(surface, scene, yawed, max_distance=0.01, axis=down, compiled=compiled)
    pos, rot = pose_error(res.matrix, T_true)
    assert pos < 0.0005 and rot < 0.3, (pos, rot)
    tilt = rotation_about(np.array([1.0, 0.0, 0.0]), np.radians(4.0))
    tilted = make_transform(T_true[:3, :3] @ tilt, T_true[:3, 3])
    kept = icp_point_to_plane(
        surface, scene, tilted, max_distance=0.01, axis=down, compiled=compiled
    )
    relative = tilted[:3, :3].T @ kept.matrix[:3, :3]  # model-frame motion of the fit
    assert np.allclose(relative @ down, down, atol=1e-9)
    assert pose_error(kept.matrix, T_true)[1] > 3.9
    free = icp_point_to_plane(surface, scene, tilted, max_distance=0.01, compiled=compiled)
    assert pose_error(free.matrix, T_true)[1] < 0.3
    for bad in ([0.0, 0.0, 0.0], [1.0, 0.0], [np.nan, 0.0, 1.0]):
        with pytest.raises(DataError, match="non-zero axis"):
            icp_point_to_plane(surface, scene, tilted, max_distance=0.01, axis=bad)


def test_compiled_icp_iterations_equal_the_numpy_path() -> None:
    """The numba normal equations give the numpy path's iterations to rounding: the same
    iteration count and the same pose (1e-12), trimmed or not, about an axis or free, and
    the same early exit when fewer than 6 pairs pass the gate."""
    if _paths() == [False]:
        pytest.skip("numba does not import here")
    surface, T_true, scene = _part_scan(np.random.default_rng(11), 3000, 1500)
    rng = np.random.default_rng(12)
    for k in range(6):
        start = _perturb(T_true, 8.0, 0.004, rng)
        kw = {
            "max_distance": [0.02, 0.004, 1e-6][k % 3],
            "trim": [0.9, 1.0][k % 2],
            "axis": [None, np.array([0.0, 0.0, 1.0])][k // 3],
        }
        a = icp_point_to_plane(surface, scene, start, compiled=False, **kw)
        b = icp_point_to_plane(surface, scene, start, compiled=True, **kw)
        assert a.iterations == b.iterations and a.converged == b.converged, kw
        np.testing.assert_allclose(b.matrix, a.matrix, atol=1e-12)
        if np.isfinite(a.rmse):
            assert b.rmse == pytest.approx(a.rmse, rel=1e-9)
        else:
            assert not np.isfinite(b.rmse)


@pytest.mark.slow
def test_icp_ends_a_two_cycle_between_the_trimmed_sets() -> None:
    """A scanned cube (scene 2, seed 2, the range finder) refined from each of the cube's 24
    symmetric restatements of its true pose: from one of them the trimmed pairs flipped
    between two sets and every update undid the last (1e-4 rad) until the iteration cap (26);
    the two-cycle now ends it, and every start lands within 0.06 mm / 0.15 deg of the
    simulator's pose (modulo the symmetry)."""
    from mks_sim.devices import make_devices
    from mks_sim.localization.model import load_model
    from mks_sim.localization.representation import representation_of
    from mks_sim.localization.workstation import _default_graph, workstation_representation
    from mks_sim.sim import truth
    from mks_sim.sim.world import build_world

    world = build_world("scene2", seed=2, objects=["cube"])
    graph = _default_graph()
    with make_devices(world.model, world.data, np.random.default_rng(2)) as devices:
        snap = graph.snapshot(devices)
        cloud = np.asarray(snap.get("Range_Points").data)[:, :3]
    # the scan at its full density (no point budget): the case was traced on it
    full = dataclasses.replace(workstation_representation(graph), max_points=10**9)
    objects = representation_of(cloud, full).objects
    model = load_model("cube_5cm")
    pts = np.asarray(model.surface_points())
    surface = ModelSurface.from_arrays(pts, model.surface_normals())
    T_true = truth.object_to_world(world, "cube")  # evaluation and the test's starts only
    centre = T_true[:3, :3] @ pts.mean(axis=0) + T_true[:3, 3]
    radius = float(np.max(np.linalg.norm(pts - pts.mean(axis=0), axis=1)))
    scene = objects[np.linalg.norm(objects - centre, axis=1) <= radius + 0.006]
    iterations = []
    for S in cube_rotations():
        start = make_transform(T_true[:3, :3] @ S, T_true[:3, 3])
        res = icp_point_to_plane(surface, scene, start, max_distance=0.012, max_iterations=26)
        iterations.append(res.iterations)
        pos, rot = pose_error(make_transform(res.matrix[:3, :3] @ S.T, res.matrix[:3, 3]), T_true)
        assert pos < 6e-5 and rot < 0.15, (pos, rot)
    assert max(iterations) <= 10, iterations


def test_icp_stall_stops_a_sliding_fit_and_keeps_a_converging_one() -> None:
    """``stall``: a start on one face of a cube, the scan showing only that face, slides
    along it. With ``stall=4`` ICP stops at the first iteration whose residual is not 0.1 %
    below the residual 4 iterations before (checked against the residuals of the same fit
    run without it, iteration by iteration); without it, it runs on. From a nearby start on a
    scan of three faces, both reach the true pose (0.05 mm / 0.05 deg)."""
    from mks_sim.models.refine import STALL_GAIN

    rng = np.random.default_rng(3)
    mesh = box_mesh(0.05)
    surface = ModelSurface.from_arrays(*sample_surface(mesh, 4000, rng=rng))
    top, _ = sample_surface(mesh, 6000, rng=rng)
    face = top[top[:, 2] > 0.0249]
    face = face + rng.normal(0, 3e-4, face.shape)
    start = make_transform(np.eye(3), [0.01, 0.004, 0.0])

    def run(cap: int, stall: int | None = None):  # type: ignore[no-untyped-def]
        return icp_point_to_plane(
            surface, face, start, max_distance=0.02, max_iterations=cap, stall=stall
        )

    free, held = run(40), run(40, stall=4)
    assert not held.converged and held.iterations < free.iterations
    rmse = {k: run(k).rmse for k in range(1, held.iterations + 1)}  # the free fit's residuals
    assert rmse[held.iterations] == held.rmse
    stalled = [k for k in range(5, held.iterations + 1) if rmse[k] > (1 - STALL_GAIN) * rmse[k - 4]]
    assert stalled == [held.iterations]
    three = top[(top[:, 0] > 0.0249) | (top[:, 1] > 0.0249) | (top[:, 2] > 0.0249)]
    near = _perturb(np.eye(4), 3.0, 0.002, rng)
    for stall in (None, 4):
        res = icp_point_to_plane(surface, three, near, max_distance=0.01, stall=stall)
        pos, rot = pose_error(res.matrix, np.eye(4))
        assert pos < 5e-5 and rot < 0.05, (stall, pos, rot)


def test_symmetric_images_are_the_distinct_non_identity_symmetries() -> None:
    """``_symmetric_images``: T @ S for each distinct S of the list (equal to 1e-6: rounding
    noise and a signed zero are the same symmetry), in order of first appearance, the
    identity left out -- checked against sets built by hand from the cube's rotations."""
    from scipy.spatial.transform import Rotation

    from mks_sim.models.refine import _symmetric_images

    syms = cube_rotations()
    rng = np.random.default_rng(43)
    for trial in range(100):
        picks = rng.integers(0, len(syms), int(rng.integers(0, 40)))
        noise = [rng.choice([0.0, 1e-17, -1e-17, 2e-8]) * rng.integers(0, 2, (3, 3)) for _ in picks]
        related = [syms[i] + e for i, e in zip(picks, noise, strict=True)]
        T = make_transform(Rotation.random(random_state=trial).as_matrix(), rng.normal(size=3))
        want: list[int] = []
        for i in picks:  # distinct, first appearance first, not the identity
            if i not in want and not np.allclose(syms[i], np.eye(3)):
                want.append(int(i))
        got = _symmetric_images(T, related)
        assert got.shape == (len(want), 4, 4)
        for image, i in zip(got, want, strict=True):
            np.testing.assert_allclose(image[:3, :3], T[:3, :3] @ syms[i], atol=1e-6)
            assert np.array_equal(image[:3, 3], T[:3, 3])


@pytest.mark.skipif(not _paths()[-1], reason="needs numba")
def test_point_to_plane_system_adds_the_pairs_in_order() -> None:
    """The compiled normal equations are the plain sums, pair after pair: Python's own
    floats, each ``H[u][v] += a_u a_v`` and ``g[u] += a_u r`` in the pairs' order, give the
    same bits; misses (inf) and the pairs beyond the trim rank are left out, and fewer than
    6 pairs give no system."""
    from mks_sim.models._refine_kernels import point_to_plane_system

    rng = np.random.default_rng(41)
    for n, trim in ((5, 0.9), (12, 0.9), (300, 0.9), (300, 1.0), (1000, 0.8)):
        p = rng.normal(size=(n, 3)) * 0.05
        dist = rng.uniform(0.0, 0.004, n)
        dist[rng.random(n) < 0.1] = np.inf
        j = rng.integers(0, 50, n)
        normals = rng.normal(size=(50, 3))
        normals /= np.linalg.norm(normals, axis=1)[:, None]
        offsets = rng.normal(size=50) * 0.01
        H, g, ss, used = point_to_plane_system(p, dist, j, normals, offsets, trim)
        ok = np.isfinite(dist)
        if ok.sum() < 6:  # too few pairs: no system
            assert used == ok.sum() and ss == 0.0 and not H.any() and not g.any()
            continue
        thr = np.inf
        if trim < 1.0 and ok.sum() > 10:
            kth = int(trim * (ok.sum() - 1))
            thr = np.partition(dist[ok], kth)[kth]
        h_ref = [[0.0] * 6 for _ in range(6)]
        g_ref, ss_ref, used_ref = [0.0] * 6, 0.0, 0
        for i in range(n):
            if not (ok[i] and dist[i] <= thr):
                continue
            nx, ny, nz = (float(v) for v in normals[j[i]])
            px, py, pz = (float(v) for v in p[i])
            r = px * nx + py * ny + pz * nz - float(offsets[j[i]])
            a = [py * nz - pz * ny, pz * nx - px * nz, px * ny - py * nx, nx, ny, nz]
            for u in range(6):
                g_ref[u] += a[u] * r
                for v in range(u, 6):
                    h_ref[u][v] += a[u] * a[v]
            ss_ref += r * r
            used_ref += 1
        for u in range(6):
            for v in range(u):
                h_ref[u][v] = h_ref[v][u]
        assert used == used_ref and ss == ss_ref
        assert H.tobytes() == np.array(h_ref).tobytes() and g.tobytes() == np.array(g_ref).tobytes()


@pytest.mark.skipif(not _paths()[-1], reason="needs numba")
def test_fused_icp_takes_the_loops_steps() -> None:
    """``fused=True`` runs the iterations in one compiled call: from the same starts on the
    part's scans (stall, trim, two-cycle and tolerance on), the same number of iterations,
    the same convergence, poses within 1e-12 of the loop's and at the true pose; without
    the lookup grid, beyond its margin or about an axis it is the loop itself."""
    rng = np.random.default_rng(7)
    for seed in range(6):
        surface, T_true, scene = _part_scan(np.random.default_rng(seed), 4000, 2000)
        surface.with_lookup()
        start = _perturb(T_true, 4.0, 0.003, rng)
        loop = icp_point_to_plane(surface, scene, start, max_distance=0.006, stall=4)
        fused = icp_point_to_plane(surface, scene, start, max_distance=0.006, stall=4, fused=True)
        assert fused.iterations == loop.iterations and fused.converged == loop.converged
        assert np.abs(fused.matrix - loop.matrix).max() < 1e-12
        assert abs(fused.rmse - loop.rmse) < 1e-12
        pos, rot = pose_error(fused.matrix, T_true)
        assert rot < 0.5 and pos < 0.001
    surface, T_true, scene = _part_scan(np.random.default_rng(0), 4000, 2000)
    start = _perturb(T_true, 4.0, 0.003, rng)
    bare = icp_point_to_plane(surface, scene, start, max_distance=0.006)
    assert surface.lookup is None  # no grid: the loop, to the bit
    assert np.array_equal(
        icp_point_to_plane(surface, scene, start, max_distance=0.006, fused=True).matrix,
        bare.matrix,
    )
    surface.with_lookup()
    assert surface.lookup is not None
    far = surface.lookup.margin * 2  # beyond the grid's margin: the loop (the tree answers)
    assert np.array_equal(
        icp_point_to_plane(surface, scene, start, max_distance=far, fused=True).matrix,
        icp_point_to_plane(surface, scene, start, max_distance=far).matrix,
    )
    axis = [0.0, 0.0, 1.0]
    assert np.array_equal(
        icp_point_to_plane(surface, scene, start, max_distance=0.006, axis=axis, fused=True).matrix,
        icp_point_to_plane(surface, scene, start, max_distance=0.006, axis=axis).matrix,
    )


def test_pose_hypothesis_arrays_are_frozen_copies_shared_by_replace() -> None:
    """A hypothesis copies a caller's arrays (changing them later changes nothing) and makes
    its own read-only; ``replace`` shares them (nothing to copy); bad shapes are DataErrors."""
    T = np.eye(4)
    ref = np.array([[1.0], [2.0], [3.0]])  # (3, 1): taken as (3,)
    h = PoseHypothesis(T, ref, votes=2, correspondences=[[0, 1]])
    T[0, 3] = 5.0
    ref[0, 0] = 9.0
    assert h.matrix[0, 3] == 0.0 and h.reference_point.tolist() == [1.0, 2.0, 3.0]
    assert not h.matrix.flags.writeable and not h.reference_point.flags.writeable
    assert h.correspondences.dtype == np.int64 and h.correspondences.shape == (1, 2)
    assert PoseHypothesis(np.eye(4), np.zeros(3)).correspondences.shape == (0, 2)
    scored = dataclasses.replace(h, score=0.5)
    assert scored.matrix is h.matrix and scored.score == 0.5
    view = h.matrix[:, :]  # read-only but not owning its data: copied
    assert PoseHypothesis(view, np.zeros(3)).matrix is not view
    with pytest.raises(DataError):
        PoseHypothesis(np.eye(3), np.zeros(3))
    with pytest.raises(DataError):
        PoseHypothesis(np.eye(4), np.zeros(4))
    with pytest.raises(DataError):
        PoseHypothesis(np.eye(4), np.zeros(3), correspondences=np.zeros((2, 3)))
