"""SpatialProximityGraph against a brute-force SPG, and updates against a fresh SPG."""

from __future__ import annotations

from typing import Any

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from hypothesis.extra.numpy import arrays
from scipy import sparse

from mks_sim.errors import DataError, SpecError
from mks_sim.lowlevel import DynamicKDTree, KDTree, Metric, SpatialProximityGraph, abs_diff

METRICS = {
    "euclidean": Metric.euclidean(),
    "manhattan": Metric.manhattan(),
    "minkowski3": Metric.minkowski(3, weights=[1.0, 0.5]),
    "chebyshev": Metric.chebyshev(),
    "sum_of": Metric.sum_of([abs_diff(), lambda a, b: 2.0 * np.abs(a - b)]),
}


def brute_spg(points, m, threshold, metric):
    """Row i: the m nearest other points (ties by index), within threshold (inclusive)."""
    n = len(points)
    rows = []
    for i in range(n):
        d = np.array([float(metric.distance(points[i], points[j])) for j in range(n)])
        others = [j for j in range(n) if j != i and (threshold is None or d[j] <= threshold)]
        others.sort(key=lambda j: (d[j], j))
        if m != "all":
            others = others[:m]
        rows.append((others, d[others]))
    return rows


def assert_matches(g, rows):
    assert g.n == len(rows)
    adj = g.adjacency
    assert adj.shape == (g.n, g.n) and adj.nnz == sum(len(r) for r, _ in rows)
    for i, (nb, d) in enumerate(rows):
        assert g.neighbors(i).tolist() == nb, (i, g.neighbors(i), nb)
        np.testing.assert_allclose(g.distances(i), d)
        s = slice(adj.indptr[i], adj.indptr[i + 1])
        assert adj.indices[s].tolist() == sorted(nb)


coords = st.integers(-3, 3).map(float)
points2d = arrays(np.float64, st.tuples(st.integers(0, 25), st.just(2)), elements=coords)
ms = st.one_of(st.integers(1, 5), st.just("all"))
thresholds = st.sampled_from([None, 0.0, 1.0, 1.5, 3.0])


@pytest.mark.parametrize("name", sorted(METRICS))
@settings(max_examples=30)
@given(points=points2d, m=ms, threshold=thresholds)
def test_spg_matches_brute_force(name, points, m, threshold):
    if m == "all" and threshold is None:
        threshold = 2.0
    metric = METRICS[name]
    g = SpatialProximityGraph(points, m=m, threshold=threshold, metric=metric, leafsize=2)
    assert_matches(g, brute_spg(points, m, threshold, metric))


@settings(max_examples=20)
@given(
    points=arrays(
        np.float64,
        st.tuples(st.integers(2, 40), st.just(3)),
        elements=st.floats(-1, 1, width=32).map(float),
    )
)
def test_spg_float_points_and_views(points):
    g = SpatialProximityGraph(points, m=4, threshold=0.8)
    rows = brute_spg(points, 4, 0.8, Metric.euclidean())
    assert_matches(g, rows)
    # symmetric view: i~j iff i->j or j->i
    sym = g.symmetric()
    n = len(points)
    want = np.zeros((n, n), bool)
    for i, (nb, _) in enumerate(rows):
        want[i, nb] = True
    want |= want.T
    got = np.zeros((n, n), bool)
    for i in range(n):
        got[i, sym.indices[sym.indptr[i] : sym.indptr[i + 1]]] = True
    assert np.array_equal(got, want)
    # components: union-find over the brute-force edges
    parent = list(range(n))

    def find(a):
        while parent[a] != a:
            a = parent[a]
        return a

    for i, j in zip(*np.nonzero(want), strict=True):
        parent[find(i)] = find(j)
    count, labels = g.components()
    assert count == len({find(i) for i in range(n)})
    for i in range(n):
        for j in range(n):
            assert (labels[i] == labels[j]) == (find(i) == find(j))


def test_zero_distance_edges_are_explicit():
    pts = np.array([[0.0], [0.0], [0.0], [5.0]])
    g = SpatialProximityGraph(pts, m=2, threshold=0.1)
    adj = g.adjacency
    assert isinstance(adj, sparse.csr_array)
    assert adj.nnz == 6 and np.all(adj.data == 0.0)  # stored zeros, one per edge
    assert g.pattern.nnz == 6 and g.pattern.dtype == bool
    assert g.components()[0] == 2
    assert g.neighbors(0).tolist() == [1, 2]


