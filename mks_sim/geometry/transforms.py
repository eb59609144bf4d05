"""Rigid transformations: 4x4 homogeneous matrices, least-squares fits and pose errors.

Column convention throughout (``p' = T @ p``, translation in the last column). The paper prints
row-vector matrices (``p' = p @ M``, translation in the bottom row, section 4.2);
:func:`to_row_convention` / :func:`from_row_convention` convert where the paper is compared.
"""

from __future__ import annotations

import functools
import itertools
import math

import numpy as np
from numpy.typing import ArrayLike, NDArray

from mks_sim.errors import DataError
from mks_sim.geometry.points import as_points

__all__ = [
    "apply",
    "cube_rotations",
    "from_row_convention",
    "invert",
    "make_transform",
    "pose_error",
    "random_rotation",
    "rigid_fit",
    "rigid_fit_unchecked",
    "rotation_angle_deg",
    "rotation_from_covariance",
    "to_row_convention",
]

FloatArray = NDArray[np.float64]


def _as_matrix(T: ArrayLike, name: str) -> FloatArray:
    arr = np.asarray(T, dtype=np.float64)
    if arr.shape != (4, 4):
        raise DataError(f"{name}: expected a 4x4 homogeneous matrix, got shape {arr.shape}")
    if not np.all(np.isfinite(arr)):
        raise DataError(f"{name}: expected finite entries, got NaN or inf")
    return arr


def cross3(a: ArrayLike, b: ArrayLike) -> FloatArray:
    """``np.cross`` of two 3-vectors to the bit (numpy multiplies and subtracts the same
    pairs: ``a1 b2 - a2 b1``, ...), without its broadcasting machinery (3 us against 16:
    the plane-pair hypotheses take three per pair of faces)."""
    a0, a1, a2 = (float(x) for x in np.asarray(a, dtype=np.float64).reshape(3))
    b0, b1, b2 = (float(x) for x in np.asarray(b, dtype=np.float64).reshape(3))
    return np.array([a1 * b2 - a2 * b1, a2 * b0 - a0 * b2, a0 * b1 - a1 * b0])


def make_transform(R: ArrayLike, t: ArrayLike) -> FloatArray:
    """Build a 4x4 column-convention transform from a rotation and a translation.

    Args:
        R: (3, 3) rotation matrix.
        t: (3,) translation.

    Returns:
        (4, 4) float array ``[[R, t], [0, 0, 0, 1]]``.
    """
    R_arr = np.asarray(R, dtype=np.float64)
    t_arr = np.asarray(t, dtype=np.float64).reshape(-1)
    if R_arr.shape != (3, 3) or t_arr.shape != (3,):
        raise DataError(
            f"make_transform: expected R (3, 3) and t (3,), got {R_arr.shape} and {t_arr.shape}"
        )
    T = np.eye(4)
    T[:3, :3] = R_arr
    T[:3, 3] = t_arr
    return T


def apply(T: ArrayLike, points: ArrayLike) -> FloatArray:
    """Apply a column-convention transform to points.

    Args:
        T: (4, 4) transform, ``p' = T @ p``.
        points: (N, 3) or (3,) points.

    Returns:
        Transformed points with the input's shape ((N, 3) or (3,)).
    """
    M = _as_matrix(T, "apply: T")
    arr = np.asarray(points, dtype=np.float64)
    single = arr.ndim == 1
    pts = as_points(arr, "apply: points", allow_single=True)
    out = pts @ M[:3, :3].T + M[:3, 3]
    return out[0] if single else out


def invert(T: ArrayLike) -> FloatArray:
    """Inverse of a rigid transform (uses ``R^T``, exact for proper rigid motions)."""
    if type(T) is np.ndarray and T.dtype == np.float64 and T.shape == (4, 4):
        # the common case, a float64 4 x 4 array: the same values without the general
        # checks and copies (26 -> 15 us; verification inverts a few poses per hypothesis);
        # a sum that is not finite means an entry may not be (or only overflowed: looked at)
        if not math.isfinite(T.sum()) and not np.all(np.isfinite(T)):
            raise DataError("invert: T: expected finite entries, got NaN or inf")
        R = T[:3, :3]
        out = np.empty((4, 4))
        out[:3, :3] = R.T
        out[:3, 3] = -R.T @ T[:3, 3]
        out[3] = (0.0, 0.0, 0.0, 1.0)
        return out
    M = _as_matrix(T, "invert: T")
    R = M[:3, :3]
    return make_transform(R.T, -R.T @ M[:3, 3])


