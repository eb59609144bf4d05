"""The localization engine's shared representation and batch scoring (issue 9, section 1)."""

from __future__ import annotations

from typing import Any

import numpy as np
import pytest

from mks_sim.geometry.meshes import box_mesh, sample_surface, uv_sphere
from mks_sim.geometry.transforms import make_transform, random_rotation
from mks_sim.localization import (
    Representation,
    RepresentationConfig,
    batch_explained,
    representation_of,
)
from mks_sim.lowlevel.normals import _smallest_eigen
from mks_sim.models.refine import ModelSurface, batch_inlier_fractions, score_pose

TABLE_Z = 0.75


def _scene(seed: int = 0) -> np.ndarray:
    """A 5 cm cube and a 3 cm sphere on a table plane (top halves seen)."""
    rng = np.random.default_rng(seed)
    cube, _ = sample_surface(box_mesh(0.05), 3000, rng=rng)
    cube = cube[cube[:, 2] > -0.0249] + [0.05, -0.03, TABLE_Z + 0.025]
    sphere, _ = sample_surface(uv_sphere(0.03, 32, 64), 3000, rng=rng)
    sphere = sphere[sphere[:, 2] > -0.02] + [-0.08, 0.06, TABLE_Z + 0.03]
    table = np.c_[rng.uniform(-0.2, 0.2, (15000, 2)), np.full(15000, TABLE_Z)]
    table[:, 2] += rng.normal(0.0, 2e-4, len(table))
    pts = np.vstack([table, cube, sphere])
    pts.setflags(write=False)
    return pts


def test_closed_form_eigen_matches_numpy() -> None:
    rng = np.random.default_rng(1)
    A = rng.normal(size=(2000, 3, 3))
    C = A @ A.transpose(0, 2, 1)
    C[:50] = np.diag([1.0, 1.0, 1e-9])  # a plane
    C[50:60] = np.eye(3)  # isotropic: any direction, curvature 1/3
    iu = [(0, 0), (0, 1), (0, 2), (1, 1), (1, 2), (2, 2)]
    normals, curvature = _smallest_eigen(np.stack([C[:, i, j] for i, j in iu], axis=1))
    w, v = np.linalg.eigh(C)
    np.testing.assert_allclose(curvature, w[:, 0] / w.sum(axis=1), atol=1e-12)
    distinct = np.arange(len(C)) >= 60
    cos = np.abs(np.einsum("ni,ni->n", normals, v[:, :, 0]))
    np.testing.assert_allclose(cos[distinct], 1.0, atol=1e-9)
    np.testing.assert_allclose(np.linalg.norm(normals, axis=1), 1.0, atol=1e-12)


def test_batch_inlier_fractions_equal_score_pose() -> None:
    rng = np.random.default_rng(2)
    pts, nrm = sample_surface(box_mesh(0.05), 3000, rng=rng)
    surface = ModelSurface.from_arrays(pts, nrm)
    scene, _ = sample_surface(box_mesh(0.05), 400, rng=rng)
    mats = [np.eye(4)] + [
        make_transform(random_rotation(rng), rng.normal(0.0, 0.003, 3)) for _ in range(15)
    ]
    batch = batch_inlier_fractions(surface, scene, np.stack(mats), 0.002)
    brute = [score_pose(surface, scene, T, 0.002)[1] for T in mats]
    np.testing.assert_allclose(batch, brute, atol=1e-12)
    assert batch[0] > 0.99 and batch[1:].max() < batch[0]
    # on the lookup grid: the compiled pass and numpy count the same inliers, and both
    # agree with score_pose on that grid
    surface.with_lookup()
    on_grid = [score_pose(surface, scene, T, 0.002)[1] for T in mats]
    for compiled in (True, False):
        batch = batch_inlier_fractions(surface, scene, np.stack(mats), 0.002, compiled=compiled)
        np.testing.assert_allclose(batch, on_grid, atol=1e-12)
    # (the grid's sample is the one nearest its cell's centre: the true pose may lose a
    # point or two of the 400 to it)
    assert on_grid[0] >= 0.99 and max(on_grid[1:]) < on_grid[0]