def test_ties_at_the_mth_place_go_to_the_lower_index():
    # 0 sits at the centre of four equidistant points; m=2 must pick 1 and 2.
    pts = np.array([[0, 0], [1, 0], [0, 1], [-1, 0], [0, -1]], float)
    g = SpatialProximityGraph(pts, m=2)
    assert g.neighbors(0).tolist() == [1, 2]
    # many duplicates: self may be missing from the tree's k nearest
    dup = np.zeros((12, 1))
    g = SpatialProximityGraph(dup, m=3)
    assert g.neighbors(7).tolist() == [0, 1, 2]
    assert g.neighbors(0).tolist() == [1, 2, 3]


def test_parameter_errors():
    with pytest.raises(SpecError, match="needs a finite threshold"):
        SpatialProximityGraph(np.zeros((3, 2)), m="all")
    with pytest.raises(SpecError, match="integer >= 1 or 'all'"):
        SpatialProximityGraph(np.zeros((3, 2)), m=0)
    with pytest.raises(SpecError, match="threshold >= 0"):
        SpatialProximityGraph(np.zeros((3, 2)), m=2, threshold=-1.0)
    with pytest.raises(DataError, match="finite"):
        SpatialProximityGraph([[0.0, np.inf]], m=2)
    with pytest.raises(DataError, match=r"\(N, k\)"):
        SpatialProximityGraph(np.zeros(3), m=2)
    g = SpatialProximityGraph(np.zeros((3, 2)), m=2)
    with pytest.raises(DataError, match="node index"):
        g.neighbors(3)
    with pytest.raises(DataError, match="out of range"):
        g.delete([5])


def test_from_tree_uses_the_trees_points_and_metric():
    rng = np.random.default_rng(3)
    pts = rng.integers(0, 5, size=(30, 2)).astype(float)
    metric = Metric.manhattan()
    for tree in (KDTree(pts, metric=metric), DynamicKDTree(pts, metric=metric)):
        g = SpatialProximityGraph.from_tree(tree, m=3, threshold=2.0)
        assert_matches(g, brute_spg(pts, 3, 2.0, metric))


def test_empty_and_single():
    assert SpatialProximityGraph(np.zeros((0, 3)), m=3).adjacency.shape == (0, 0)
    g = SpatialProximityGraph(np.zeros((1, 3)), m=3)
    assert g.neighbors(0).tolist() == [] and g.components()[0] == 1


UPDATE_OPS = st.lists(
    st.one_of(
        st.tuples(st.just("insert"), st.integers(1, 6)),
        st.tuples(st.just("delete"), st.floats(0.0, 0.6)),
    ),
    min_size=1,
    max_size=8,
)


@pytest.mark.parametrize(
    ("m", "threshold", "metric"),
    [(3, None, "euclidean"), (2, 1.5, "chebyshev"), ("all", 1.0, "manhattan"), (2, 2.0, "sum_of")],
)
@settings(max_examples=15)
@given(ops=UPDATE_OPS, seed=st.integers(0, 2**16))
def test_updates_equal_a_fresh_spg(m, threshold, metric, ops, seed):
    rng = np.random.default_rng(seed)
    pts = rng.integers(-3, 4, size=(rng.integers(0, 15), 2)).astype(float)
    g = SpatialProximityGraph(pts, m=m, threshold=threshold, metric=METRICS[metric], leafsize=2)
    for op, arg in ops:
        before = g.points
        if op == "insert":
            new = rng.integers(-3, 4, size=(arg, 2)).astype(float)
            idx = g.insert(new)
            assert idx.tolist() == list(range(len(before), len(before) + arg))
            np.testing.assert_array_equal(g.points, np.concatenate([before, new]))
        elif g.n:
            gone = np.flatnonzero(rng.random(g.n) < arg)
            mapping = g.delete(gone)
            np.testing.assert_array_equal(g.points, np.delete(before, gone, axis=0))
            assert np.all(mapping[gone] == -1)
        assert_matches(g, brute_spg(g.points, m, threshold, METRICS[metric]))


def test_chunked_queries_give_the_same_graph(monkeypatch):
    import mks_sim.lowlevel.spg as spg_module

    rng = np.random.default_rng(5)
    pts = rng.integers(0, 4, size=(120, 2)).astype(float)  # many ties across chunk borders
    monkeypatch.setattr(spg_module, "_CHUNK_ENTRIES", 37)
    g = SpatialProximityGraph(pts, m=5, threshold=2.0)
    assert_matches(g, brute_spg(pts, 5, 2.0, Metric.euclidean()))


