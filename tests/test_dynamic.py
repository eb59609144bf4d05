"""DynamicKDTree: after any sequence of inserts and deletes, queries answer exactly as a tree
freshly built from the same points."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from mks_sim.errors import DataError, NotFound
from mks_sim.lowlevel import DynamicKDTree, KDTree, Metric, abs_diff

K = 2
OPS = st.lists(
    st.one_of(
        st.tuples(st.just("insert"), st.integers(1, 9)),
        st.tuples(st.just("delete"), st.floats(0.0, 1.0)),
    ),
    min_size=1,
    max_size=12,
)
METRICS = [
    Metric.euclidean(),
    Metric.chebyshev(weights=[2.0, 1.0]),
    Metric.sum_of([abs_diff(), abs_diff(2.0)]),
]


def _check_same_as_fresh(dyn: DynamicKDTree, q: np.ndarray) -> None:
    ids = dyn.ids
    pts = dyn.data
    assert len(ids) == len(pts) == dyn.n
    fresh = KDTree(pts, metric=dyn.metric)
    for k in (1, 3):
        d, i = dyn.query(q, k=k, distance_upper_bound=2.5)
        fd, fi = fresh.query(q, k=k, distance_upper_bound=2.5)
        np.testing.assert_allclose(
            np.asarray(d).reshape(len(q), k), np.asarray(fd).reshape(len(q), k)
        )
        fi = np.asarray(fi).reshape(len(q), k)
        i = np.asarray(i).reshape(len(q), k)
        missing = fi == fresh.n
        assert np.all(i[missing] == dyn.next_id)
        # same distance to the point each id names (equidistant ties may pick other ids)
        got = dyn.points_of(i[~missing])
        np.testing.assert_allclose(
            dyn.metric.distance(q[np.nonzero(~missing)[0]], got),
            np.asarray(fd).reshape(len(q), k)[~missing],
        )
    for r in (0.0, 1.0, 3.0):
        a = dyn.query_ball_point(q, r)
        b = fresh.query_ball_point(q, r)
        for j in range(len(q)):
            assert a[j] == ids[np.asarray(b[j], np.intp)].tolist()


@pytest.mark.parametrize("metric", METRICS, ids=["euclidean", "w_chebyshev", "sum_of"])
@settings(max_examples=15)
@given(ops=OPS, seed=st.integers(0, 2**16))
def test_ops_sequence_equals_fresh_tree(metric, ops, seed):
    rng = np.random.default_rng(seed)
    dyn = DynamicKDTree(k=K, leafsize=2, metric=metric)
    q = rng.integers(-3, 4, size=(4, K)).astype(float)
    for op, arg in ops:
        if op == "insert":
            pts = rng.integers(-3, 4, size=(arg, K)).astype(float)  # many ties and duplicates
            new = dyn.insert(pts)
            np.testing.assert_array_equal(dyn.points_of(new), pts)
        elif dyn.n:
            ids = dyn.ids
            gone = ids[rng.random(len(ids)) < arg]
            dyn.delete(gone)
            assert not np.isin(gone, dyn.ids).any()
        _check_same_as_fresh(dyn, q)


def test_blocks_follow_a_binary_counter_and_rebuild_on_many_deletes():
    dyn = DynamicKDTree(k=1)
    for v in range(7):
        dyn.insert([[float(v)]])
    sizes = sorted(b.size for b in dyn._blocks.values())
    assert sizes == [1, 2, 4]  # 7 = 0b111
    built = dyn.rebuilds
    dyn.delete([0, 1, 2])  # 3 of the size-4 block: more than half dead -> rebuilt
    assert dyn.rebuilds > built
    assert sum(b.dead for b in dyn._blocks.values()) == 0
    # the survivor 3 carries into 6 (level 0) and then 4, 5 (level 1): one block of 4
    assert sorted(b.size for b in dyn._blocks.values()) == [4]
    assert dyn.ids.tolist() == [3, 4, 5, 6]


def test_missing_neighbour_is_next_id_and_errors():
    dyn = DynamicKDTree(np.zeros((2, 2)))
    dyn.delete([0])
    d, i = dyn.query(np.zeros(2), k=2)
    assert i.tolist() == [1, 2] and math.isinf(d[1])
    with pytest.raises(NotFound, match=r"ids \[0\] are not live"):
        dyn.delete([0])
    with pytest.raises(NotFound, match="not live"):
        dyn.points_of([7])
    with pytest.raises(DataError, match="k=2 columns"):
        dyn.insert(np.zeros((1, 3)))
    with pytest.raises(DataError, match="give data or k"):
        DynamicKDTree()


def test_many_marks_in_one_block_still_exact():
    # 64 points on a line in one block; the 31 nearest to the query are dead (< half): the
    # block query must widen its k until it sees live points.
    pts = np.arange(64.0)[:, None]
    dyn = DynamicKDTree(pts, leafsize=4)
    dyn.delete(np.arange(31))
    assert len(dyn._blocks) == 1 and next(iter(dyn._blocks.values())).dead == 31
    d, i = dyn.query(np.array([[0.0]]), k=3)
    assert i.tolist() == [[31, 32, 33]] and d.tolist() == [[31.0, 32.0, 33.0]]