def test_compiled_score_pose_equals_numpys() -> None:
    """score_pose's compiled pass (on the lookup grid) gives numpy's inlier fraction and its
    score and RMS residual to ~1e-12 (its own rounding), near the truth and off it; without
    the grid, or when the reach exceeds the grid's margin, it is numpy's path."""
    from mks_sim.lowlevel import _gridknn

    if not _gridknn.available():
        pytest.skip("numba unavailable")
    rng = np.random.default_rng(12)
    pts, nrm = sample_surface(box_mesh(0.05), 3000, rng=rng)
    surface = ModelSurface.from_arrays(pts, nrm)
    scene, _ = sample_surface(box_mesh(0.05), 1500, rng=rng)
    scene = scene + rng.normal(0.0, 3e-4, scene.shape)
    mats = [np.eye(4)] + [
        make_transform(random_rotation(rng) if k % 3 == 0 else np.eye(3), rng.normal(0, 0.002, 3))
        for k in range(30)
    ]
    no_grid = [score_pose(surface, scene, T, 0.002, compiled=True) for T in mats]
    assert no_grid == [score_pose(surface, scene, T, 0.002) for T in mats]
    surface.with_lookup()
    for T in mats:
        want = score_pose(surface, scene, T, 0.002)
        got = score_pose(surface, scene, T, 0.002, compiled=True)
        assert got[1] == want[1]  # the same inliers
        np.testing.assert_allclose(got, want, rtol=1e-12, atol=1e-15)
    assert score_pose(surface, scene, mats[0], 0.002, compiled=True)[1] > 0.95
    empty = score_pose(surface, scene + 1.0, mats[0], 0.002, compiled=True)  # nothing near
    assert empty == (0.0, 0.0, float("inf"))


def test_batch_explained_counts_model_samples_near_the_scene() -> None:
    from scipy.spatial import cKDTree

    rng = np.random.default_rng(3)
    model = rng.uniform(-0.02, 0.02, (200, 3))
    shift = make_transform(np.eye(3), [0.1, 0.0, 0.0])
    scene_tree = cKDTree(model)
    counts = batch_explained(model, np.stack([np.eye(4), shift]), scene_tree, 1e-6)
    assert counts.tolist() == [200, 0]


def test_representation_finds_table_objects_and_cube_vertexes() -> None:
    rep = Representation(_scene(), RepresentationConfig(table_z_m=TABLE_Z, gap_m=0.012))
    assert rep.table is not None and abs(rep.table.normal[2]) > 0.999
    assert np.all(rep.objects[:, 2] > TABLE_Z + rep.table_threshold - 1e-9)
    comps = rep.components(30)
    assert len(comps) == 2  # the cube and the sphere
    cube = max(comps, key=lambda c: -abs(rep.objects[c, 0].mean() - 0.05))
    verts, planes = rep.vertexes_of(cube)
    corners = np.array([[x, y, z] for x in (-1, 1) for y in (-1, 1) for z in (-1, 1)]) * 0.025
    corners += [0.05, -0.03, TABLE_Z + 0.025]
    d = np.linalg.norm(verts.points[:, None] - corners[None], axis=2).min(axis=0)
    assert np.all(d < 0.003), d  # every corner: top ones from three faces, bottom with the table
    assert len(planes) == 5
    sphere_regions = [r for r in rep.segmentation.curved if r.sphere is not None]
    assert any(abs(r.sphere.radius - 0.03) < 0.002 for r in sphere_regions)


def test_representation_of_is_shared_per_array_and_config() -> None:
    pts = _scene()
    cfg = RepresentationConfig(table_z_m=TABLE_Z)
    a = representation_of(pts, cfg)
    assert representation_of(pts, cfg) is a
    assert representation_of(pts, RepresentationConfig()) is not a
    assert representation_of(pts.copy(), cfg) is not a