@pytest.mark.parametrize("max_runs", [0, 4096])
def test_both_update_splices(monkeypatch, max_runs):
    import mks_sim.lowlevel.spg as spg_module

    monkeypatch.setattr(spg_module, "_MAX_RUNS", max_runs)
    rng = np.random.default_rng(11)
    pts = rng.integers(-4, 5, size=(40, 2)).astype(float)
    g = SpatialProximityGraph(pts, m=3, threshold=2.5)
    for step in range(6):
        if step % 2 == 0:
            g.insert(rng.integers(-4, 5, size=(3, 2)).astype(float))
        else:
            g.delete(rng.choice(g.n, 4, replace=False))
        assert_matches(g, brute_spg(g.points, 3, 2.5, Metric.euclidean()))


# --------------------------------------------------------------------------- the grid kernel
GRID_METRICS = {"euclidean": Metric.euclidean(), "weighted": Metric.minkowski(2, weights=[1.0, 0.5])}


@pytest.mark.parametrize("name", sorted(GRID_METRICS))
@settings(max_examples=30, deadline=None)
@given(points=points2d, m=st.integers(1, 5), threshold=thresholds)
def test_grid_spg_matches_brute_force(name, points, m, threshold):
    # integer coordinates: many exact ties and duplicates, decided by index like the brute force
    metric = GRID_METRICS[name]
    g = SpatialProximityGraph(points, m=m, threshold=threshold, metric=metric, method="grid")
    assert_matches(g, brute_spg(points, m, threshold, metric))


@pytest.mark.parametrize("dim", [1, 2, 3])
@pytest.mark.parametrize("threshold", [None, 0.08])
@pytest.mark.parametrize("brute", [True, False])
def test_grid_equals_tree_on_clustered_points(dim, threshold, brute, monkeypatch):
    # clusters of different densities, duplicates, a dense clump (crowded cells are left to the
    # tree) and far outliers (rows the grid cannot prove): the grid path must give exactly the
    # tree path's graph, and the grid itself must answer most rows
    from mks_sim.lowlevel._gridknn import grid_knn

    rng = np.random.default_rng(dim)
    sizes = (0.03, 0.05, 0.1, 0.1)
    parts = [rng.normal(c, s, size=(1500, dim)) for c, s in zip(rng.random(4) * 3, sizes)]
    parts.append(np.repeat(rng.random((3, dim)), 40, axis=0))  # duplicates
    parts.append(rng.normal(0.5, 1e-4, size=(300, dim)))  # a clump
    parts.append(rng.random((4, dim)) * 100 + 50)  # outliers
    pts = np.concatenate(parts)[rng.permutation(sum(len(p) for p in parts))]
    assert grid_knn(pts, 6, threshold)[3].mean() > 0.8
    import mks_sim.lowlevel.spg as spg_module

    # the rows the grid leaves: by brute force, or (0 entries allowed) by the tree
    monkeypatch.setattr(spg_module, "_BRUTE_ENTRIES", 10**12 if brute else 0)
    tree = SpatialProximityGraph(pts, m=6, threshold=threshold, method="tree")
    grid = SpatialProximityGraph(pts, m=6, threshold=threshold, method="grid")
    for a, b in ((grid.adjacency, tree.adjacency), (grid.symmetric(), tree.symmetric())):
        assert np.array_equal(a.indptr, b.indptr) and np.array_equal(a.indices, b.indices)
        assert np.array_equal(a.data, b.data)
    for i in rng.choice(len(pts), 50, replace=False):
        assert grid.neighbors(i).tolist() == tree.neighbors(i).tolist()
        assert np.array_equal(grid.distances(i), tree.distances(i))


