"""Rigid transforms: fits, conventions, pose errors, the cube group, PoseHypothesis."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st

from mks_sim.errors import DataError
from mks_sim.geometry.transforms import (
    apply,
    cross3,
    cube_rotations,
    from_row_convention,
    invert,
    make_transform,
    pose_error,
    random_rotation,
    rigid_fit,
    rotation_angle_deg,
    rotation_from_covariance,
    to_row_convention,
)
from mks_sim.models.pose import PoseHypothesis

seeds = st.integers(min_value=0, max_value=2**32 - 1)


def _random_rigid(rng: np.random.Generator) -> np.ndarray:
    return make_transform(random_rotation(rng), rng.uniform(-10, 10, 3))


@given(seeds, st.integers(min_value=3, max_value=40))
def test_rigid_fit_recovers_random_transform(seed: int, n: int) -> None:
    rng = np.random.default_rng(seed)
    src = rng.uniform(-5, 5, (n, 3))
    T = _random_rigid(rng)
    dst = apply(T, src)
    T_fit, rmse = rigid_fit(src, dst)
    assert rmse < 1e-8
    np.testing.assert_allclose(T_fit, T, atol=1e-8)
    assert np.linalg.det(T_fit[:3, :3]) == pytest.approx(1.0)


@given(seeds)
def test_rigid_fit_reflection_guard(seed: int) -> None:
    # A mirrored point set: the best proper rotation, never a reflection.
    rng = np.random.default_rng(seed)
    src = rng.uniform(-1, 1, (10, 3))
    dst = src * np.array([1.0, 1.0, -1.0])
    T, rmse = rigid_fit(src, dst)
    assert np.linalg.det(T[:3, :3]) == pytest.approx(1.0)
    assert rmse > 0


def test_rigid_fit_weights_ignore_outlier() -> None:
    rng = np.random.default_rng(1)
    src = rng.uniform(-1, 1, (8, 3))
    T = _random_rigid(rng)
    dst = apply(T, src)
    dst[0] += 100.0
    w = np.ones(8)
    w[0] = 0.0
    T_fit, rmse = rigid_fit(src, dst, w)
    np.testing.assert_allclose(T_fit, T, atol=1e-8)
    assert rmse < 1e-8


def test_rigid_fit_bad_input() -> None:
    with pytest.raises(DataError, match="pair up"):
        rigid_fit(np.zeros((3, 3)), np.zeros((4, 3)))
    with pytest.raises(DataError, match="NaN"):
        rigid_fit(np.full((3, 3), np.nan), np.zeros((3, 3)))
    with pytest.raises(DataError, match=r"\(N, 3\)"):
        rigid_fit(np.zeros((3, 2)), np.zeros((3, 2)))
    with pytest.raises(DataError, match="weights"):
        rigid_fit(np.zeros((3, 3)), np.zeros((3, 3)), weights=[-1, 1, 1])


@given(seeds)
def test_row_column_round_trip(seed: int) -> None:
    rng = np.random.default_rng(seed)
    T = _random_rigid(rng)
    M = to_row_convention(T)
    np.testing.assert_array_equal(from_row_convention(M), T)
    p = rng.uniform(-3, 3, 3)
    # The paper's convention: p' = [p 1] @ M.
    np.testing.assert_allclose(np.append(p, 1.0) @ M, np.append(apply(T, p), 1.0), atol=1e-12)
    np.testing.assert_allclose(M[3, :3], T[:3, 3])


@given(seeds)
def test_invert(seed: int) -> None:
    T = _random_rigid(np.random.default_rng(seed))
    np.testing.assert_allclose(invert(T) @ T, np.eye(4), atol=1e-12)


def test_invert_of_a_float64_array_equals_the_general_path_to_the_bit() -> None:
    """The float64 (4, 4) array's inverse (no general checks) equals the general path's
    (a list, float32) bit for bit; NaN or inf raises on both; finite entries whose sum
    overflows do not."""
    rng = np.random.default_rng(3)
    for _ in range(50):
        T = _random_rigid(rng)
        T[:3, 3] *= 10.0 ** rng.uniform(-3, 3)
        general = make_transform(T[:3, :3].T, -T[:3, :3].T @ T[:3, 3])
        assert invert(T).tobytes() == general.tobytes()
        assert invert(T.tolist()).tobytes() == general.tobytes()
        F = np.asfortranarray(T)  # (the product's rounding may follow the layout)
        assert invert(F).tobytes() == make_transform(F[:3, :3].T, -F[:3, :3].T @ F[:3, 3]).tobytes()
    T32 = _random_rigid(rng).astype(np.float32)
    R = T32[:3, :3].astype(np.float64)
    want = make_transform(R.T, -R.T @ T32[:3, 3].astype(np.float64))
    assert invert(T32).tobytes() == want.tobytes()
    for bad in (np.nan, np.inf, -np.inf):
        T = np.eye(4)
        T[1, 3] = bad
        with pytest.raises(DataError, match="finite"):
            invert(T)
        with pytest.raises(DataError, match="finite"):
            invert(T.tolist())
    huge = np.eye(4)
    huge[:3, 3] = 1e308
    assert np.isfinite(invert(huge)[:3, :3]).all()


def test_cube_rotations_is_group_of_24() -> None:
    G = cube_rotations()
    assert G.shape == (24, 3, 3)
    np.testing.assert_array_equal(G[0], np.eye(3))
    keys = {tuple(R.astype(int).ravel()) for R in G}
    assert len(keys) == 24
    for R in G:
        assert np.linalg.det(R) == pytest.approx(1.0)
        np.testing.assert_allclose(R @ R.T, np.eye(3))
    for A in G:  # closure
        for B in G:
            assert tuple((A @ B).astype(int).ravel()) in keys
    # Each maps the cube's vertex set onto itself.
    cube = np.array([[x, y, z] for x in (-1, 1) for y in (-1, 1) for z in (-1, 1)], float)
    ref = {tuple(v) for v in cube}
    for R in G:
        assert {tuple(v) for v in cube @ R.T} == ref


def test_random_rotation_uniform() -> None:
    rng = np.random.default_rng(7)
    Rs = np.array([random_rotation(rng) for _ in range(4000)])
    np.testing.assert_allclose(
        np.einsum("nij,nkj->nik", Rs, Rs), np.broadcast_to(np.eye(3), Rs.shape), atol=1e-12
    )
    assert np.allclose(np.linalg.det(Rs), 1.0)
    # Haar measure: E[R] = 0 and the rotation angle has density (1 - cos a)/pi, mean pi/2 + 2/pi.
    assert np.abs(Rs.mean(axis=0)).max() < 0.05
    angles = np.arccos(np.clip((np.trace(Rs, axis1=1, axis2=2) - 1) / 2, -1, 1))
    assert angles.mean() == pytest.approx(np.pi / 2 + 2 / np.pi, abs=0.03)


def test_rotation_angle_and_pose_error() -> None:
    c, s = math.cos(math.radians(30)), math.sin(math.radians(30))
    Rz = np.array([[c, -s, 0], [s, c, 0], [0, 0, 1]])
    assert rotation_angle_deg(np.eye(3), Rz) == pytest.approx(30.0)
    T_true = make_transform(np.eye(3), [1, 2, 3])
    T_est = make_transform(Rz, [1, 2, 3.5])
    pos, rot = pose_error(T_est, T_true)
    assert pos == pytest.approx(0.5) and rot == pytest.approx(30.0)
    # A cube rotated by 90 degrees is the same cube: zero error modulo its symmetries.
    R90 = np.array([[0, -1, 0], [1, 0, 0], [0, 0, 1]], float)
    T_sym = make_transform(R90, [1, 2, 3])
    assert pose_error(T_sym, T_true)[1] == pytest.approx(90.0)
    assert pose_error(T_sym, T_true, cube_rotations())[1] == pytest.approx(0.0, abs=1e-6)


def test_pose_hypothesis() -> None:
    T = make_transform(np.eye(3), [5, 0, 0])
    h = PoseHypothesis(T, [6.5, 1.3, 1.25], votes=8, correspondences=[[0, 1], [2, 3]], rmse=0.0)
    assert math.isnan(h.score)
    np.testing.assert_array_equal(h.matrix_row_convention[3], [5, 0, 0, 1])
    with pytest.raises(ValueError):
        h.matrix[0, 0] = 2.0
    assert h.with_score(0.9).score == pytest.approx(0.9)
    assert h.correspondences.dtype == np.int64
    with pytest.raises(DataError, match=r"\(n, 2\)"):
        PoseHypothesis(T, [0, 0, 0], correspondences=[1, 2, 3])
    with pytest.raises(DataError, match=r"\(4, 4\)"):
        PoseHypothesis(np.eye(3), [0, 0, 0])


def test_pose_hypothesis_many_equals_one_by_one() -> None:
    rng = np.random.default_rng(3)
    mats = np.stack([make_transform(random_rotation(rng), rng.normal(size=3)) for _ in range(5)])
    refs = rng.normal(size=(5, 3))
    corrs = [np.arange(2 * k).reshape(-1, 2) for k in range(5)]
    votes = [4, 3, 3, 1, 0]
    many = PoseHypothesis.many(mats, refs, votes, corrs)
    mats[0, 0, 0] = 9.0  # the caller's arrays may change later
    corrs[1][0, 0] = 9
    for k, h in enumerate(many):
        one = PoseHypothesis(mats[k] if k else many[0].matrix, refs[k], votes[k], corrs[k])
        np.testing.assert_array_equal(h.matrix, one.matrix)
        np.testing.assert_array_equal(h.reference_point, one.reference_point)
        if k != 1:
            np.testing.assert_array_equal(h.correspondences, one.correspondences)
        assert h.correspondences.shape == (k, 2) and h.correspondences.dtype == np.int64
        assert h.votes == votes[k] and type(h.votes) is int
        assert math.isnan(h.rmse) and math.isnan(h.score)
        for arr in (h.matrix, h.reference_point, h.correspondences):
            assert not arr.flags.writeable
    assert many[0].matrix[0, 0] != 9.0 and many[1].correspondences[0, 0] == 0
    assert many[2].with_score(0.5).score == 0.5
    with pytest.raises(DataError, match=r"\(K, 4, 4\)"):
        PoseHypothesis.many(mats[:, :3], refs, votes, corrs)
    with pytest.raises(DataError, match="5 votes"):
        PoseHypothesis.many(mats, refs, votes[:4], corrs)
    with pytest.raises(DataError, match=r"\(n, 2\)"):
        PoseHypothesis.many(mats[:1], refs[:1], [1], [np.arange(3)])
    # correspondences of one shape (a matcher's: stacked once), int32 and empty ones
    for same in (
        [rng.integers(0, 9, size=(3, 2)).astype(np.int32) for _ in range(5)],
        [np.zeros((0, 2), dtype=np.int64) for _ in range(5)],
    ):
        kept = [c.copy() for c in same]
        stacked = PoseHypothesis.many(mats, refs, votes, same)
        same[2][...] = 7  # the caller's arrays may change later
        for k, h in enumerate(stacked):
            one = PoseHypothesis(mats[k], refs[k], votes[k], kept[k])
            np.testing.assert_array_equal(h.correspondences, one.correspondences)
            assert h.correspondences.dtype == np.int64 and not h.correspondences.flags.writeable


def test_pose_hypothesis_many_takes_the_pairs_in_one_array_with_their_counts() -> None:
    """``many(..., pairs, pair_counts)``: the same hypotheses as one array of pairs per
    hypothesis, read-only and safe from the caller's later changes; counts that do not
    add up to the pairs, or are not one per hypothesis, are refused."""
    rng = np.random.default_rng(4)
    mats = np.stack([make_transform(random_rotation(rng), rng.normal(size=3)) for _ in range(5)])
    refs = rng.normal(size=(5, 3))
    votes = [4, 3, 3, 1, 0]
    counts = [2, 0, 3, 1, 4]
    each = [rng.integers(0, 9, size=(c, 2)) for c in counts]
    flat = np.concatenate(each).astype(np.int32)
    got = PoseHypothesis.many(mats, refs, votes, flat, counts)
    flat[...] = -1  # the caller's array may change later
    want = PoseHypothesis.many(mats, refs, votes, each)
    for g, w in zip(got, want, strict=True):
        np.testing.assert_array_equal(g.correspondences, w.correspondences)
        assert g.correspondences.dtype == np.int64 and not g.correspondences.flags.writeable
        np.testing.assert_array_equal(g.matrix, w.matrix)
        assert g.votes == w.votes
    with pytest.raises(DataError, match="pair counts"):
        PoseHypothesis.many(mats, refs, votes, np.concatenate(each), [2, 0, 3, 1, 3])
    with pytest.raises(DataError, match="pair counts"):
        PoseHypothesis.many(mats, refs, votes, np.concatenate(each), [2, 0, 3, 5])


def test_rotation_from_covariance_batched_recovers_rotations_and_matches_single() -> None:
    """Batched Kabsch: K random rotations recovered from noise-free pairs, each equal to the
    one-matrix call, det +1 even for a reflection's covariance."""
    rng = np.random.default_rng(11)
    src = rng.normal(size=(6, 3))
    Rs = np.stack([random_rotation(rng) for _ in range(5)])
    H = np.stack([src.T @ (src @ R.T) for R in Rs])  # sum src_i dst_i^T, dst = R src
    got = rotation_from_covariance(H)
    assert got.shape == (5, 3, 3)
    np.testing.assert_allclose(got, Rs, atol=1e-9)
    for k in range(5):
        np.testing.assert_allclose(rotation_from_covariance(H[k]), got[k], atol=1e-12)
    mirror = np.diag([1.0, 1.0, -1.0])
    R_m = rotation_from_covariance(src.T @ (src @ mirror.T))
    assert np.linalg.det(R_m) == pytest.approx(1.0)


def test_cross3_is_numpys_cross_to_the_bit() -> None:
    rng = np.random.default_rng(4)
    for _ in range(2000):
        a = rng.normal(size=3) * 10.0 ** rng.uniform(-6, 6)
        b = rng.normal(size=3) * 10.0 ** rng.uniform(-6, 6)
        assert np.array_equal(cross3(a, b), np.cross(a, b))
    assert cross3([1.0, 0.0, 0.0], [0.0, 1.0, 0.0]).tolist() == [0.0, 0.0, 1.0]