def test_each_piece_is_computed_once(monkeypatch: pytest.MonkeyPatch) -> None:
    import mks_sim.lowlevel.normals as normals_mod
    import mks_sim.lowlevel.regions as regions_mod

    calls = {"normals": 0, "segment": 0}
    real_normals, real_segment = normals_mod.estimate_normals, regions_mod.segment_surfaces

    def count_normals(*a, **k):  # type: ignore[no-untyped-def]
        calls["normals"] += 1
        return real_normals(*a, **k)

    def count_segment(*a, **k):  # type: ignore[no-untyped-def]
        calls["segment"] += 1
        return real_segment(*a, **k)

    monkeypatch.setattr(normals_mod, "estimate_normals", count_normals)
    monkeypatch.setattr(regions_mod, "segment_surfaces", count_segment)
    rep = Representation(_scene(), RepresentationConfig(table_z_m=TABLE_Z, gap_m=0.012))
    for comp in rep.components():
        rep.vertexes_of(comp)
        rep.vertexes_of(comp)
    _ = rep.segmentation.curved, rep.normals.curvature
    assert calls == {"normals": 1, "segment": 1}


def test_a_segment_and_its_component_intersect_their_faces_once(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    """The Vertex_Detector's component and the object segment holding the same points (the
    cube) share one plane-vertex intersection, and a segment intersects its faces only when
    its vertexes are asked for; the vertexes are the cube's 8 corners (top ones from three
    faces, bottom ones with the table)."""
    import mks_sim.lowlevel.vertexes as vertexes_mod
    from mks_sim.localization.pipeline import object_segments

    calls: list[int] = []
    real = vertexes_mod.plane_vertexes

    def count(planes, *a, **k):  # type: ignore[no-untyped-def]
        calls.append(len(planes))
        return real(planes, *a, **k)

    monkeypatch.setattr(vertexes_mod, "plane_vertexes", count)
    rep = Representation(_scene(), RepresentationConfig(table_z_m=TABLE_Z, gap_m=0.012))
    segments = object_segments(rep, 0.0866)
    assert calls == []  # none until asked for
    cube_seg = min(segments, key=lambda s: abs(s.points[:, 0].mean() - 0.05))
    comp = next(c for c in rep.components(30) if set(rep.objects[c, 0].round(9)) ==
                set(cube_seg.points[:, 0].round(9)))  # fmt: skip
    verts, planes = rep.vertexes_of(comp)
    assert len(calls) == 1
    assert verts is cube_seg.vertexes and tuple(planes) == cube_seg.planes
    n_segment_calls = len(calls)  # no second intersection
    corners = np.array([[x, y, z] for x in (-1, 1) for y in (-1, 1) for z in (-1, 1)]) * 0.025
    corners += [0.05, -0.03, TABLE_Z + 0.025]
    d = np.linalg.norm(verts.points[:, None] - corners[None], axis=2).min(axis=0)
    assert np.all(d < 0.003), d
    # other planes (one face left out): a new intersection
    rep.plane_vertexes(planes[1:], True)
    assert len(calls) == n_segment_calls + 1


def test_contenders_leave_out_candidates_far_below_a_consistent_best() -> None:
    """Only when the best-scored candidate is consistent are those scoring more than
    CHECK_MARGIN below it left unchecked; the others are all kept."""
    from mks_sim.localization.pipeline import CHECK_MARGIN, _contenders
    from mks_sim.localization.verify import Consistency
    from mks_sim.models.pose import PoseHypothesis

    def hyp(score: float) -> PoseHypothesis:
        return PoseHypothesis(np.eye(4), np.zeros(3), votes=1, score=score)

    def verdict(ok: bool) -> Consistency:
        return Consistency(explained=100, inside=0 if ok else 50, below=0, penetration=0.0,
                           unexplained=0, ok=ok)  # fmt: skip

    hyps = [hyp(0.99), hyp(0.99 - CHECK_MARGIN + 0.01), hyp(0.99 - CHECK_MARGIN - 0.01)]
    checked: list[PoseHypothesis] = []

    def check_ok(h: PoseHypothesis) -> Consistency:
        checked.append(h)
        return verdict(True)

    assert _contenders(hyps, check_ok) == hyps[:2]
    assert checked == [hyps[0]]  # only the best is checked to decide
    assert _contenders(hyps, lambda h: verdict(False)) == hyps
    assert _contenders([], check_ok) == []


def test_segments_are_verified_most_promising_first_and_stop_when_settled() -> None:
    """A 5 cm cube and a 9 x 6 x 3 cm box on a table, the box's segment the larger: the
    cube's segment is verified first (its vertex hypotheses explain it, the box's only in
    part) and, when the caller says the candidates so far settle it, the box's is never
    verified; the best candidate is the cube's pose the points were sampled at. Without the
    callback both segments are verified."""
    from mks_sim.localization.model import PolyhedralModel
    from mks_sim.localization.pipeline import object_segments, polyhedral_candidates

    rng = np.random.default_rng(2)
    cube_at = np.array([0.05, -0.03, TABLE_Z + 0.025])
    T = make_transform(np.eye(3), cube_at)
    cube, _ = sample_surface(box_mesh(0.05), 4000, rng=rng)
    cube = cube[cube[:, 2] > -0.0249] + cube_at
    box, _ = sample_surface(box_mesh((0.09, 0.06, 0.03)), 6000, rng=rng)
    box = box[box[:, 2] > -0.0149] + [-0.09, 0.05, TABLE_Z + 0.015]
    table = np.c_[rng.uniform(-0.2, 0.2, (15000, 2)), np.full(15000, TABLE_Z)]
    pts = np.vstack([table, cube, box]) + rng.normal(0.0, 2e-4, (15000 + len(cube) + len(box), 3))
    rep = Representation(pts, RepresentationConfig(table_z_m=TABLE_Z, gap_m=0.012))
    model = PolyhedralModel.from_mesh(box_mesh(0.05), "cube")
    segments = object_segments(rep, model.surface.size)
    assert len(segments) == 2
    box_seg = int(np.argmax([s.points[:, 0].mean() < 0 for s in segments]))
    assert len(segments[box_seg].points) > len(segments[1 - box_seg].points)
    asked: list[int] = []

    def settled(found: list) -> bool:  # type: ignore[type-arg]
        asked.append(len(found))
        return True

    hyps, seg_of = polyhedral_candidates(
        model, rep, segments, rng=np.random.default_rng(0), settled=settled
    )
    assert len(asked) == 1 and hyps
    assert set(seg_of) == {1 - box_seg}
    best = np.asarray(hyps[0].matrix)
    # modulo the cube's symmetry: the posed corners compared as sets
    A = model.vertexes @ best[:3, :3].T + best[:3, 3]
    B = model.vertexes @ T[:3, :3].T + T[:3, 3]
    assert np.max(np.min(np.linalg.norm(A[:, None] - B[None], axis=2), axis=1)) < 0.002
    _, seg_of_all = polyhedral_candidates(model, rep, segments, rng=np.random.default_rng(0))
    assert box_seg in seg_of_all


def test_lazy_plans_come_in_the_order_of_all_plans_sorted() -> None:
    """The segments' plans come in the order every plan computed and sorted by promise
    (ties in segment order, fragments left out) gives, and a full promise (1.0) is verified
    before the segments after it are planned: against that brute force on random promises
    with many ties."""
    from mks_sim.localization.pipeline import _LazyPlans

    rng = np.random.default_rng(11)
    for _ in range(300):
        n = int(rng.integers(0, 8))
        promise = rng.choice([0.0, 0.5, 0.9, 1.0, -1.0], size=n)  # -1: a fragment (no plan)
        planned: list[int] = []

        def plan(si: int, promise: np.ndarray = promise, planned: list[int] = planned) -> Any:
            planned.append(si)
            return None if promise[si] < 0 else (float(promise[si]), si, [], 0.0)

        want = sorted((si for si in range(n) if promise[si] >= 0), key=lambda si: -promise[si])
        plans = _LazyPlans(n, plan)
        got = []
        while (p := plans.next()) is not None:
            if not got:  # the first: planned up to the first full promise, no further
                full = [si for si in range(n) if promise[si] == 1.0]
                assert planned == list(range(full[0] + 1 if full else n))
            got.append(p[1])
        assert got == want
        assert planned == list(range(n))  # each segment planned once


def test_description_sensors_ask_for_the_flows_one_representation() -> None:
    """Every description sensor over ``Range_Points`` in ``sensors/`` asks for the same
    representation as the localization flow, so one snapshot builds it once. (A point budget
    set on Vertex_Detector alone gave Sphere_Detector a second, full-density representation:
    45 ms more per sphere localization.)"""
    from mks_sim.localization.workstation import _default_graph, workstation_representation
    from mks_sim.sensing.programs.points import representation_config

    graph = _default_graph()
    want = workstation_representation(graph)
    programs = {"surface_curvature", "vertex_detector", "control_point_detector"}
    programs.add("sphere_detector")
    seen = []
    for name, spec in graph.sensors.items():
        if spec.program in programs and tuple(spec.inputs) == ("Range_Points",):
            assert representation_config(spec.params) == want, name
            seen.append(name)
    assert len(seen) == 4, seen


def test_a_cloud_over_the_point_budget_is_voxel_averaged() -> None:
    """``max_points``: a cloud above the budget is averaged on a voxel grid of edge 1.1 x
    spacing x sqrt(N / max_points) (spacing: the median nearest-neighbour distance of the
    input); every averaged point lies within one voxel diagonal of an input point, there
    are fewer of them, and the cube and the sphere are still two objects. Under the budget
    nothing is averaged."""
    from scipy.spatial import cKDTree

    pts = _scene()
    tree = cKDTree(pts)
    rep = Representation(pts, RepresentationConfig(table_z_m=TABLE_Z, max_points=6000))
    spacing = float(np.median(tree.query(pts, k=2)[0][:, 1]))
    assert rep.voxel == pytest.approx(1.1 * spacing * np.sqrt(len(pts) / 6000), rel=0.1)
    assert len(rep.points) < 0.8 * len(pts)
    d, _ = tree.query(rep.points)
    assert d.max() <= np.sqrt(3) * rep.voxel
    assert len(rep.components()) == 2
    full = Representation(pts, RepresentationConfig(table_z_m=TABLE_Z))
    assert full.voxel == 0 and len(full.points) == len(pts)
    # max_voxel_spacings: the budget's edge is rep.voxel / spacing spacings; a cap below it
    # leaves the cloud alone, a cap above it lets the budget average
    ratio = rep.voxel / rep._raw_stats[0]
    for cap, averaged in ((0.9 * ratio, False), (1.1 * ratio, True)):
        cfg = RepresentationConfig(table_z_m=TABLE_Z, max_points=6000, max_voxel_spacings=cap)
        assert (Representation(pts, cfg).voxel > 0) is averaged, cap


def test_raw_points_of_an_averaged_representation_by_brute_force() -> None:
    """``raw_rows``: each raw point's row of the averaged points is the one whose voxel cell
    it falls in, and each averaged point is the mean of its raw points (brute force over the
    cells); ``raw_of`` a component gives exactly the raw points of its rows;
    ``raw_curvature`` is the two-ring variation of the raw object points over their own
    SPG (a tree's, brute force here) without edges between objects."""
    pts = _scene()
    rep = Representation(pts, RepresentationConfig(table_z_m=TABLE_Z, max_points=6000))
    assert rep.voxel > 0
    rows = rep.raw_rows
    cells = np.floor(rep.raw / rep.voxel).astype(np.int64)
    # one cell per row, and one row per cell
    keys = {tuple(c): r for c, r in zip(cells, rows, strict=True)}
    assert len(keys) == len(rep.points)
    for c, r in zip(cells, rows, strict=True):
        assert keys[tuple(c)] == r
    for d in range(3):
        mean = np.bincount(rows, weights=rep.raw[:, d]) / np.bincount(rows)
        np.testing.assert_allclose(mean, rep.points[:, d], atol=1e-12)
    comp = rep.components()[0]
    got = rep.raw_of(comp)
    want = rep.raw[np.isin(rows, rep.object_indices[comp])]
    np.testing.assert_array_equal(got, want)
    assert len(got) > len(comp)
    # the raw objects' curvature: two rings of their own SPG (by the tree here), edges
    # between objects (components over edges <= the gap) dropped
    from scipy import sparse
    from scipy.sparse import csgraph

    from mks_sim.lowlevel.normals import FixedGraph, estimate_normals
    from mks_sim.lowlevel.spg import SpatialProximityGraph

    raw = rep.raw_objects
    assert len(raw) == int(np.isin(rows, rep.object_indices).sum())
    adj = sparse.csr_array(SpatialProximityGraph(raw, m=12, method="tree").adjacency)
    short = adj.copy()
    short.data[short.data > rep.gap] = 0.0
    short.eliminate_zeros()
    _, lab = csgraph.connected_components(short, directed=False)
    coo = adj.tocoo()
    same = lab[coo.row] == lab[coo.col]
    graph = sparse.csr_array((coo.data[same], (coo.row[same], coo.col[same])), shape=adj.shape)
    want_c = estimate_normals(raw, FixedGraph(graph), curvature_rings=2).curvature
    np.testing.assert_allclose(rep.raw_curvature, want_c, rtol=1e-9, atol=1e-12)


def test_spacing_and_noise_match_a_brute_force_on_a_noisy_plane() -> None:
    """Spacing: the median nearest-neighbour distance; noise: the median over probes of the
    RMS distance of their 12 nearest neighbours from the fitted plane (numpy's eigvalsh on
    brute-force neighbourhoods as the reference); a plane sampled on a 2 mm grid with 0.1 mm
    noise gives about 2 mm and about 0.1 mm."""
    from mks_sim.localization.representation import spacing_and_noise

    rng = np.random.default_rng(5)
    g = np.arange(0.0, 0.2, 0.002)
    xy = np.stack(np.meshgrid(g, g), axis=-1).reshape(-1, 2)
    pts = np.c_[xy, rng.normal(0.0, 1e-4, len(xy))]
    spacing, noise = spacing_and_noise(pts, np.random.default_rng(0), probes=300)
    probe = pts[np.random.default_rng(0).choice(len(pts), 300, replace=False)]
    d = np.linalg.norm(probe[:, None] - pts[None], axis=2)
    nn = np.argsort(d, axis=1)[:, :12]
    nb = pts[nn] - pts[nn].mean(axis=1, keepdims=True)
    lam = np.linalg.eigvalsh(np.einsum("pki,pkj->pij", nb, nb) / 12)[:, 0]
    assert spacing == pytest.approx(np.median(np.sort(d, axis=1)[:, 1]), rel=1e-9)
    assert noise == pytest.approx(np.median(np.sqrt(np.clip(lam, 0, None))), rel=1e-6)
    assert 0.0018 < spacing < 0.0022 and 0.5e-4 < noise < 1.5e-4


def test_probe_knn_matches_brute_force_and_leaves_far_rows_to_the_tree(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    """The column grid's rows are a brute force's k nearest (the probe first, distances to
    the last bit); a probe far from everything (2 m off a 20 cm scan) is not proven within the
    rings and is left not done, and so are rows whose blocks a far outlier crowds;
    spacing_and_noise then answers them by a pass over all the points each (no tree is
    built) or, past ``_BRUTE_WORK`` distances, by a tree, and returns what a tree alone
    gives either way."""
    from scipy.spatial import cKDTree

    from mks_sim.localization.representation import spacing_and_noise
    from mks_sim.lowlevel import _gridknn

    if not _gridknn.available():
        pytest.skip("numba not importable")
    rng = np.random.default_rng(11)
    xy = rng.uniform(0.0, 0.2, (6000, 2))
    scan = np.c_[xy, 0.02 * np.sin(20 * xy[:, 0]) + rng.normal(0, 2e-4, len(xy))]
    box = rng.uniform(0.08, 0.12, (1500, 3))  # a dense block standing on it
    far = np.array([[2.0, 2.0, 0.0], [2.001, 2.0, 0.0]])
    pts = np.vstack([scan, box, scan[:5], far])  # 5 exact duplicates
    rows = np.r_[rng.choice(len(pts) - 2, 300, replace=False), len(pts) - 2]
    d, idx, done = _gridknn.probe_knn(pts, rows, 12)
    brute = np.sqrt(((pts[rows][:, None] - pts[None]) ** 2).sum(axis=2))
    want = np.lexsort((np.broadcast_to(np.arange(len(pts)), brute.shape), brute), axis=1)[:, :12]
    assert not done[-1] and done[:-1].all()
    np.testing.assert_array_equal(idx[:-1], want[:-1])
    np.testing.assert_array_equal(d[:-1], np.take_along_axis(brute, want, axis=1)[:-1])
    import numba  # the probes run in parallel chunks: the same rows on one thread

    old = numba.get_num_threads()
    numba.set_num_threads(1)
    try:
        d1, idx1, done1 = _gridknn.probe_knn(pts, rows, 12)
    finally:
        numba.set_num_threads(old)
    assert np.array_equal(done1, done) and np.array_equal(idx1[done], idx[done])
    assert np.array_equal(d1[done], d[done])
    # the rows left, by one pass over the points each: a tree's answers, to the bit
    bd, bi = _gridknn.brute_knn(pts, rows, 12)
    td, ti = cKDTree(pts).query(pts[rows], k=12)
    np.testing.assert_array_equal(bi[:-1], want[:-1])
    np.testing.assert_array_equal(bi[-1], ti[-1])
    np.testing.assert_array_equal(bd[-1], td[-1])
    import mks_sim.localization.representation as rep

    tree = cKDTree(pts)
    # one point 1 km off stretches the grid: the scan crowds a few columns, so its rows are
    # left not done rather than ranked against thousands of points each
    stretched = np.vstack([pts[:-2], [[1000.0, 1000.0, 0.0]]])
    _, _, done = _gridknn.probe_knn(stretched, rows[:-1], 12)
    assert not done.any()
    stretched_tree = cKDTree(stretched)
    with_tree = [
        spacing_and_noise(pts, np.random.default_rng(1), tree, probes=probes)
        for probes in (300, 20000)  # probes drawn, and every point a probe
    ] + [spacing_and_noise(stretched, np.random.default_rng(1), stretched_tree)]
    built: list[int] = []
    real_tree = rep._tree

    def counted(points: np.ndarray) -> cKDTree:
        built.append(len(points))
        return real_tree(points)

    monkeypatch.setattr(rep, "_tree", counted)
    for work in (rep._BRUTE_WORK, 0):  # passes for the rows left; then trees for them
        monkeypatch.setattr(rep, "_BRUTE_WORK", work)
        built.clear()
        got = [
            spacing_and_noise(pts, np.random.default_rng(1), probes=probes)
            for probes in (300, 20000)
        ] + [spacing_and_noise(stretched, np.random.default_rng(1))]
        assert got == with_tree
        # the far rows of the first two by passes; the stretched scan leaves all its 1500
        # probes (11 million distances): a tree
        assert len(built) >= 2 if work == 0 else built == [len(stretched)]


def test_compiled_plane_counts_equal_the_products() -> None:
    """``plane_counts`` (a RANSAC's inlier counts) equals the count of ``|P n - o| <=
    threshold`` by products, on planes through some of the points and random ones."""
    from mks_sim.lowlevel import _gridknn

    if not _gridknn.available():
        pytest.skip("numba unavailable")
    rng = np.random.default_rng(5)
    for _ in range(30):
        pts = rng.normal(size=(int(rng.integers(1, 3000)), 3)) * 0.05
        nrm = rng.normal(size=(64, 3))
        nrm /= np.linalg.norm(nrm, axis=1)[:, None]
        off = np.einsum("ij,ij->i", nrm, pts[rng.integers(0, len(pts), 64)])
        want = (np.abs(nrm @ pts.T - off[:, None]) <= 0.01).sum(axis=1)
        np.testing.assert_array_equal(_gridknn.plane_counts(nrm, off, pts, 0.01), want)


def test_neighbour_scatter_equals_numpys_sums_to_the_bit() -> None:
    """The compiled scatter sums of ``spacing_and_noise`` equal numpy's (the mean over the
    neighbours, the centred products summed per row) bit for bit, for neighbourhoods below,
    at and above numpy's 8-term pairwise block."""
    from mks_sim.lowlevel import _gridknn

    if not _gridknn.available():
        pytest.skip("numba unavailable")
    rng = np.random.default_rng(21)
    pts = rng.normal(size=(5000, 3)) * 0.01 + np.array([0.1, -0.2, 0.75])
    for k in (2, 3, 7, 8, 9, 12, 16, 17, 40):
        idx = rng.integers(0, len(pts), size=(300, k))
        nb = pts[idx]
        c = nb - nb.mean(axis=1, keepdims=True)
        want = np.stack(
            [(c[..., a] * c[..., b]).sum(axis=1) for a, b in
             ((0, 0), (0, 1), (0, 2), (1, 1), (1, 2), (2, 2))], axis=1
        )  # fmt: skip
        got = _gridknn.neighbour_scatter(pts, idx)
        assert np.array_equal(got, want), k


def test_voxel_average_compiled_equals_numpys_to_the_bit(monkeypatch: pytest.MonkeyPatch) -> None:
    """The compiled voxel centroids equal the numpy path's (unique cells in lexicographic
    order, sums in the points' order) bit for bit: coarse and fine voxels, rounded points
    on cell borders, one point, and scans listed row by row (runs of points in one cell,
    each cell met again on the next rows: the compiled path sorts the runs)."""
    from mks_sim.localization.representation import voxel_average
    from mks_sim.lowlevel import _gridknn

    if not _gridknn.available():
        pytest.skip("numba unavailable")
    rng = np.random.default_rng(27)
    cases = []
    for t in range(40):
        pts = rng.normal(size=(int(rng.integers(1, 30000)), 3)) * rng.uniform(0.01, 1.0)
        if t % 2:
            pts = np.round(pts, 3)  # many points on cell borders
        shift = (0.0, 0.5, 0.25)[t % 3]  # cells starting at, centred on, between
        cases.append((pts + rng.normal(size=3), float(rng.uniform(0.0005, 0.05)), shift))
    for t in range(8):  # range images row by row: 2-20 points a run
        w, h = int(rng.integers(40, 400)), int(rng.integers(30, 300))
        u, w_ = np.meshgrid(np.linspace(-0.1, 0.1, w), np.linspace(-0.08, 0.08, h))
        z = 0.4 + 0.05 * np.sin(9.0 * u) * np.cos(7.0 * w_) + rng.normal(0, 3e-4, u.shape)
        scan = np.stack([u * z, w_ * z, z], axis=-1).reshape(-1, 3)
        if t % 2:
            scan = np.round(scan, 4)
        cases.append((scan, float(0.2 / w * rng.uniform(1.5, 20.0)), (0.0, 0.5)[t % 2]))
    got = [voxel_average(p, v, shift=s) for p, v, s in cases]
    monkeypatch.setattr(_gridknn, "available", lambda: False)
    for (p, v, s), g in zip(cases, got, strict=True):
        want = voxel_average(p, v, shift=s)
        assert g.shape == want.shape and g.tobytes() == want.tobytes()