def test_grid_rows_do_not_depend_on_the_tasks(monkeypatch):
    """The grid's rows are the same, to the bit, whatever the cells per parallel task (1 to
    all of them) and the threads: each cell's rows are its own work."""
    import numba

    import mks_sim.lowlevel._gridknn as gk

    rng = np.random.default_rng(31)
    pts = np.concatenate(
        [rng.normal(0.3, 0.05, (2000, 3)), np.repeat(rng.random((5, 3)), 20, axis=0)]
    )
    runs = []
    before = numba.get_num_threads()
    try:
        for low, high, threads in ((32, 256, None), (1, 1, None), (7, 7, 1), (10**6, 10**6, None)):
            monkeypatch.setattr(gk, "_KNN_CHUNK_MIN", low)
            monkeypatch.setattr(gk, "_KNN_CHUNK_MAX", high)
            numba.set_num_threads(threads or numba.config.NUMBA_NUM_THREADS)
            runs.append(gk.grid_knn(pts, 8, 0.05))
    finally:
        numba.set_num_threads(before)
    first = runs[0]
    assert first[3].mean() > 0.8
    for other in runs[1:]:
        assert np.array_equal(other[3], first[3])  # the same rows done
        done = first[3]
        assert np.array_equal(other[2][done], first[2][done])  # of the same lengths
        keep = (np.arange(8) < first[2][:, None]) & done[:, None]  # (the rest is garbage)
        assert np.array_equal(other[0][keep], first[0][keep])
        assert np.array_equal(other[1][keep], first[1][keep])


def test_grid_rows_against_brute_force_3d():
    rng = np.random.default_rng(8)
    pts = np.round(rng.random((400, 3)) * 6) / 2  # a lattice: ties everywhere
    g = SpatialProximityGraph(pts, m=7, threshold=1.2, method="grid")
    assert_matches(g, brute_spg(pts, 7, 1.2, Metric.euclidean()))


def test_grid_graph_updates_and_tree():
    rng = np.random.default_rng(9)
    pts = rng.integers(-4, 5, size=(60, 3)).astype(float)
    g = SpatialProximityGraph(pts, m=3, threshold=2.5, method="grid")
    assert isinstance(g.tree, KDTree) and g.tree.n == 60  # built on demand
    g.insert(rng.integers(-4, 5, size=(5, 3)).astype(float))
    g.delete([0, 7, 30])
    assert_matches(g, brute_spg(g.points, 3, 2.5, Metric.euclidean()))


def test_grid_method_errors():
    with pytest.raises(SpecError, match="method='grid' needs an integer m"):
        SpatialProximityGraph(np.zeros((3, 2)), m="all", threshold=1.0, method="grid")
    with pytest.raises(SpecError, match="dimension <= 3"):
        SpatialProximityGraph(np.zeros((3, 4)), m=2, method="grid")
    with pytest.raises(SpecError, match="Euclidean"):
        SpatialProximityGraph(np.zeros((3, 2)), m=2, metric=Metric.manhattan(), method="grid")
    with pytest.raises(SpecError, match="method 'auto', 'tree' or 'grid'"):
        SpatialProximityGraph(np.zeros((3, 2)), m=2, method="fast")


def _flood_labels(n: int, edges: Any, nodes: Any) -> tuple[int, np.ndarray]:
    """(count, (n,) labels, -1 off ``nodes``): a flood fill from each unlabelled node of
    ``nodes`` in turn over the ``edges`` both ways (scipy's numbering)."""
    nbrs: list[set[int]] = [set() for _ in range(n)]
    for a, b in edges:
        nbrs[a].add(b)
        nbrs[b].add(a)
    labels = np.full(n, -1)
    count = 0
    for s in nodes:
        if labels[s] >= 0:
            continue
        labels[s] = count
        stack = [s]
        while stack:
            for b in nbrs[stack.pop()]:
                if labels[b] < 0:
                    labels[b] = count
                    stack.append(b)
        count += 1
    return count, labels


@pytest.mark.parametrize("seed", range(6))
def test_weak_components_against_flood_fill_and_scipy(seed):
    """The compiled union-find's count and labels: those of a flood fill over the graph's
    entries both ways, numbered by each component's first node (scipy's numbering), and
    scipy's own; explicit zeros are edges."""
    from scipy.sparse import csgraph

    from mks_sim.lowlevel._gridknn import weak_components

    rng = np.random.default_rng(seed)
    n = int(rng.integers(1, 200))
    e = int(rng.integers(0, 2 * n))
    rows, cols = rng.integers(0, n, e), rng.integers(0, n, e)
    data = rng.random(e) * (rng.random(e) > 0.3)  # some explicit zeros
    graph = sparse.csr_array((data, (rows, cols)), shape=(n, n))
    count, expect = _flood_labels(n, zip(rows.tolist(), cols.tolist(), strict=True), range(n))
    got_count, got = weak_components(graph)
    assert got_count == count
    np.testing.assert_array_equal(got, expect)
    ref_count, ref = csgraph.connected_components(graph, directed=True, connection="weak")
    assert ref_count == got_count and ref.dtype == got.dtype
    np.testing.assert_array_equal(got, ref)
    # a COO graph (converted first) and the path without numba give the same
    coo_count, coo = weak_components(graph.tocoo())
    assert coo_count == count
    np.testing.assert_array_equal(coo, expect)
    with pytest.raises(DataError, match="square"):
        weak_components(sparse.csr_array((2, 3)))