def to_row_convention(T: ArrayLike) -> FloatArray:
    """Convert a column-convention transform to the paper's row convention (``p' = p @ M``).

    Args:
        T: (4, 4) column-convention transform.

    Returns:
        (4, 4) ``M = T.T``: rotation ``R^T`` in the top-left block, translation in the bottom row.
    """
    return _as_matrix(T, "to_row_convention: T").T.copy()


def from_row_convention(M: ArrayLike) -> FloatArray:
    """Convert a row-convention matrix (``p' = p @ M``, translation in the bottom row) to ours.

    Args:
        M: (4, 4) row-convention matrix as the paper prints it.

    Returns:
        (4, 4) column-convention transform ``M.T``.
    """
    return _as_matrix(M, "from_row_convention: M").T.copy()


def rotation_from_covariance(H: FloatArray) -> FloatArray:
    """The proper rotation ``R`` (det +1) maximising ``trace(R H)`` for a cross-covariance
    ``H = sum_i w_i src_i dst_i^T`` (so ``R src_i ~ dst_i``: the Kabsch step), batched over
    any leading axes ((..., 3, 3) in, (..., 3, 3) out). The reflection guard flips the
    smallest singular direction when the SVD would give det -1.
    """
    U, _, Vt = np.linalg.svd(H)
    V = np.swapaxes(Vt, -1, -2).copy()
    Ut = np.swapaxes(U, -1, -2)
    d = np.sign(np.linalg.det(V @ Ut))
    d = np.where(d == 0, 1.0, d)
    V[..., :, 2] *= d[..., None]
    return np.asarray(V @ Ut, dtype=np.float64)


def rigid_fit(
    src: ArrayLike, dst: ArrayLike, weights: ArrayLike | None = None
) -> tuple[FloatArray, float]:
    """Least-squares rigid transform mapping ``src`` onto ``dst`` (Kabsch / Umeyama, no scale).

    Minimises ``sum_i w_i |R src_i + t - dst_i|^2`` over proper rotations (det +1): the
    reflection guard flips the smallest singular direction when the SVD would give det -1.

    Args:
        src: (N, 3) source points (e.g. model frame), N >= 3 for a unique rotation
            (fewer points, or collinear points, give one of the optimal rotations).
        dst: (N, 3) destination points (e.g. detected frame), paired row by row.
        weights: optional (N,) non-negative weights (not all zero).

    Returns:
        ``(T, rmse)``: (4, 4) column-convention transform ``dst ~ T @ src`` and the
        (weighted) root-mean-square residual in the points' units.

    Raises:
        DataError: shapes differ, fewer than one pair, NaN, or bad weights.
    """
    P = as_points(src, "rigid_fit: src", allow_single=True)
    Q = as_points(dst, "rigid_fit: dst", allow_single=True)
    if P.shape != Q.shape:
        raise DataError(f"rigid_fit: src and dst must pair up, got {P.shape} and {Q.shape}")
    n = P.shape[0]
    if n == 0:
        raise DataError("rigid_fit: expected at least one point pair, got none")
    if weights is None:
        w = np.full(n, 1.0 / n)
    else:
        w = np.asarray(weights, dtype=np.float64).reshape(-1)
        if w.shape != (n,) or not np.all(np.isfinite(w)) or np.any(w < 0) or w.sum() <= 0:
            raise DataError(
                f"rigid_fit: expected {n} finite non-negative weights with a positive sum, "
                f"got shape {w.shape}"
            )
        w = w / w.sum()
    return _kabsch(P, Q, w)


def rigid_fit_unchecked(src: FloatArray, dst: FloatArray) -> tuple[FloatArray, float]:
    """:func:`rigid_fit` without weights for (N, 3) finite float64 arrays, N >= 1, that the
    caller has validated: the same arithmetic (and so the same bits) without the checks,
    for a matcher's inner loop (the rotation-invariant Hough fits one per maximum)."""
    n = src.shape[0]
    return _kabsch(src, dst, np.full(n, 1.0 / n))


