"""Rotation-invariant 3-D Hough (paper section 2.2.1) against known rigid motions."""

from __future__ import annotations

import itertools

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from mks_sim.errors import DataError, SpecError
from mks_sim.geometry.transforms import (
    apply,
    cube_rotations,
    make_transform,
    pose_error,
    random_rotation,
)
from mks_sim.models.rotinv import (
    RotationInvariantHough,
    choose_reference,
    dedupe_points,
    radius_gaps,
    trilaterate,
)

CUBE = np.array(list(itertools.product([-1.0, 1.0], repeat=3)))


def _best_error(hyps, T_true, symmetries=None) -> tuple[float, float]:
    errs = [pose_error(h.matrix, T_true, symmetries) for h in hyps]
    # Rank by both errors (a partial hypothesis can have the right rotation, wrong position).
    return min(errs, key=lambda e: e[0] + 0.01 * e[1]) if errs else (np.inf, np.inf)


def test_trilaterate_matches_brute_force() -> None:
    rng = np.random.default_rng(0)
    K = 200
    a, b, c = (rng.uniform(-1, 1, (K, 3)) for _ in range(3))
    X = rng.uniform(-2, 2, (K, 3))  # a common point: the spheres through X meet there
    ra, rb, rc = (np.linalg.norm(X - p, axis=1) for p in (a, b, c))
    pts, ok = trilaterate(a, b, c, ra, rb, rc)
    assert ok.all()
    err = np.minimum(np.linalg.norm(pts[:, 0] - X, axis=1), np.linalg.norm(pts[:, 1] - X, axis=1))
    assert err.max() < 1e-6
    for k in range(2):  # both answers lie on all three spheres
        for p, r in ((a, ra), (b, rb), (c, rc)):
            np.testing.assert_allclose(np.linalg.norm(pts[:, k] - p, axis=1), r, atol=1e-6)
    # Disjoint spheres: no intersection.
    _, ok = trilaterate(a, a + [3, 0, 0], a + [0, 3, 0], np.ones(K), np.ones(K), np.ones(K))
    assert not ok.any()


def test_choose_reference_makes_radii_distinct() -> None:
    ref = choose_reference(CUBE)
    gap, rel = radius_gaps(CUBE, ref)
    # The centre of a cube has all radii equal; the chosen point must separate them clearly.
    assert radius_gaps(CUBE, [0, 0, 0])[0] == pytest.approx(0.0)
    assert gap > 0.05 and rel > 0.01
    np.testing.assert_array_equal(ref, choose_reference(CUBE))  # deterministic


def test_dedupe_points_counts() -> None:
    P = np.array([[0, 0, 0], [1, 0, 0], [0, 0, 0], [1, 0, 1e-9]], float)
    uniq, counts = dedupe_points(P, 1e-6)
    np.testing.assert_allclose(uniq, [[0, 0, 0], [1, 0, 0]], atol=1e-8)
    np.testing.assert_array_equal(counts, [2, 2])


def test_cube_translated_all_24_symmetric_poses() -> None:
    h = RotationInvariantHough(CUBE, reference=[1.5, 1.3, 1.25], tolerance=0.01)
    T_true = make_transform(np.eye(3), [5, 0, 0])
    res = h.analyze(apply(T_true, CUBE))
    # 24 proper + 24 mirror-image positions gather all 8 votes.
    assert res.top_votes == 8
    assert len(res.top_maxima) == 48
    assert sum(m.proper for m in res.top_maxima) == 24
    top = [hy for hy in res.hypotheses if hy.votes == 8]
    assert len(top) == 24
    for hy in top:  # every one is a symmetric equivalent of the truth
        pos, rot = pose_error(hy.matrix, T_true, cube_rotations())
        assert pos < 1e-9 and rot < 1e-4  # arccos near 1: ~1e-6 deg


