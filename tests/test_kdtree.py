"""KDTree and Metric against brute force, for every metric and both queries."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from hypothesis.extra.numpy import arrays

from mks_sim.errors import DataError, SpecError
from mks_sim.lowlevel import KDTree, Metric, abs_diff

K = 3


def _sq(m, v):
    return (np.asarray(m) - np.asarray(v)) ** 2


def _asym(m, v):
    # Asymmetric: overshooting the query costs 3x undershooting; non-decreasing in |m - v|.
    d = np.asarray(v) - np.asarray(m)
    return np.where(d > 0, 3.0 * d, -d)


def _capped(m, v):
    # Bounded f: the bounding box must fall back to the whole axis.
    return np.minimum(np.abs(np.asarray(m) - np.asarray(v)), 1.5)


# (metric, independent brute-force distance(query (k,), data (N, k)) -> (N,))
W = np.array([1.0, 2.0, 0.5])
R = np.array([10.0, 1.0, 4.0])
METRICS = {
    "euclidean": (Metric.euclidean(), lambda q, X: np.sqrt(((X - q) ** 2).sum(1))),
    "manhattan": (Metric.manhattan(), lambda q, X: np.abs(X - q).sum(1)),
    "chebyshev": (Metric.chebyshev(), lambda q, X: np.abs(X - q).max(1)),
    "weighted_euclidean": (
        Metric.euclidean(weights=W, ranges=R),
        lambda q, X: np.sqrt((((X - q) * W / R) ** 2).sum(1)),
    ),
    "weighted_manhattan": (
        Metric.manhattan(weights=W, ranges=np.stack([np.zeros(3), R], 1)),
        lambda q, X: (np.abs(X - q) * W / R).sum(1),
    ),
    "weighted_chebyshev": (
        Metric.chebyshev(weights=W),
        lambda q, X: (np.abs(X - q) * W).max(1),
    ),
    "sum_of_abs": (
        Metric.sum_of([abs_diff(), abs_diff(0.5), abs_diff(4.0)]),
        lambda q, X: (
            np.abs(X[:, 0] - q[0]) + np.abs(X[:, 1] - q[1]) / 0.5 + np.abs(X[:, 2] - q[2]) / 4
        ),
    ),
    "sum_of_mixed": (
        Metric.sum_of([_sq, _asym, _capped], scales=[1.0, 2.0, 3.0]),
        lambda q, X: (
            (X[:, 0] - q[0]) ** 2
            + np.where(X[:, 1] > q[1], 3 * (X[:, 1] - q[1]), q[1] - X[:, 1])
            + np.minimum(np.abs(X[:, 2] - q[2]), 1.5)
        ),
    ),
}

coords = st.one_of(
    st.integers(-4, 4).map(float),  # ties and duplicates
    st.floats(-5, 5, allow_nan=False, width=32).map(float),
)
point_sets = arrays(np.float64, st.tuples(st.integers(1, 30), st.just(K)), elements=coords)
queries = arrays(np.float64, st.tuples(st.integers(1, 4), st.just(K)), elements=coords)


def _near(a: np.ndarray, b: float) -> np.ndarray:
    return np.abs(a - b) <= 1e-9 * (1 + abs(b))


@pytest.mark.parametrize("name", sorted(METRICS))
@settings(max_examples=30)
@given(data=point_sets, q=queries, k=st.integers(1, 6), dub=st.sampled_from([math.inf, 1.0, 3.5]))
def test_query_matches_brute_force(name, data, q, k, dub):
    metric, brute = METRICS[name]
    tree = KDTree(data, leafsize=2, metric=metric)
    d, i = tree.query(q, k=k, distance_upper_bound=dub)
    d = np.asarray(d).reshape(len(q), k)
    i = np.asarray(i).reshape(len(q), k)
    for j in range(len(q)):
        ref = brute(q[j], data)
        within = np.sort(ref[ref < dub])[:k]
        n_found = int(np.isfinite(d[j]).sum())
        # boundary points within 1e-9 of dub may go either way
        assert abs(n_found - len(within)) <= int(_near(ref, dub).sum())
        np.testing.assert_allclose(
            d[j, : min(n_found, len(within))], within[:n_found], rtol=1e-9, atol=1e-12
        )
        found = i[j, :n_found]
        assert len(set(found.tolist())) == n_found
        np.testing.assert_allclose(ref[found], d[j, :n_found], rtol=1e-9, atol=1e-12)
        assert np.all(i[j, n_found:] == tree.n) and np.all(np.isinf(d[j, n_found:]))
        assert np.all(np.diff(d[j, :n_found]) >= 0)


@pytest.mark.parametrize("name", sorted(METRICS))
@settings(max_examples=30)
@given(data=point_sets, q=queries, r=st.sampled_from([0.0, 0.5, 1.0, 2.0, 4.5]))
def test_ball_matches_brute_force(name, data, q, r):
    metric, brute = METRICS[name]
    tree = KDTree(data, leafsize=3, metric=metric)
    ind, dist = tree.query_ball_point(q, r, return_distances=True)
    for j in range(len(q)):
        ref = brute(q[j], data)
        got = set(ind[j])
        want = set(np.flatnonzero(ref <= r).tolist())
        ambiguous = set(np.flatnonzero(_near(ref, r)).tolist())
        assert got - ambiguous == want - ambiguous
        assert ind[j] == sorted(ind[j])
        np.testing.assert_allclose(dist[j], ref[ind[j]], rtol=1e-9, atol=1e-12)


def test_sum_of_knn_breaks_ties_by_index():
    data = np.array([[0.0], [1.0], [-1.0], [1.0], [2.0]])
    tree = KDTree(data, metric=Metric.sum_of([abs_diff()]))
    d, i = tree.query([0.0], k=3)
    assert i.tolist() == [0, 1, 2] and d.tolist() == [0.0, 1.0, 1.0]


def test_scipy_shapes_and_sentinels():
    data = np.arange(12.0).reshape(4, 3)
    tree = KDTree(data)
    d, i = tree.query(data[1])
    assert np.ndim(d) == 0 and i == 1 and d == 0.0
    d, i = tree.query(data, k=6)
    assert d.shape == (4, 6) and i.shape == (4, 6)
    assert np.all(i[:, 4:] == 4) and np.all(np.isinf(d[:, 4:]))
    assert tree.query_ball_point(data[0], 0.0) == [0]
    assert tree.n == 4 and tree.m == 3 and len(tree) == 4


def test_balanced_tree_is_the_papers_median_split():
    tree = KDTree(np.random.default_rng(0).random((100, 2)), leafsize=5)
    # scipy's balanced tree: median split on the widest axis, buckets of <= leafsize points.
    assert tree.tree.leafsize == 5
    assert tree.tree.tree.children == 100


def test_range_normalisation_equals_dividing_by_ranges():
    rng = np.random.default_rng(1)
    data = rng.random((50, 2)) * [1000.0, 1.0]
    ranges = np.array([1000.0, 1.0])
    a = KDTree(data, metric=Metric.euclidean(ranges=ranges)).query(data[:5], k=4)
    b = KDTree(data / ranges).query(data[:5] / ranges, k=4)
    np.testing.assert_allclose(a[0], b[0])


def test_bad_input_errors():
    with pytest.raises(DataError, match="finite"):
        KDTree([[0.0, np.nan]])
    with pytest.raises(DataError, match="k=2 columns"):
        KDTree(np.zeros((3, 2))).query(np.zeros((1, 3)))
    with pytest.raises(DataError, match="k >= 1"):
        KDTree(np.zeros((3, 2))).query(np.zeros(2), k=0)
    with pytest.raises(DataError, match="metric is defined on k=3"):
        KDTree(np.zeros((3, 2)), metric=Metric.euclidean(weights=[1, 1, 1]))
    with pytest.raises(SpecError, match="p >= 1"):
        Metric.minkowski(0.5)
    with pytest.raises(SpecError, match="positive"):
        Metric.euclidean(ranges=[1.0, 0.0])
    with pytest.raises(SpecError, match="callables"):
        Metric.sum_of([])
    with pytest.raises(DataError, match="r >= 0"):
        KDTree(np.zeros((3, 2))).query_ball_point(np.zeros(2), -1.0)


def test_empty_tree():
    tree = KDTree(np.zeros((0, 2)), metric=Metric.sum_of([abs_diff(), abs_diff()]))
    d, i = tree.query(np.zeros(2), k=2)
    assert i.tolist() == [0, 0] and np.all(np.isinf(d))
    assert tree.query_ball_point(np.zeros(2), 5.0) == []


@pytest.mark.parametrize(
    "metric",
    [
        Metric.euclidean(),
        Metric.manhattan(weights=[0.3, 2, 1.7]),
        Metric.chebyshev(ranges=[100, 1, 7]),
        Metric.euclidean(weights=[0.3, 2, 1.7], ranges=[100, 1, 7]),
    ],
)
def test_tree_distances_equal_metric_distance_bit_for_bit(metric):
    # The SPG stores the tree's distances; they must be the metric's exactly (p = 1, 2, inf).
    pts = np.random.default_rng(4).random((500, 3)) * [100, 1, 7]
    d, i = KDTree(pts, metric=metric).query(pts[:100], k=6)
    assert np.array_equal(d, metric.distance(pts[:100, None, :], pts[i]))
