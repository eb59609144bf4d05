"""3-D Hough under translation: the properties section 2.2 states, on random models."""

from __future__ import annotations

import itertools

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from mks_sim.errors import DataError, SpecError
from mks_sim.models.hough3d import TranslationHough3D, accumulate_sparse

CUBE = np.array(list(itertools.product([-1.0, 1.0], repeat=3)))


@settings(max_examples=25)
@given(st.integers(min_value=0, max_value=2**31 - 1))
def test_translated_model_unique_maximum_equals_vertex_count(seed: int) -> None:
    rng = np.random.default_rng(seed)
    n = int(rng.integers(4, 20))
    model = rng.uniform(-1, 1, (n, 3))
    t = rng.uniform(-50, 50, 3)
    h = TranslationHough3D(model, cell=0.01)
    hyps = h.detect(model + t)
    assert hyps[0].votes == n
    assert all(x.votes < n for x in hyps[1:])  # unique
    np.testing.assert_allclose(hyps[0].matrix[:3, 3], t, atol=1e-9)
    np.testing.assert_allclose(hyps[0].reference_point, model.mean(axis=0) + t, atol=1e-9)
    np.testing.assert_array_equal(hyps[0].correspondences, np.column_stack([np.arange(n)] * 2))


def test_missing_vertexes_lower_the_maximum() -> None:
    h = TranslationHough3D(CUBE)
    t = np.array([5.0, 0, 0])
    for k in range(8, 2, -1):
        hyps = h.detect(CUBE[:k] + t)
        assert hyps[0].votes == k
        top = [x.matrix[:3, 3] for x in hyps if x.votes == k]
        # "The reference point is always guaranteed to be one of the maxima" (section 2.2);
        # with one face left (k = 4) the face also fits the opposite face's place: a tie.
        assert any(np.allclose(x, t, atol=1e-9) for x in top)
        assert len(top) == (1 if k > 4 else 2)


def test_several_copies_give_several_maxima() -> None:
    rng = np.random.default_rng(4)
    model = rng.uniform(-1, 1, (10, 3))
    shifts = np.array([[0, 0, 0], [10, 0, 0], [0, 7, 3]], float)
    det = np.vstack([model + s for s in shifts])
    hyps = TranslationHough3D(model, cell=0.01).detect(det)
    top = [x for x in hyps if x.votes == 10]
    assert len(top) == 3
    found = np.array(sorted(x.matrix[:3, 3].tolist() for x in top))
    np.testing.assert_allclose(found, sorted(shifts.tolist()), atol=1e-9)


@settings(max_examples=25)
@given(st.integers(min_value=0, max_value=2**31 - 1))
def test_noise_robust_quantisation(seed: int) -> None:
    # Noise of 1/5 cell: the peak must not split between neighbouring cells.
    rng = np.random.default_rng(seed)
    model = rng.uniform(-1, 1, (12, 3))
    t = rng.uniform(-3, 3, 3)
    h = TranslationHough3D(model, cell=0.05)
    det = model + t + rng.normal(0, 0.01, model.shape)
    best = h.detect(det)[0]
    assert best.votes == 12
    np.testing.assert_allclose(best.matrix[:3, 3], t, atol=0.02)


def test_sparse_accumulator_counts_distinct_voters() -> None:
    votes = np.array([[0, 0, 0], [0, 0, 0], [0.001, 0, 0], [5, 5, 5]], float)
    acc = accumulate_sparse(votes, [0, 0, 1, 2], cell_size=1.0, spread=False)
    d = {tuple(c): n for c, n in zip(acc.cells.tolist(), acc.counts.tolist())}
    assert d == {(0, 0, 0): 2, (5, 5, 5): 1}
    # Memory grows with votes: 1000 far-apart votes -> at most 8000 cells, whatever the span.
    far = np.random.default_rng(0).uniform(-1e6, 1e6, (1000, 3))
    assert len(accumulate_sparse(far, np.arange(1000), 1e-3)) <= 8000


def test_errors() -> None:
    with pytest.raises(DataError, match=r"\(N, 3\)"):
        TranslationHough3D(np.zeros((4, 2)))
    with pytest.raises(SpecError, match="cell"):
        TranslationHough3D(CUBE, cell=0.0)
    with pytest.raises(DataError, match="NaN"):
        TranslationHough3D(CUBE).detect(np.full((3, 3), np.nan))