@settings(max_examples=15)
@given(st.integers(min_value=0, max_value=2**31 - 1))
def test_cube_random_pose_noise_missing_spurious(seed: int) -> None:
    rng = np.random.default_rng(seed)
    T_true = make_transform(random_rotation(rng), rng.uniform(-10, 10, 3))
    keep = rng.permutation(8)[: rng.integers(4, 9)]
    det = apply(T_true, CUBE[keep]) + rng.normal(0, 0.005, (len(keep), 3))
    det = np.vstack([det, rng.uniform(-12, 12, (2, 3))])  # spurious points
    h = RotationInvariantHough(CUBE, tolerance=0.03, symmetries=cube_rotations())
    hyps = h.detect(det)
    pos, rot = _best_error(hyps, T_true, cube_rotations())
    assert pos < 0.05 and rot < 2.0


@settings(max_examples=15)
@given(st.integers(min_value=0, max_value=2**31 - 1))
def test_random_point_set_recovered(seed: int) -> None:
    rng = np.random.default_rng(seed)
    n = int(rng.integers(8, 31))
    model = rng.uniform(-1, 1, (n, 3))
    T_true = make_transform(random_rotation(rng), rng.uniform(-5, 5, 3))
    keep = rng.permutation(n)[: int(rng.integers(min(n, 6), min(n, 16) + 1))]
    det = apply(T_true, model[keep]) + rng.normal(0, 0.002, (len(keep), 3))
    n_out = int(rng.integers(0, 5))
    det = np.vstack([det, rng.uniform(-6, 6, (n_out, 3))])
    det = det[rng.permutation(len(det))]
    h = RotationInvariantHough(model, tolerance=0.01)
    hyps = h.detect(det)
    assert hyps, "no hypothesis"
    pos, rot = pose_error(hyps[0].matrix, T_true)
    assert pos < 0.02 and rot < 1.0
    # The best hypothesis pairs detected points with the right model points.
    moved = apply(T_true, model)
    for d_idx, m_idx in hyps[0].correspondences:
        assert np.linalg.norm(det[d_idx] - moved[m_idx]) < 0.02


def test_repeated_detected_points_merged_not_crashing() -> None:
    T_true = make_transform(random_rotation(np.random.default_rng(3)), [1, 2, 3])
    det = apply(T_true, CUBE)
    det = np.vstack([det, det[:2]])  # two repeats
    h = RotationInvariantHough(CUBE, reference=[1.5, 1.3, 1.25], tolerance=0.01)
    res = h.analyze(det)
    assert len(res.unique_points) == 8
    assert sorted(res.counts.tolist()) == [1] * 6 + [2, 2]
    assert res.top_votes == 8  # a repeat does not vote twice
    assert _best_error(res.hypotheses, T_true, cube_rotations())[1] < 1e-6


def test_three_points_enough() -> None:
    rng = np.random.default_rng(5)
    model = rng.uniform(-1, 1, (10, 3))
    T_true = make_transform(random_rotation(rng), [0.5, 0, 0])
    h = RotationInvariantHough(model, tolerance=0.005)
    hyps = h.detect(apply(T_true, model[:3]))
    # Three points: a proper fit, but with 3 votes other triples may fit too; truth is listed.
    assert _best_error(hyps, T_true)[1] < 1e-4


def test_errors() -> None:
    h = RotationInvariantHough(CUBE, reference=[1.5, 1.3, 1.25])
    with pytest.raises(DataError, match=">= 3 distinct detected"):
        h.detect(np.zeros((5, 3)))
    with pytest.raises(DataError, match=r"\(N, 3\)"):
        h.detect(np.zeros((5, 2)))
    with pytest.raises(DataError, match="NaN"):
        h.detect(np.full((5, 3), np.nan))
    with pytest.raises(SpecError, match="not distinct"):
        RotationInvariantHough(CUBE, reference=[0, 0, 0])
    with pytest.raises(SpecError, match="tolerance"):
        RotationInvariantHough(CUBE, tolerance=-1.0)
    with pytest.raises(DataError, match=">= 3 distinct model"):
        RotationInvariantHough([[0, 0, 0], [0, 0, 0], [1, 0, 0]])