def test_weak_components_without_numba(monkeypatch):
    """Where numba is unavailable, scipy answers: the same count and labels."""
    import mks_sim.lowlevel._gridknn as gk

    graph = sparse.csr_array(
        (np.ones(4), ([0, 1, 3, 5], [1, 0, 4, 3])), shape=(6, 6)
    )  # components {0, 1}, {2}, {3, 4, 5}
    monkeypatch.setattr(gk, "available", lambda: False)
    count, labels = gk.weak_components(graph)
    assert count == 3
    np.testing.assert_array_equal(labels, [0, 0, 1, 2, 2, 2])
    with pytest.raises(DataError, match="square"):
        gk.weak_components(sparse.csr_array((2, 3)))


def _random_graph(rng: np.random.Generator) -> tuple[int, sparse.csr_array]:
    n = int(rng.integers(1, 150))
    e = int(rng.integers(0, 3 * n))
    data = rng.random(e) * (rng.random(e) > 0.3)  # some explicit zeros
    graph = sparse.csr_array((data, (rng.integers(0, n, e), rng.integers(0, n, e))), shape=(n, n))
    return n, graph


@pytest.mark.parametrize("compiled", [True, False])
@pytest.mark.parametrize("seed", range(4))
def test_masked_components_against_flood_fill(seed, compiled, monkeypatch):
    """The components of the kept nodes over the entries <= limit between two of them: a
    flood fill's over those entries both ways, numbered by each component's first node,
    -1 off the mask; compiled and through scipy."""
    import mks_sim.lowlevel._gridknn as gk

    if not compiled:
        monkeypatch.setattr(gk, "available", lambda: False)
    rng = np.random.default_rng(100 + seed)
    for _ in range(20):
        n, graph = _random_graph(rng)
        keep = rng.random(n) > 0.3
        limit = float(rng.choice([np.inf, 0.5, 0.0]))
        coo = graph.tocoo()
        edges = [
            (a, b)
            for a, b, v in zip(coo.row.tolist(), coo.col.tolist(), coo.data.tolist(), strict=True)
            if keep[a] and keep[b] and v <= limit
        ]
        count, expect = _flood_labels(n, edges, np.flatnonzero(keep).tolist())
        got_count, got = gk.masked_components(graph, keep, limit)
        assert got_count == count
        np.testing.assert_array_equal(got, expect)
    # all nodes, no limit: weak_components
    n, graph = _random_graph(rng)
    count, labels = gk.masked_components(graph)
    ref_count, ref = gk.weak_components(graph)
    assert count == ref_count
    np.testing.assert_array_equal(labels, ref)
    with pytest.raises(DataError, match="square"):
        gk.masked_components(sparse.csr_array((2, 3)))
    with pytest.raises(DataError, match=r"\(2,\) keep"):
        gk.masked_components(sparse.csr_array((2, 2)), np.ones(3, bool))


@pytest.mark.parametrize("compiled", [True, False])
def test_same_label_entries_against_brute_force(compiled, monkeypatch):
    """``same_label_entries`` keeps exactly the entries joining two nodes of one label, with
    their values, each row in its order."""
    import mks_sim.lowlevel._gridknn as gk

    if not compiled:
        monkeypatch.setattr(gk, "available", lambda: False)
    rng = np.random.default_rng(7)
    for _ in range(30):
        n, graph = _random_graph(rng)
        labels = rng.integers(0, 3, n)
        kept = gk.same_label_entries(graph, labels)
        coo = graph.tocoo()
        same = labels[coo.row] == labels[coo.col]
        want = sparse.csr_array((coo.data[same], (coo.row[same], coo.col[same])), shape=(n, n))
        np.testing.assert_array_equal(kept.indptr, want.indptr)
        np.testing.assert_array_equal(kept.indices, want.indices)
        np.testing.assert_array_equal(kept.data, want.data)