def _kabsch(P: FloatArray, Q: FloatArray, w: FloatArray) -> tuple[FloatArray, float]:
    """The weighted Kabsch fit of validated points, ``w`` summing to one."""
    mu_p = w @ P
    mu_q = w @ Q
    Pc = P - mu_p
    Qc = Q - mu_q
    H = (Pc * w[:, None]).T @ Qc  # (3, 3) weighted cross-covariance
    R = rotation_from_covariance(H)
    t = mu_q - R @ mu_p
    resid = Q - (P @ R.T + t)
    rmse = float(np.sqrt(w @ np.sum(resid**2, axis=1)))
    T = np.eye(4)
    T[:3, :3] = R
    T[:3, 3] = t
    return T, rmse


def rotation_angle_deg(R_a: ArrayLike, R_b: ArrayLike) -> float:
    """Angle of the relative rotation ``R_a^T R_b`` in degrees (geodesic distance on SO(3)).

    Args:
        R_a: (3, 3) rotation (a (4, 4) transform's rotation block is used if given).
        R_b: (3, 3) rotation, likewise.

    Returns:
        Angle in degrees, in [0, 180].
    """
    A = np.asarray(R_a, dtype=np.float64)[:3, :3]
    B = np.asarray(R_b, dtype=np.float64)[:3, :3]
    c = (np.trace(A.T @ B) - 1.0) / 2.0
    return float(np.degrees(np.arccos(np.clip(c, -1.0, 1.0))))


def pose_error(
    T_est: ArrayLike,
    T_true: ArrayLike,
    symmetries: ArrayLike | None = None,
) -> tuple[float, float]:
    """Position and rotation error of an estimated pose, modulo the model's symmetries.

    A symmetry ``S`` (a rotation of the model frame about its origin that maps the model onto
    itself) makes ``T_true @ S`` an equally correct pose; the error is the minimum over the set.

    Args:
        T_est: (4, 4) estimated model->world (column convention).
        T_true: (4, 4) true model->world.
        symmetries: optional (K, 3, 3) rotations (e.g. :func:`cube_rotations`); the identity is
            always included.

    Returns:
        ``(position_err, rotation_err_deg)``: translation distance (points' units) and
        relative rotation angle in degrees, both of the best symmetric equivalent (chosen by
        rotation error, then position error).
    """
    E = _as_matrix(T_est, "pose_error: T_est")
    G = _as_matrix(T_true, "pose_error: T_true")
    if symmetries is None:
        syms = np.eye(3)[None]
    else:
        syms = np.asarray(symmetries, dtype=np.float64)
        if syms.ndim != 3 or syms.shape[1:] != (3, 3):
            raise DataError(f"pose_error: expected (K, 3, 3) symmetries, got {syms.shape}")
        syms = np.concatenate([np.eye(3)[None], syms])
    best = (np.inf, np.inf)
    for S in syms:
        R_true = G[:3, :3] @ S
        rot = rotation_angle_deg(E[:3, :3], R_true)
        # A symmetry about the model origin leaves the origin's image (translation) fixed.
        pos = float(np.linalg.norm(E[:3, 3] - G[:3, 3]))
        if (rot, pos) < (best[1], best[0]):
            best = (pos, rot)
    return best


@functools.lru_cache(maxsize=1)
def _cube_rotations() -> FloatArray:
    mats = []
    for perm in itertools.permutations(range(3)):
        for signs in itertools.product((1.0, -1.0), repeat=3):
            R = np.zeros((3, 3))
            for row, (col, s) in enumerate(zip(perm, signs)):
                R[row, col] = s
            if np.linalg.det(R) > 0:
                mats.append(R)
    out = np.array(mats)
    out.setflags(write=False)
    return out


def cube_rotations() -> FloatArray:
    """The 24 proper rotations of the cube (signed permutation matrices with det +1).

    Returns:
        (24, 3, 3) float array, the identity first.
    """
    return _cube_rotations().copy()


def random_rotation(rng: np.random.Generator) -> FloatArray:
    """A rotation drawn uniformly (Haar measure) on SO(3).

    Uses a random unit quaternion (normalised 4-D Gaussian), which is uniform on SO(3).

    Args:
        rng: the random generator.

    Returns:
        (3, 3) rotation matrix.
    """
    q = rng.standard_normal(4)
    q /= np.linalg.norm(q)
    w, x, y, z = q
    return np.array(
        [
            [1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)],
            [2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)],
            [2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)],
        ]
    )
