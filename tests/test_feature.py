"""Feature models: the three matchers of paper section 2.1 agree with each other and with brute
force (computed here independently of the library's metric code)."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from hypothesis.extra.numpy import arrays

from mks_sim.errors import DataError, SpecError
from mks_sim.fields import DONT_CARE
from mks_sim.lowlevel import Metric
from mks_sim.models.feature import (
    FeatureModel,
    Match,
    match_brute_force,
    match_description_tree,
    match_model_tree,
    match_spg,
)

MATCHERS = [match_model_tree, match_description_tree, match_spg]


def _asym(m, v):
    d = np.asarray(v) - np.asarray(m)
    return np.where(d > 0, 2.0 * d, -0.5 * d)


def independent(models, data):
    """Brute force with the distance written out per metric kind."""
    out = []
    for mod in models:
        keys = [i for i, r in enumerate(mod.reference) if r is not DONT_CARE]
        ref = np.array([mod.reference[i] for i in keys])
        for j, row in enumerate(np.asarray(data, float)):
            diff = row[keys] - ref
            if mod.metric.kind == "sum_of":
                d = float(np.sum(np.where(diff > 0, 2.0 * diff, -0.5 * diff)))
            elif mod.metric.p == 1:
                d = float(np.abs(diff).sum())
            elif mod.metric.p == np.inf:
                d = float(np.abs(diff).max())
            else:
                d = float(np.sqrt((diff**2).sum()))
            if d <= mod.threshold * (1 + 1e-12):
                out.append((mod.name, j))
    return sorted(out)


values = st.integers(0, 4).map(float)
refs = st.lists(st.one_of(values, st.just("*")), min_size=3, max_size=3).filter(
    lambda r: any(v != "*" for v in r)
)
metric_kinds = st.sampled_from(["euclidean", "manhattan", "chebyshev", "sum_of"])


def make_model(i, ref, kind, threshold):
    k = sum(v != "*" for v in ref)
    metric = Metric.sum_of([_asym] * k) if kind == "sum_of" else getattr(Metric, kind)()
    return FeatureModel(f"M{i}", "S", tuple(ref), threshold, metric)


@settings(max_examples=25)
@given(
    specs=st.lists(
        st.tuples(refs, metric_kinds, st.sampled_from([0.0, 0.5, 1.0, 2.0])), min_size=1, max_size=5
    ),
    data=arrays(np.float64, st.tuples(st.integers(0, 20), st.just(3)), elements=values),
)
def test_three_matchers_agree_with_brute_force(specs, data):
    models = [make_model(i, *s) for i, s in enumerate(specs)]
    want = independent(models, data)
    results = [m(models, data) for m in [*MATCHERS, match_brute_force]]
    for res in results:
        assert sorted((x.model, x.description) for x in res) == want
        assert res == results[0]  # same list, same distances, same order


def test_match_records_distance_and_sorting():
    c2 = FeatureModel("C2", "Circle_Detector", ("*", "*", 2), 0.1)
    c3 = FeatureModel("C3", "Circle_Detector", (DONT_CARE, DONT_CARE, 3.0), 0.5)
    data = np.array([[0, 0, 3.4], [1, 1, 2.0], [5, 5, 2.05], [9, 9, 1.0]])
    want = [
        Match("C2", 1, 0.0),
        Match("C2", 2, pytest.approx(0.05)),
        Match("C3", 0, pytest.approx(0.4)),
    ]
    for m in MATCHERS:
        assert m([c3, c2], data) == want


def test_models_on_different_sensors_take_a_mapping():
    a = FeatureModel("nut", "Corner_Holes_Detector", ("*", "*", 4, 1), 0.1)
    b = FeatureModel("C2", "Circle_Detector", ("*", "*", 2), 0.1)
    data = {"Corner_Holes_Detector": [[0, 0, 4, 1], [0, 0, 4, 0]], "Circle_Detector": [[1, 1, 2]]}
    for m in MATCHERS:
        assert [(x.model, x.description) for x in m([a, b], data)] == [("C2", 0), ("nut", 0)]
    with pytest.raises(DataError, match="several sensors"):
        match_spg([a, b], [[0, 0, 4, 1]])
    with pytest.raises(DataError, match="no descriptions of sensor 'Circle_Detector'"):
        match_spg([a, b], {"Corner_Holes_Detector": [[0, 0, 4, 1]]})


def test_k_vector_and_errors():
    m = FeatureModel(
        "nut", "Corner_Holes_Detector", ("*", "*", 4, 1), 0.1, fields=("x", "y", "corners", "holes")
    )
    assert m.key_indices == (2, 3) and m.key_fields == ("corners", "holes") and m.k == 2
    np.testing.assert_array_equal(m.reference_vector, [4.0, 1.0])
    # don't-care columns may hold anything, even NaN; k-vector columns may not
    assert m.matches([[np.nan, np.nan, 4, 1]]).tolist() == [True]
    with pytest.raises(DataError, match="field 'holes' is nan"):
        m.distance([[0, 0, 4, np.nan]])
    with pytest.raises(DataError, match=r"expected \(N, 4\)"):
        m.distance([[0, 0, 4]])
    with pytest.raises(SpecError, match="every field is don't care"):
        FeatureModel("x", "S", ("*", "*"), 0.1)
    with pytest.raises(SpecError, match="threshold"):
        FeatureModel("x", "S", (1.0,), -1.0)
    with pytest.raises(SpecError, match="reference\\[0\\]"):
        FeatureModel("x", "S", ("two",), 1.0)
    with pytest.raises(SpecError, match="k=2"):
        FeatureModel("x", "S", (1.0,), 1.0, Metric.euclidean(weights=[1, 2]))
    with pytest.raises(SpecError, match="repeat"):
        match_spg([m, m], [[0, 0, 4, 1]])


def test_empty_descriptions():
    m = FeatureModel("C2", "S", ("*", "*", 2), 0.1)
    for f in MATCHERS:
        assert f([m], np.zeros((0, 3))) == []