def test_exhaustive_equals_pruned_maxima() -> None:
    # Pruning drops only intersections that no rigid motion can produce: same top maxima.
    det = apply(make_transform(random_rotation(np.random.default_rng(2)), [1, 1, 1]), CUBE[:6])
    a = RotationInvariantHough(CUBE, reference=[1.5, 1.3, 1.25], tolerance=0.01).analyze(det)
    b = RotationInvariantHough(
        CUBE, reference=[1.5, 1.3, 1.25], tolerance=0.01, prune=False
    ).analyze(det)
    assert a.top_votes == b.top_votes == 6
    pa = np.array(sorted(tuple(np.round(m.position, 6)) for m in a.top_maxima))
    pb = np.array(sorted(tuple(np.round(m.position, 6)) for m in b.top_maxima))
    np.testing.assert_allclose(pa, pb, atol=1e-5)


# --------------------------------------------------------------------------- model kinds


def _write(tmp_path, body: str):
    p = tmp_path / "m.toml"
    p.write_text(body, encoding="utf-8")
    return p


def test_model_kinds_load(tmp_path) -> None:
    from mks_sim.models.database import ModelDatabase
    from mks_sim.models.hough3d import TranslationHough3D

    p = _write(
        tmp_path,
        """
[[model]]
name = "tri"
kind = "rotinv"
points = [[0, 0, 0], [1, 0, 0], [0, 2, 0], [0, 0, 3]]
tolerance = 0.01
symmetry = "none"

[[model]]
name = "box"
kind = "hough3d"
points = [[0, 0, 0], [1, 0, 0], [0, 2, 0]]
reference = [0, 0, 0]
symmetry = "cube"
""",
    )
    db = ModelDatabase.from_files([p])
    tri = db.get("tri")
    assert isinstance(tri, RotationInvariantHough)
    assert tri.tolerance == pytest.approx(0.01) and tri.symmetries is None
    assert tri.min_gap > 0  # reference chosen automatically
    box = db.get("box")
    assert isinstance(box, TranslationHough3D)
    assert box.symmetries.shape == (24, 3, 3)


@pytest.mark.parametrize(
    ("body", "match"),
    [
        ("points = [[0, 0, 0], [1, 0, 0]]", "at least 3"),
        ('points = [[0, 0, 0], [1, 0, 0], [0, 1, 0]]\nsymmetry = "sphere"', "symmetry"),
        ("points = [[0, 0, 0], [1, 0, 0], [0, 1, 0]]\ntolerance = -1", "tolerance"),
        ("points = [[0, 0, 0], [1, 0, 0], [0, 1, 0]]\nreference = [1, 2]", "reference"),
        ('points = [[0, 0, 0], [1, 0, 0], [0, 1, 0]]\ncolour = "red"', "unknown field"),
        ("tolerance = 1.0", "'points' is missing"),
        ("points = [[0, 0, 0], [1, 0, 0], [0, 1, 0]]\nreference = [0, 0, 5]", "not distinct"),
    ],
)
def test_model_kind_errors(tmp_path, body: str, match: str) -> None:
    from mks_sim.models.database import ModelDatabase

    p = _write(tmp_path, f'[[model]]\nname = "bad"\nkind = "rotinv"\n{body}\n')
    with pytest.raises(SpecError, match=match) as info:
        ModelDatabase.from_files([p])
    assert "model 'bad'" in str(info.value)


@pytest.mark.parametrize("seed", range(8))
def test_partial_view_with_outliers(seed: int) -> None:
    # 4 of 8 points seen plus 2 spurious ones: outliers must not take the inliers' radii.
    rng = np.random.default_rng(100 + seed)
    model = rng.uniform(-1, 1, (8, 3))
    T_true = make_transform(random_rotation(rng), [1, 2, 3])
    det = np.vstack(
        [apply(T_true, model[:4]) + rng.normal(0, 0.002, (4, 3)), rng.uniform(-3, 3, (2, 3))]
    )
    hyps = RotationInvariantHough(model, tolerance=0.01).detect(det)
    pos, rot = _best_error(hyps, T_true)
    assert pos < 0.02 and rot < 2.0
