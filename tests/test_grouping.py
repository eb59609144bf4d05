"""Grouping on the SPG: normals, curvature code, planar/curved regions, fits, vertexes."""

from __future__ import annotations

import itertools

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from mks_sim.errors import DataError
from mks_sim.geometry.meshes import box_mesh, sample_surface
from mks_sim.geometry.scan import synthetic_scan
from mks_sim.geometry.transforms import make_transform, random_rotation
from mks_sim.lowlevel.grouping import (
    PlanarRegion,
    Plane,
    build_graph,
    curvature_code,
    estimate_normals,
    fit_plane,
    fit_plane_ransac,
    fit_sphere,
    neighbour_table,
    plane_vertexes,
    segment_surfaces,
)

CUBE = 6.0  # the paper's cube (Table 4-7: side 2 units there; Table 4-5: side 6)
CUBE_CORNERS = np.array(list(itertools.product((-3.0, 3.0), repeat=3)))


def _sphere(n: int, radius: float, center: np.ndarray, rng: np.random.Generator) -> np.ndarray:
    v = rng.normal(size=(n, 3))
    return center + radius * v / np.linalg.norm(v, axis=1, keepdims=True)


def _cube(n: int, noise: float, rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
    pts, nrm = sample_surface(box_mesh(CUBE), n, rng=rng)
    return pts + rng.normal(0.0, noise, pts.shape), nrm


def test_normals_match_faces_and_face_viewpoint() -> None:
    rng = np.random.default_rng(1)
    pts, true_n = _cube(3000, 0.01, rng)
    sn = estimate_normals(pts)
    interior = np.sort(np.abs(pts), axis=1)[:, 1] < 2.5
    cos = np.einsum("ij,ij->i", sn.normals[interior], true_n[interior])
    assert np.mean(cos > np.cos(np.radians(5))) > 0.97  # oriented outward, accurate
    eye = np.array([0.0, 0.0, -50.0])
    flipped = estimate_normals(pts, viewpoint=eye).normals
    assert np.all(np.einsum("ij,ij->i", flipped, eye - pts) >= 0)


def test_neighbour_table_matches_graph_rows() -> None:
    rng = np.random.default_rng(2)
    pts = rng.uniform(size=(200, 3))
    g = build_graph(pts, m=6)
    idx, valid = neighbour_table(g)
    assert np.all(idx[:, 0] == np.arange(200))
    from scipy.spatial import cKDTree

    _, brute = cKDTree(pts).query(pts, k=7)
    for i in range(0, 200, 17):
        assert set(idx[i, valid[i]]) == set(brute[i])
    idx2, valid2 = neighbour_table(g, rings=2)
    assert valid2.sum(axis=1).mean() > 2 * valid.sum(axis=1).mean()


def test_curvature_code_separates_cube_from_sphere_like_table_4_6() -> None:
    # Table 4-5 / 4-6: sphere of radius 3 atop a cube of side 6; +1 curved, -1 planar.
    rng = np.random.default_rng(3)
    cube, _ = _cube(3000, 0.01, rng)
    sphere = _sphere(1500, 3.0, np.array([0.0, 0.0, 6.5]), rng) + rng.normal(0, 0.01, (1500, 3))
    pts = np.vstack([cube, sphere])
    # The paper separates objects by SPG connectivity first; do the same per object.
    cube_code = curvature_code(estimate_normals(cube).curvature)
    sphere_code = curvature_code(estimate_normals(sphere).curvature)
    face_interior = np.sort(np.abs(cube), axis=1)[:, 1] < 3.0 - 1.2
    assert np.mean(cube_code[face_interior] == -1) > 0.9
    assert np.mean(sphere_code == 1) > 0.98
    # The paper's Table 4-5 sample points get the paper's codes.
    paper = np.array([[0.0, 0.0, 3.0], [-1.76, 0.0, 2.43], [2.31, 1.68, 0.93]])
    assert np.all(np.linalg.norm(paper, axis=1) == pytest.approx(3.0, abs=0.02))
    assert pts.shape == (4500, 3)


def test_segment_cube_into_six_faces_with_true_planes() -> None:
    rng = np.random.default_rng(4)
    pts, _ = _cube(3000, 0.01, rng)
    seg = segment_surfaces(pts)
    assert len(seg.planes) == 6
    assert not seg.curved or all(len(c.indices) < 200 for c in seg.curved)
    for region in seg.planes:
        n = region.normal
        axis = int(np.argmax(np.abs(n)))
        assert abs(n[axis]) > np.cos(np.radians(1.0))
        # outward normal; face at +-3 along the axis: n . x = 3
        assert region.plane.offset == pytest.approx(3.0, abs=0.01)
        assert region.plane.rmse == pytest.approx(0.01, rel=0.3)
        assert len(region.indices) > 300


def test_sphere_fit_recovers_centre_and_radius() -> None:
    rng = np.random.default_rng(5)
    center = np.array([1.0, -2.0, 0.5])
    pts = _sphere(800, 2.5, center, rng) + rng.normal(0, 0.02, (800, 3))
    fit = fit_sphere(pts)
    assert np.linalg.norm(fit.center - center) < 0.01
    assert fit.radius == pytest.approx(2.5, abs=0.01)
    assert fit.rmse == pytest.approx(0.02, rel=0.2)
    # a cap (one-sided view) still works
    cap = pts[pts[:, 2] > center[2] + 1.0]
    fit = fit_sphere(cap)
    assert fit.radius == pytest.approx(2.5, abs=0.05)


@pytest.mark.parametrize("compiled", [True, False])
def test_sphere_fit_refinement_compiled_and_numpy_find_one_sphere(compiled: bool) -> None:
    """The Levenberg-Marquardt refinement in one compiled call and by numpy: both recover
    caps of noisy spheres (20 seeds, 60-1,500 points, caps from a tenth to most of the
    sphere) to the truth's noise, and agree with each other to a millionth of the radius
    (their steps are the same; the normal equations' sums round in their own order)."""
    from mks_sim.lowlevel import _gridknn

    if compiled and not _gridknn.available():
        pytest.skip("numba unavailable")
    rng = np.random.default_rng(12)
    for _ in range(20):
        n = int(rng.integers(60, 1500))
        center = rng.normal(size=3)
        radius = float(rng.uniform(0.01, 2.0))
        pts = _sphere(4 * n, radius, center, rng)
        pts = pts[pts[:, 2] > center[2] + rng.uniform(-0.5, 0.8) * radius][:n]
        if len(pts) < 50:
            continue
        pts = pts + rng.normal(0, 0.005 * radius, pts.shape)
        fit = fit_sphere(pts, compiled=compiled)
        other = fit_sphere(pts, compiled=not compiled)
        assert np.linalg.norm(fit.center - center) < 0.05 * radius
        assert fit.radius == pytest.approx(radius, rel=0.05)
        assert np.linalg.norm(fit.center - other.center) < 1e-6 * radius
        assert fit.radius == pytest.approx(other.radius, rel=1e-6)
        assert fit.rmse == pytest.approx(other.rmse, rel=1e-6)
        # the refinement improved on the algebraic start: the radial rmse is the truth's noise
        assert fit.rmse == pytest.approx(0.005 * radius, rel=0.25)


def test_curved_region_of_cube_and_sphere_scene() -> None:
    rng = np.random.default_rng(6)
    cube, _ = _cube(3000, 0.005, rng)
    sphere = _sphere(1500, 3.0, np.array([0.0, 0.0, 12.0]), rng)
    seg = segment_surfaces(np.vstack([cube, sphere]), viewpoint=np.array([20.0, 20.0, 40.0]))
    big = [c for c in seg.curved if len(c.indices) > 500]
    assert len(big) == 1 and big[0].sphere is not None
    assert big[0].sphere.radius == pytest.approx(3.0, abs=0.02)
    assert np.linalg.norm(big[0].sphere.center - [0, 0, 12]) < 0.02
    assert len(seg.planes) == 6
    # without the curved regions (localize_cloud's grouping): the same planar regions
    flat = segment_surfaces(
        np.vstack([cube, sphere]), viewpoint=np.array([20.0, 20.0, 40.0]), curved=False
    )
    assert flat.curved == () and np.array_equal(flat.labels, seg.labels)
    assert [p.indices.tolist() for p in flat.planes] == [p.indices.tolist() for p in seg.planes]


def test_robust_plane_fits_reject_outliers() -> None:
    rng = np.random.default_rng(7)
    xy = rng.uniform(-1, 1, (500, 2))
    pts = np.column_stack([xy, 0.3 * xy[:, 0] + 0.1 + rng.normal(0, 0.001, 500)])
    pts[:50, 2] += rng.uniform(0.2, 1.0, 50)  # 10 % gross outliers
    truth = np.array([-0.3, 0.0, 1.0]) / np.linalg.norm([-0.3, 0.0, 1.0])
    for plane in (fit_plane(pts), fit_plane_ransac(pts, 0.005, rng)[0]):
        assert abs(plane.normal @ truth) > np.cos(np.radians(0.2))
        assert plane.rmse < 0.002
    _, inliers = fit_plane_ransac(pts, 0.005, rng)
    assert inliers[50:].mean() > 0.99 and inliers[:50].mean() < 0.05


def test_the_compiled_plane_fit_takes_numpys_steps() -> None:
    """``fit_plane(compiled=True)``: the same outlier rejection (the same kept points give
    the same residual) and the same plane to rounding, on tilted noisy patches with gross
    outliers, from 20 to 5,000 points (and the 1-iteration least-squares fit)."""
    from mks_sim.lowlevel import _gridknn

    if not _gridknn.available():
        pytest.skip("needs numba")
    rng = np.random.default_rng(8)
    for trial in range(60):
        n = int(rng.integers(20, 5000))
        flat = np.column_stack([rng.uniform(-0.05, 0.05, (n, 2)), rng.normal(0, 3e-4, n)])
        bad = rng.random(n) < 0.1
        flat[bad, 2] += rng.uniform(-0.01, 0.01, int(bad.sum()))
        pts = flat @ random_rotation(rng).T + rng.normal(0, 0.1, 3)
        for iterations in (3, 1):
            a = fit_plane(pts, iterations)
            b = fit_plane(pts, iterations, compiled=True)
            sign = 1.0 if a.normal @ b.normal > 0 else -1.0
            assert np.abs(a.normal - sign * b.normal).max() < 1e-12, trial
            assert abs(a.offset - sign * b.offset) < 1e-12 and abs(a.rmse - b.rmse) < 1e-12


def test_all_eight_cube_vertexes_from_full_sample() -> None:
    rng = np.random.default_rng(8)
    pts, _ = _cube(4000, 0.01, rng)
    seg = segment_surfaces(pts)
    v = plane_vertexes(seg.planes, pts, tolerance=5 * seg.spacing)
    assert len(v) == 8
    d = np.linalg.norm(v.points[:, None] - CUBE_CORNERS[None], axis=2)
    assert sorted(np.argmin(d, axis=1)) == list(range(8))
    assert d.min(axis=1).max() < 0.03
    # the face normals at each vertex point out of the cube at that corner
    for p, nrm in zip(v.points, v.normals):
        assert np.all(nrm @ np.sign(p) > 0.99)


def test_visible_vertexes_from_one_sided_scan_with_table_plane() -> None:
    size = 0.05
    angle = np.radians(25.0)
    R = np.array([[np.cos(angle), -np.sin(angle), 0], [np.sin(angle), np.cos(angle), 0], [0, 0, 1]])
    T = make_transform(R, [0.01, -0.02, size / 2])
    eye = np.array([0.3, 0.25, 0.3])
    rng = np.random.default_rng(9)
    pts = synthetic_scan(
        box_mesh(size),
        T,
        eye,
        [0.01, -0.02, 0.0],
        width=200,
        height=150,
        fov_deg=25,
        noise_sigma=0.0002,
        rng=rng,
    )
    seg = segment_surfaces(pts, viewpoint=eye)
    assert len(seg.planes) == 3  # top and two sides
    table = Plane(np.array([0.0, 0.0, -1.0]), 0.0)  # out of the object, i.e. down
    without = plane_vertexes(seg.planes, pts, tolerance=5 * seg.spacing)
    with_table = plane_vertexes(seg.planes, pts, extra_planes=[table], tolerance=5 * seg.spacing)
    corners = (T @ np.column_stack([CUBE_CORNERS / CUBE * size, np.ones(8)]).T).T[:, :3]
    # visible: the corner nearest the eye on top, and (with the table) the one below it
    top = corners[np.argmin(np.linalg.norm(corners - eye, axis=1))]
    expected = np.stack([top, top - [0.0, 0.0, size]])
    assert len(without) == 1
    assert np.linalg.norm(without.points[0] - top) < 0.001
    assert len(with_table) == 2
    d = np.linalg.norm(with_table.points[:, None] - expected[None], axis=2)
    assert d.min(axis=0).max() < 0.001


def test_bad_input_raises_clear_errors() -> None:
    with pytest.raises(DataError, match=r"expected shape \(N, 3\)"):
        estimate_normals(np.zeros((10, 2)))
    with pytest.raises(DataError, match="NaN"):
        segment_surfaces(np.full((10, 3), np.nan))
    with pytest.raises(DataError, match="at least 4"):
        fit_sphere(np.zeros((3, 3)))
    with pytest.raises(DataError, match="sphere"):
        fit_sphere(np.column_stack([np.random.default_rng(0).uniform(size=(20, 2)), np.zeros(20)]))
    with pytest.raises(DataError, match="tolerance"):
        plane_vertexes([], np.zeros((5, 3)), tolerance=0.0)
    with pytest.raises(DataError, match="seeds"):
        segment_surfaces(np.random.default_rng(0).uniform(size=(20, 3)), seeds="some")


@settings(max_examples=25)
@given(
    st.floats(-5, 5), st.floats(-5, 5), st.floats(-5, 5), st.floats(0.2, 10.0), st.integers(0, 99)
)
def test_fit_sphere_property(cx: float, cy: float, cz: float, r: float, seed: int) -> None:
    rng = np.random.default_rng(seed)
    c = np.array([cx, cy, cz])
    fit = fit_sphere(_sphere(200, r, c, rng))
    assert np.linalg.norm(fit.center - c) < 1e-6 * max(1.0, r)
    assert fit.radius == pytest.approx(r, rel=1e-6)


@settings(max_examples=25)
@given(st.integers(0, 10_000))
def test_vertex_of_three_sampled_planes_is_their_corner(seed: int) -> None:
    # Three faces of a randomly posed corner, sampled near it: the vertex is the corner.
    rng = np.random.default_rng(seed)
    R = random_rotation(rng)
    corner = rng.uniform(-1, 1, 3)
    regions, pts = [], []
    for axis in range(3):
        uv = rng.uniform(0.05, 1.0, (150, 2))
        local = np.zeros((150, 3))
        others = [a for a in range(3) if a != axis]
        local[:, others[0]], local[:, others[1]] = uv[:, 0], uv[:, 1]
        p = corner + local @ R.T
        n = -R[:, axis]  # outward for the octant the faces bound
        idx = np.arange(len(pts) * 150, (len(pts) + 1) * 150)
        regions.append(PlanarRegion(idx, Plane(n, float(n @ corner)), p.mean(axis=0)))
        pts.append(p)
    v = plane_vertexes(regions, np.vstack(pts), tolerance=0.5)
    assert len(v) == 1
    assert np.linalg.norm(v.points[0] - corner) < 1e-9


@pytest.mark.parametrize("rings", [1, 2, 3])
def test_ring_matrix_is_brute_force_reachability(rings: int) -> None:
    """Row i of the ring matrix is i, its SPG row (ring 1) or every point within ``rings``
    undirected SPG hops (breadth-first over a dense adjacency)."""
    from mks_sim.lowlevel.normals import _ring_matrix

    rng = np.random.default_rng(7)
    g = build_graph(rng.uniform(size=(150, 3)), m=5)
    directed = g.adjacency.toarray() > 0
    got = _ring_matrix(g, rings).toarray()
    assert set(np.unique(got)) <= {0.0, 1.0}
    for i in range(150):
        if rings == 1:
            want = directed[i].copy()
        else:
            undirected = directed | directed.T
            want = np.zeros(150, dtype=bool)
            frontier = np.zeros(150, dtype=bool)
            frontier[i] = True
            for _ in range(rings):
                frontier = undirected[frontier].any(axis=0) & ~want
                want |= frontier
        want[i] = True
        assert np.array_equal(got[i] > 0, want), i


def test_compiled_region_growing_matches_numpy_loop() -> None:
    """The numba kernel grows exactly the regions of the numpy reference loop (noisy cube and
    sphere: many seeds, plane refits)."""
    from scipy import sparse

    from mks_sim.lowlevel import _gridknn
    from mks_sim.lowlevel._regions_kernels import grow_regions
    from mks_sim.lowlevel.regions import _grow

    if not _gridknn.available():
        pytest.skip("numba not importable")
    rng = np.random.default_rng(3)
    cube, _ = _cube(2500, 0.05, rng)
    pts = np.vstack([cube, _sphere(1500, 2.0, np.array([8.0, 0.0, 0.0]), rng)])
    g = build_graph(pts, m=12)
    sn = estimate_normals(pts, g)
    adj = sparse.csr_array(g.adjacency)
    adj = sparse.csr_array(adj + adj.T)
    order = np.argsort(sn.curvature, kind="stable")
    for allowed in (curvature_code(sn.curvature) < 0, np.ones(len(pts), dtype=bool)):
        args = (sn.normals, allowed, order, float(np.cos(np.radians(12.0))), 0.2)
        want, n_want = _grow(adj, pts, *args, compiled=False)
        got, n_got = grow_regions(
            adj.indptr.astype(np.int64), adj.indices.astype(np.int64), pts, *args
        )
        assert n_got == n_want >= 6
        assert np.array_equal(got, want)


def test_compiled_boundary_absorption_matches_numpy_passes() -> None:
    """The numba kernel gives the unlabelled edge points the same planes as the numpy
    reference passes (noisy cube: regions grown, their planes fitted), and some are given."""
    from mks_sim.lowlevel import _gridknn
    from mks_sim.lowlevel.regions import _absorb_boundary, fit_plane, symmetric_adjacency

    if not _gridknn.available():
        pytest.skip("numba not importable")
    from mks_sim.lowlevel.regions import _grow

    rng = np.random.default_rng(4)
    pts, _ = _cube(3000, 0.05, rng)
    g = build_graph(pts, m=12)
    sn = estimate_normals(pts, g)
    order = np.argsort(sn.curvature, kind="stable")
    grown, count = _grow(
        symmetric_adjacency(g), pts, sn.normals, curvature_code(sn.curvature) < 0, order,
        float(np.cos(np.radians(12.0))), 0.2, compiled=False,
    )  # fmt: skip
    sizes = np.bincount(grown[grown >= 0], minlength=count)
    keep = np.flatnonzero(sizes >= 40)
    labels = np.full(len(pts), -1, dtype=np.intp)
    for rid, r in enumerate(keep):
        labels[grown == r] = rid
    planes = [fit_plane(pts[labels == rid]) for rid in range(len(keep))]
    want, got = labels.copy(), labels.copy()
    _absorb_boundary(pts, g, want, planes, 0.1, compiled=False)
    _absorb_boundary(pts, g, got, planes, 0.1, compiled=True)
    assert np.array_equal(got, want)
    assert np.count_nonzero(want >= 0) > np.count_nonzero(labels >= 0)


def test_compiled_ring_moments_match_sparse_ring_matrix() -> None:
    """Two- and three-ring normals and surface variation of the compiled kernel equal the
    sparse reference (PCA over the rows of the ring matrix)."""
    from mks_sim.lowlevel import _gridknn
    from mks_sim.lowlevel.normals import _pca_sparse, _ring_matrix, _ring_pca

    if not _gridknn.available():
        pytest.skip("numba not importable")
    rng = np.random.default_rng(5)
    pts, _ = _cube(1500, 0.02, rng)
    g = build_graph(pts, m=8)
    for rings in (2, 3):
        nrm, curv = _ring_pca(pts, g, rings)
        want_n, want_c = _pca_sparse(pts, _ring_matrix(g, rings))
        assert np.allclose(curv, want_c, atol=1e-10)
        assert np.all(np.abs(np.einsum("ij,ij->i", nrm, want_n)) > 1.0 - 1e-9)


def test_compiled_one_ring_covariances_equal_the_sparse_products_to_the_bit() -> None:
    """One-ring covariances by the compiled pass equal the sparse products over the ring
    matrix bit for bit (the SPG's rows, the symmetric closure's); a graph with a self entry
    or an unsorted row is left to the sparse products (the same values too)."""
    from scipy import sparse

    from mks_sim.lowlevel import _gridknn
    from mks_sim.lowlevel.normals import FixedGraph, _ring_cov, _ring_matrix, _sparse_cov

    if not _gridknn.available():
        pytest.skip("numba not importable")
    rng = np.random.default_rng(7)
    pts, _ = _cube(1500, 0.02, rng)
    g = FixedGraph(build_graph(pts, m=8).adjacency)
    for graph in (g, FixedGraph(g.symmetric)):
        want = _sparse_cov(pts, _ring_matrix(graph, 1))
        assert _gridknn.ring1_cov(graph.adjacency, pts - pts.mean(axis=0)) is not None
        assert np.array_equal(_ring_cov(pts, graph, 1), want)
    adj = sparse.csr_array(g.adjacency, copy=True)
    adj.data[:] = 1.0
    looped = FixedGraph(sparse.csr_array(adj + sparse.eye_array(len(pts), format="csr")))
    assert _gridknn.ring1_cov(looped.adjacency, pts) is None
    assert np.array_equal(_ring_cov(pts, looped, 1), _sparse_cov(pts, _ring_matrix(looped, 1)))


def test_compiled_ring_moments_do_not_depend_on_the_threads() -> None:
    """The parallel kernel gives the same moments, to the bit, on one thread and on all,
    and on any number of chunks (each point's ring and sums are its own arithmetic; 4 and 5
    threads cut 6 chunks to a multiple of the threads)."""
    import numba

    from mks_sim.lowlevel import _gridknn
    from mks_sim.lowlevel.normals import symmetric_adjacency

    if not _gridknn.available():
        pytest.skip("numba not importable")
    from mks_sim.lowlevel._regions_kernels import ring_moments

    rng = np.random.default_rng(8)
    pts, _ = _cube(3000, 0.02, rng)
    sym = symmetric_adjacency(build_graph(pts, m=8))
    args = (sym.indptr.astype(np.int64), sym.indices.astype(np.int64), pts - pts.mean(axis=0))
    before = numba.get_num_threads()
    try:
        numba.set_num_threads(1)
        one = ring_moments(*args, 2, 1)
        numba.set_num_threads(numba.config.NUMBA_NUM_THREADS)
        runs = [ring_moments(*args, 2, t) for t in (1, 2, 3, 4, 5, 8)]
    finally:
        numba.set_num_threads(before)
    assert all(np.array_equal(r, one) for r in runs)
    # and the moments are those of the two-ring neighbourhood, brute force for a few points
    for i in (0, 1234, 2999):
        ring1 = set(sym.indices[sym.indptr[i] : sym.indptr[i + 1]]) | {i}
        ring2 = set(ring1)
        for q in ring1:
            ring2 |= set(sym.indices[sym.indptr[q] : sym.indptr[q + 1]])
        nb = args[2][sorted(ring2)]
        cov = np.cov(nb.T, bias=True)
        want = cov[np.triu_indices(3)]
        assert np.allclose(one[i], want, atol=1e-12)
    # a ring that holds every point (the kernel writes one slot past the ring as it goes):
    # a path of 6 points, 3 rings reach all of them from its middle
    path = np.array([[float(i), 0.1 * i * i, 0.0] for i in range(6)])
    ptr = np.array([0, 1, 3, 5, 7, 9, 10], dtype=np.int64)
    idx = np.array([1, 0, 2, 1, 3, 2, 4, 3, 5, 4], dtype=np.int64)
    c = path - path.mean(axis=0)
    got = ring_moments(ptr, idx, c, 3, 1)
    for i, members in ((2, range(6)), (0, range(4))):  # 3 hops from 2: all; from 0: 0..3
        want = np.cov(c[list(members)].T, bias=True)[np.triu_indices(3)]
        assert np.allclose(got[i], want, atol=1e-12)


def test_warm_up_kernels_says_whether_the_compiled_paths_run() -> None:
    from mks_sim.lowlevel import _gridknn
    from mks_sim.lowlevel.regions import warm_up_kernels

    assert warm_up_kernels() is _gridknn.available()


def test_no_writable_numba_cache_falls_back_to_numpy_paths() -> None:
    """Where numba finds no writable cache folder it refuses to define ``cache=True`` kernels
    (RuntimeError at import): the low level then runs its numpy paths, with the same regions,
    instead of failing (a fresh process, with numba's cache locators emptied)."""
    import subprocess
    import sys

    pytest.importorskip("numba")
    code = """
import numpy as np
from numba.core import caching
impl = getattr(caching, "CacheImpl", None) or getattr(caching, "_CacheImpl")
impl._locator_classes = []  # no writable place for machine code
from mks_sim.lowlevel import _gridknn
from mks_sim.lowlevel.regions import segment_surfaces, warm_up_kernels
assert warm_up_kernels() is False and _gridknn.available() is False
rng = np.random.default_rng(0)
u = rng.uniform(-1, 1, (2, 900))
pts = np.concatenate([np.c_[u[0], u[1], np.zeros(900)], np.c_[u[0], np.zeros(900), u[1] + 1.2]])
seg = segment_surfaces(pts, m=12)
print(len(seg.planes))
"""
    out = subprocess.run(
        [sys.executable, "-c", code], capture_output=True, text=True, timeout=300, check=False
    )
    assert out.returncode == 0, out.stderr[-2000:]
    assert out.stdout.split()[-1] == "2"


def test_median_by_one_partition_is_numpys_median() -> None:
    """regions._median gives np.median's value to the bit, odd and even lengths."""
    from mks_sim.lowlevel.regions import _median

    rng = np.random.default_rng(8)
    for n in (1, 2, 3, 10, 11, 1000, 1001):
        x = rng.normal(size=n)
        assert _median(x) == float(np.median(x))


def test_column_mean_is_numpys_axis0_mean_to_the_bit() -> None:
    """``column_mean`` gives ``a.mean(axis=0)`` bit for bit: the compiled loop for 2-8
    columns (numpy adds their rows in order), numpy itself for one column (added pairwise),
    short, strided or float32 arrays."""
    from mks_sim.lowlevel import _gridknn
    from mks_sim.lowlevel._gridknn import column_mean

    if not _gridknn.available():
        pytest.skip("numba not importable")
    rng = np.random.default_rng(21)
    for _ in range(200):
        n, k = int(rng.integers(1, 20000)), int(rng.integers(1, 10))
        a = rng.normal(size=(n, k)) * rng.uniform(1e-3, 1e3) + rng.normal(size=k) * 100
        for arr in (a, a[rng.random(n) < 0.6], a[::2], a.astype(np.float32)):
            if len(arr):
                want = np.asarray(arr.mean(axis=0), dtype=np.float64)
                assert column_mean(arr).tobytes() == want.tobytes()
    for n in range(1, 600, 7):  # the short arrays of region fits, around the compiled bound
        a = rng.normal(size=(n, 3)) * 0.02 + np.array([0.1, -0.3, 0.77])
        assert column_mean(a).tobytes() == a.mean(axis=0).tobytes()


def test_column_bounds_are_numpys_min_and_max() -> None:
    """``column_bounds`` gives ``a.min(axis=0)`` and ``a.max(axis=0)``: the compiled pass
    for finite (N, 3) float64 rows, numpy's own rules where a NaN or inf is among them, and
    numpy for other shapes, dtypes and strides."""
    from mks_sim.lowlevel import _gridknn
    from mks_sim.lowlevel._gridknn import column_bounds

    if not _gridknn.available():
        pytest.skip("numba not importable")
    rng = np.random.default_rng(23)
    for _ in range(200):
        n, k = int(rng.integers(1, 5000)), int(rng.choice([2, 3, 3, 4]))
        a = rng.normal(size=(n, k)) * 10.0 ** rng.integers(-4, 4)
        if rng.random() < 0.3:
            a[rng.integers(0, n), rng.integers(0, k)] = rng.choice([np.nan, np.inf, -np.inf])
        for arr in (a, a[::2], a.astype(np.float32)):
            lo, hi = column_bounds(arr)
            np.testing.assert_array_equal(lo, arr.min(axis=0))
            np.testing.assert_array_equal(hi, arr.max(axis=0))


def test_row_norms_are_numpys_norms_to_the_bit() -> None:
    """``row_norms`` gives ``np.linalg.norm(a, axis=1)`` bit for bit (N x 3 by the three
    squares in order, other shapes by numpy)."""
    from mks_sim.lowlevel._gridknn import row_norms

    rng = np.random.default_rng(22)
    for _ in range(300):
        a = rng.normal(size=(int(rng.integers(0, 2000)), 3)) * 10.0 ** rng.integers(-5, 3)
        assert row_norms(a).tobytes() == np.linalg.norm(a, axis=1).tobytes()
    b = rng.normal(size=(50, 4))
    assert row_norms(b).tobytes() == np.linalg.norm(b, axis=1).tobytes()


def test_norm_within_takes_the_rows_numpys_norm_takes() -> None:
    """``norm_within`` returns the rows ``np.linalg.norm(points - c, axis=1) <= r`` keeps,
    radii set to some rows' own norms (the boundary) and one ulp either side of them
    included (the compiled pass takes roots only near the bound), and a zero radius."""
    from mks_sim.lowlevel._gridknn import norm_within

    rng = np.random.default_rng(26)
    for _ in range(200):
        pts = np.round(rng.normal(size=(int(rng.integers(0, 3000)), 3)) * 0.05, 4)
        c = np.round(rng.normal(size=3) * 0.02, 4)
        norms = np.linalg.norm(pts - c, axis=1)
        r = float(norms[rng.integers(len(norms))]) if len(norms) else 0.05
        for radius in (r, np.nextafter(r, 0.0), np.nextafter(r, np.inf), 0.0):
            np.testing.assert_array_equal(
                norm_within(pts, c, float(radius)), np.flatnonzero(norms <= radius)
            )
    nan = np.array([[0.0, 0.0, 0.0], [np.nan, 0.0, 0.0], [0.01, 0.0, 0.0]])  # NaN is not in
    np.testing.assert_array_equal(norm_within(nan, np.zeros(3), 0.05), [0, 2])


def test_median_is_numpys_median() -> None:
    """``_gridknn.median`` equals ``np.median``: odd and even counts, short arrays (one
    partition), long ones (bins), heavy ties, constant arrays, and a bin holding most of
    the values (left to the partition)."""
    from mks_sim.lowlevel._gridknn import median

    rng = np.random.default_rng(23)
    for t in range(120):
        n = int(rng.integers(1, 60000)) if t % 3 else int(rng.integers(1, 50))
        x = np.round(rng.gamma(2.0, 0.001, size=n), int(rng.integers(3, 8)))
        if t % 10 == 0:
            x[:] = 0.5
        if t % 7 == 0:
            x[: 3 * n // 4] = 0.25
        assert median(x) == np.median(x), (t, n)


def test_vertex_support_distances_equal_the_trees() -> None:
    """The vertex support's nearest distances (all pairs for a face and a few candidates,
    the tree beyond) equal ``cKDTree.query``'s bit for bit, ties on a coarse grid included."""
    from scipy.spatial import cKDTree

    from mks_sim.lowlevel import vertexes

    rng = np.random.default_rng(24)
    for t in range(200):
        pts = rng.normal(size=(int(rng.integers(1, 700)), 3)) * 0.02 + 0.5
        q = rng.normal(size=(int(rng.integers(1, 25)), 3)) * 0.03 + 0.5
        if t % 2:
            pts, q = np.round(pts, 3), np.round(q, 3)
        want = cKDTree(pts).query(q)[0]
        assert vertexes._nearest_distances(pts, q).tobytes() == want.tobytes()
    assert np.all(np.isinf(vertexes._nearest_distances(np.zeros((0, 3)), q)))  # no points
    big = rng.normal(size=(30000, 3))
    q = rng.normal(size=(10, 3))
    np.testing.assert_array_equal(vertexes._nearest_distances(big, q), cKDTree(big).query(q)[0])


def _numpy_trig_is_libm() -> bool:
    """numpy's float64 arccos and cos give the C library's values here (not so where numpy
    dispatches them to its AVX-512 SVML loops, a few ulps apart): the compiled closed form,
    which calls the C library, then equals numpy's to the bit."""
    import math

    x = np.random.default_rng(0).uniform(-1.0, 1.0, 20000)
    acos = np.array([math.acos(v) for v in x])
    cos = np.array([math.cos(v) for v in acos])
    return bool(np.array_equal(np.arccos(x), acos) and np.array_equal(np.cos(acos), cos))


def _same(got: np.ndarray, want: np.ndarray) -> None:
    """Bit for bit where numpy's trigonometry is the C library's, else within 1e-12."""
    if _numpy_trig_is_libm():
        assert got.dtype == want.dtype and got.tobytes() == want.tobytes()
    else:
        np.testing.assert_allclose(got, want, rtol=1e-12, atol=1e-300)


def test_compiled_smallest_eigenvectors_equal_numpys_to_the_bit(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    """The normals' eigenvectors by the compiled pass equal the numpy path's bit for bit,
    isotropic rows (left to eigh) included."""
    from mks_sim.lowlevel import _gridknn
    from mks_sim.lowlevel.normals import _smallest_eigen

    if not _gridknn.available():
        pytest.skip("numba not importable")
    rng = np.random.default_rng(25)
    nb_ = rng.normal(size=(3000, 12, 3)) * np.array([0.01, 0.006, 0.0004])
    c = nb_ - nb_.mean(axis=1, keepdims=True)
    cov = np.stack(
        [(c[..., a] * c[..., b]).mean(axis=1) for a, b in
         ((0, 0), (0, 1), (0, 2), (1, 1), (1, 2), (2, 2))], axis=1
    )  # fmt: skip
    cov[:50] = np.array([1.0, 0.0, 0.0, 1.0, 0.0, 1.0]) * 3e-6  # isotropic: eigh
    got_n, got_c = _smallest_eigen(cov)
    monkeypatch.setattr(_gridknn, "available", lambda: False)
    want_n, want_c = _smallest_eigen(cov)
    _same(got_n, want_n)
    _same(got_c, want_c)


def test_compiled_smallest_eigenvalues_equal_numpys_and_eigh() -> None:
    """``smallest_eigenvalue``'s compiled pass gives numpy's closed form bit for bit (zero,
    isotropic and NaN rows included), and both the least eigenvalue of ``eigvalsh``."""
    from mks_sim.lowlevel import _gridknn
    from mks_sim.lowlevel.normals import _smallest_eigenvalue_numpy, smallest_eigenvalue

    if not _gridknn.available():
        pytest.skip("numba not importable")
    rng = np.random.default_rng(26)
    nb_ = rng.normal(size=(2000, 12, 3)) * np.array([0.01, 0.004, 0.0003])
    c = nb_ - nb_.mean(axis=1, keepdims=True)
    pairs = ((0, 0), (0, 1), (0, 2), (1, 1), (1, 2), (2, 2))
    cov = np.stack([(c[..., a] * c[..., b]).mean(axis=1) for a, b in pairs], axis=1)
    cov[:5] = 0.0
    cov[5:10] = np.array([1.0, 0.0, 0.0, 1.0, 0.0, 1.0]) * 2e-6
    cov[10] = [np.nan, 0.0, 0.0, 1.0, 0.0, 1.0]
    got = smallest_eigenvalue(cov)  # 2,000 rows: the compiled pass
    want = _smallest_eigenvalue_numpy(cov)
    for g, w in zip(got, want, strict=True):
        _same(g, w)
    full = np.empty((len(cov) - 11, 3, 3))
    for k, (a, b) in enumerate(pairs):
        full[:, a, b] = full[:, b, a] = cov[11:, k]
    lam = np.linalg.eigvalsh(full)[:, 0]
    np.testing.assert_allclose(got[0][11:], lam, rtol=1e-6, atol=1e-15)
    np.testing.assert_allclose(got[3][11:], lam / np.trace(full, axis1=1, axis2=2), rtol=1e-6)
    assert np.all(got[0][:10] == got[1][:10]) and not got[2][:10].any()  # q, not safe
    assert np.isnan(got[0][10])


def test_vertex_support_compiled_as_face_by_face(monkeypatch: pytest.MonkeyPatch) -> None:
    """``plane_vertexes``' support distances in one compiled pass give the vertexes of the
    face-by-face numpy pass to the bit, on the industrial part's faces (many planes, the
    table as an extra face) and with a region that has no points."""
    import mks_sim.lowlevel.vertexes as vx
    from mks_sim.geometry.meshes import industrial_part_mesh, sample_surface
    from mks_sim.lowlevel import _gridknn
    from mks_sim.lowlevel.regions import PlanarRegion

    if not _gridknn.available():
        pytest.skip("needs numba")
    rng = np.random.default_rng(9)
    pts, _ = sample_surface(industrial_part_mesh(), 6000, rng=rng)
    pts = pts + rng.normal(0, 2e-4, pts.shape)
    seg = segment_surfaces(pts, seeds="all")
    assert len(seg.planes) >= 6
    table = Plane(np.array([0.0, 0.0, -1.0]), 0.0)
    empty = PlanarRegion(np.zeros(0, np.intp), seg.planes[0].plane, np.zeros(3))
    for regions in (list(seg.planes), [*seg.planes, empty]):
        runs = []
        for compiled in (True, False):
            monkeypatch.setattr(vx._gridknn, "available", lambda c=compiled: c)
            runs.append(vx.plane_vertexes(regions, pts, extra_planes=[table], tolerance=0.004))
        a, b = runs
        assert len(a) > 4 and len(a) == len(b)
        for name in ("points", "faces", "normals", "support"):
            assert np.array_equal(getattr(a, name), getattr(b, name)), name
