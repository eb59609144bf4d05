"""Rotation-invariant local signatures and repeatable keypoints of surface point sets.

A point's signature is computed from the points within a ball of radius ``r`` around it, at
two radii (scales). Per scale, with the neighbourhood covariance eigenvalues
``l0 <= l1 <= l2``, its centroid ``c`` and the point's unit normal ``n``:

* surface variation ``l0 / (l0 + l1 + l2)`` (0 on a plane, up to 1/3; curvature, edges,
  corners),
* anisotropy ``l1 / l2`` (near 1 inside a surface or at a corner, lower along an edge),
* convexity ``(p - c) . n / r`` (positive where the surface bulges towards the normal,
  negative in a hollow; needs outward / sensor-facing normals).

All three are invariant to rotation and translation, so a detected point can be paired only
with the model points it could be (the free-form Hough model, ``mks_sim.models.freeform``).
Keypoints are local maxima of the surface variation (non-maximum suppression over a ball),
above a floor: corners, hole rims, bump tops - points whose location is repeatable.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray
from scipy.sparse import csr_matrix
from scipy.spatial import cKDTree

__all__ = [
    "SIGNATURE_NAMES",
    "add_convexity",
    "ball_signatures",
    "estimate_normals_pca",
    "local_signatures",
    "nms_keypoints",
    "pca_normals_signed",
    "voxel_downsample",
]

FloatArray = NDArray[np.float64]

#: Signature components, in order (two scales).
SIGNATURE_NAMES = (
    "variation_r1",
    "anisotropy_r1",
    "convexity_r1",
    "variation_r2",
    "anisotropy_r2",
    "convexity_r2",
)

_K = 96  # neighbours per ball query (the cloud is thinned so that a ball holds fewer)


def cell_keys(cells: NDArray[np.int64]) -> NDArray[np.int64] | None:
    """One int64 per row of (N, 3) integer cells (mixed radix from the smallest cell): equal
    cells get equal keys and sorted keys are the cells in lexicographic order, the order of
    ``np.unique(cells, axis=0)``, which sorts rows as records ~10x slower than a 1-D sort.
    None when the cells span too much for one int64 (then use the rows)."""
    if len(cells) == 0:
        return np.zeros(0, np.int64)
    # column by column: numpy reduces an (N, 3) array along axis 0 ~7x slower than its three
    # columns one by one, and has no BLAS for an integer ``rel @ radix`` (the keys of a
    # 640 x 480 scan took 24 ms that way, 3 ms this way)
    x, y, z = (np.asarray(cells[:, d], dtype=np.int64) for d in range(3))
    lo = [int(c.min()) for c in (x, y, z)]
    span = [int(c.max()) - low + 1 for c, low in zip((x, y, z), lo, strict=True)]
    if float(span[0]) * float(span[1]) * float(span[2]) >= 2.0**62:
        return None
    return np.asarray(
        ((x - lo[0]) * (span[1] * span[2]) + (y - lo[1]) * span[2]) + (z - lo[2]), dtype=np.int64
    )


#: Keys from which :func:`unique_keys` sorts by the compiled radix sort (when numba imports).
_RADIX_MIN_KEYS = 1000


def _sort_order(keys: NDArray[np.int64]) -> NDArray[np.intp]:
    """An order sorting 1-D integer keys: the compiled radix sort for many non-negative
    int64 keys (the workstation scan's voxel keys 0.9 -> 0.1 ms), else numpy's argsort
    (the order among equal keys differs; :func:`unique_keys` does not depend on it)."""
    if len(keys) >= _RADIX_MIN_KEYS and keys.dtype == np.int64 and int(keys.min()) >= 0:
        from mks_sim.lowlevel import _gridknn

        if _gridknn.available():
            return _gridknn.sort_order(keys).astype(np.intp, copy=False)
    return np.argsort(keys)


def unique_keys(
    keys: NDArray[np.int64], *, first: bool = True
) -> tuple[NDArray[np.int64], NDArray[np.intp], NDArray[np.intp], NDArray[np.intp]]:
    """``np.unique(keys, return_index=True, return_inverse=True, return_counts=True)`` of
    1-D integer keys, from one argsort (``np.unique`` sorts for the inverse and again, a
    stable sort, for the first indices: a stable sort of 307k shuffled int64 keys took
    3-9x the time of the default sort).

    Returns:
        ``(unique, first, inverse, counts)``: the sorted distinct keys, the index of the
        first occurrence of each (empty when ``first`` is False: not computed), the (N,)
        index of each key's distinct key, and the counts.
    """
    keys = np.asarray(keys).reshape(-1)
    if len(keys) == 0:
        empty = np.zeros(0, dtype=np.intp)
        return keys.copy(), empty, empty, empty
    order = _sort_order(keys)
    ordered = keys[order]
    start = np.ones(len(keys), dtype=bool)
    np.not_equal(ordered[1:], ordered[:-1], out=start[1:])
    starts = np.flatnonzero(start)
    inverse = np.empty(len(keys), dtype=np.intp)
    inverse[order] = np.cumsum(start, dtype=np.intp) - 1
    # the first occurrence: the smallest index among equal keys (the sort need not be stable)
    firsts = np.minimum.reduceat(order, starts) if first else np.zeros(0, dtype=np.intp)
    counts = np.diff(np.append(starts, len(keys)))
    return ordered[starts], firsts, inverse, counts


def unique_cells(
    cells: NDArray[np.int64], *, first: bool = True
) -> tuple[NDArray[np.intp], NDArray[np.intp], NDArray[np.intp]]:
    """``np.unique(cells, axis=0, return_index=True, return_inverse=True,
    return_counts=True)`` of (N, 3) integer cells without the unique rows: ``(first,
    inverse, counts)``, the distinct cells in lexicographic order, from one int64 key per
    cell (:func:`cell_keys`, :func:`unique_keys`) or, for cells too far apart for that, the
    rows themselves. ``first`` is empty when not asked for."""
    keys = cell_keys(cells)
    if keys is not None:
        _, firsts, inverse, counts = unique_keys(keys, first=first)
        return firsts, inverse, counts
    if first:
        _, firsts, inverse, counts = np.unique(
            cells, axis=0, return_index=True, return_inverse=True, return_counts=True
        )
    else:
        _, inverse, counts = np.unique(cells, axis=0, return_inverse=True, return_counts=True)
        firsts = np.zeros(0, dtype=np.intp)
    return firsts, inverse.reshape(-1), counts


def first_in_each_cell(cells: NDArray[np.int64]) -> NDArray[np.int64]:
    """Ascending indices of the first row of each distinct (x, y, z) cell in ``cells``."""
    return np.sort(unique_cells(cells)[0]).astype(np.int64)


def voxel_downsample(points: FloatArray, spacing: float) -> NDArray[np.int64]:
    """Indices of one point per occupied voxel of edge ``spacing`` (the first, in input order)."""
    if len(points) == 0:
        return np.zeros(0, np.int64)
    from mks_sim.lowlevel._gridknn import column_bounds

    lo, _ = column_bounds(points)
    return first_in_each_cell(np.floor((points - lo) / spacing).astype(np.int64))


def _ball_neighbours(
    cloud: FloatArray, tree: cKDTree, queries: FloatArray, radius: float, k: int = _K
) -> csr_matrix:
    """(Q, N) 0/1 sparse matrix: row q marks the (at most ``k`` nearest) cloud points within
    ``radius`` of query q."""
    # Every pair within the radius by one dual-tree search (~3x faster than a k-nearest query
    # of the same balls); only when some ball holds more than k points is the k-nearest
    # query needed to choose among them.
    pairs = cKDTree(queries).sparse_distance_matrix(tree, radius, output_type="ndarray")
    if len(pairs) == 0 or np.bincount(pairs["i"], minlength=len(queries)).max() <= k:
        # rows in query order, each nearest first as the k-nearest query gives them (the
        # ball sums are then added in the same order, to the last bit)
        order = np.argsort(pairs["i"] + pairs["v"] / (2.0 * radius))
        indptr = np.zeros(len(queries) + 1, np.int64)
        np.cumsum(np.bincount(pairs["i"], minlength=len(queries)), out=indptr[1:])
        cols = pairs["j"][order]
        return csr_matrix((np.ones(len(cols)), cols, indptr), shape=(len(queries), len(cloud)))
    d, j = tree.query(queries, k=min(k, len(cloud)), distance_upper_bound=radius)
    if d.ndim == 1:
        d, j = d[:, None], j[:, None]
    ok = np.isfinite(d)  # (Q, k), row-major: column indices grouped by row
    indptr = np.zeros(len(queries) + 1, np.int64)
    np.cumsum(ok.sum(axis=1), out=indptr[1:])
    cols = j[ok]
    return csr_matrix((np.ones(len(cols)), cols, indptr), shape=(len(queries), len(cloud)))


def _ball_stats(
    cloud: FloatArray, tree: cKDTree, queries: FloatArray, radius: float, k: int = _K
) -> tuple[FloatArray, FloatArray, FloatArray, NDArray[np.int64], csr_matrix]:
    """Centroid (Q, 3), eigenvalues ascending (Q, 3), eigenvectors (Q, 3, 3), counts (Q,) and
    the neighbour matrix of :func:`_ball_neighbours`.

    The ball moments are one sparse product with the cloud's first and second moments (no
    (Q, k, 3) gathers), taken about the cloud's mean so that the covariance
    ``E[x x^T] - c c^T`` loses nothing at the object's scale.
    """
    nb = _ball_neighbours(cloud, tree, queries, radius, k)
    cnt = np.diff(nb.indptr).astype(np.int64)
    o = cloud.mean(axis=0) if len(cloud) else np.zeros(3)
    x = cloud - o
    iu, ju = np.triu_indices(3)
    mom = np.concatenate([x, x[:, iu] * x[:, ju]], axis=1)  # (N, 9): x and the 6 products
    s = nb @ mom / np.maximum(cnt, 1)[:, None]
    c = s[:, :3]
    cov = np.empty((len(queries), 3, 3))
    cov[:, iu, ju] = s[:, 3:] - c[:, iu] * c[:, ju]
    cov[:, ju, iu] = cov[:, iu, ju]
    cov[cnt == 0] = 0.0
    evals, evecs = np.linalg.eigh(cov)
    return c + o, np.clip(evals, 0.0, None), evecs, cnt, nb


def estimate_normals_pca(
    points: FloatArray, radius: float, viewpoint: FloatArray | None = None
) -> FloatArray:
    """(N, 3) unit normals by PCA over balls of ``radius``, oriented towards ``viewpoint``
    (or, without one, away from the cloud's centroid)."""
    tree = cKDTree(points)
    _, _, evecs, _, _ = _ball_stats(points, tree, points, radius)
    n = evecs[:, :, 0]
    ref = points - (points.mean(axis=0) if viewpoint is None else viewpoint)
    sign = np.einsum("ij,ij->i", n, ref)
    if viewpoint is not None:
        sign = -sign
    return n * np.where(sign < 0, -1.0, 1.0)[:, None]


def pca_normals_signed(
    cloud: FloatArray,
    cloud_normals: FloatArray,
    queries: FloatArray,
    radius: float,
    k: int = 48,
) -> FloatArray:
    """(Q, 3) PCA normals over balls of ``radius`` (at most ``k`` nearest cloud points each),
    signed to agree with the mean of the given (oriented) ``cloud_normals`` in each ball."""
    tree = cKDTree(cloud)
    _, _, evecs, _, nb = _ball_stats(cloud, tree, queries, radius, k)
    n = evecs[:, :, 0]
    mean_n = nb @ cloud_normals
    sign = np.where(np.einsum("ij,ij->i", n, mean_n) < 0, -1.0, 1.0)
    return n * sign[:, None]


def local_signatures(
    cloud: FloatArray,
    queries: FloatArray,
    query_normals: FloatArray,
    radii: tuple[float, float],
    min_count: int = 8,
) -> FloatArray:
    """(Q, 6) signatures of query locations over a cloud (NaN rows where a ball is too sparse).

    Args:
        cloud: (N, 3) surface points (the neighbourhoods); thinned internally per scale to
            about radius / 4 spacing.
        queries: (Q, 3) locations to describe (need not be cloud points).
        query_normals: (Q, 3) unit normals at the queries (outward / towards the sensor).
        radii: the two ball radii (points' units).
        min_count: fewer neighbours than this gives NaN.
    """
    sig, centroids = ball_signatures(cloud, queries, radii, min_count)
    return add_convexity(sig, centroids, queries, query_normals, radii)


def ball_signatures(
    cloud: FloatArray,
    queries: FloatArray,
    radii: tuple[float, float],
    min_count: int = 8,
) -> tuple[FloatArray, FloatArray]:
    """The normal-free part of :func:`local_signatures`: (Q, 6) signatures whose convexity
    columns are 0 (NaN rows where a ball is too sparse, as there) and the (2, Q, 3) ball
    centroids per scale, for :func:`add_convexity`.

    Variation and anisotropy (hence keypoint saliency) need no normals, so keypoints can be
    chosen first and normals estimated at the keypoints only.
    """
    out = np.full((len(queries), 6), np.nan)
    centroids = np.zeros((2, len(queries), 3))
    for s, r in enumerate(radii):
        sub = cloud[voxel_downsample(cloud, r / 4.0)]
        if len(sub) == 0:
            continue
        tree = cKDTree(sub)
        c, ev, _, cnt, _ = _ball_stats(sub, tree, queries, r)
        tot = ev.sum(axis=1)
        with np.errstate(divide="ignore", invalid="ignore"):
            var = ev[:, 0] / tot
            ani = ev[:, 1] / ev[:, 2]
        good = (cnt >= min_count) & (tot > 0)
        out[good, 3 * s] = var[good]
        out[good, 3 * s + 1] = ani[good]
        out[good, 3 * s + 2] = 0.0
        centroids[s] = c
    return out, centroids


def add_convexity(
    sig: FloatArray,
    centroids: FloatArray,
    queries: FloatArray,
    query_normals: FloatArray,
    radii: tuple[float, float],
) -> FloatArray:
    """Fill the convexity columns of :func:`ball_signatures` output in place (and return it):
    ``(q - c) . n / r`` per scale; NaN rows stay NaN."""
    for s, r in enumerate(radii):
        sig[:, 3 * s + 2] += np.einsum("ij,ij->i", queries - centroids[s], query_normals) / r
    return sig


def nms_keypoints(
    points: FloatArray, saliency: FloatArray, radius: float, floor: float
) -> NDArray[np.int64]:
    """Indices of points whose saliency is the maximum within ``radius`` and above ``floor``.

    Ties are broken by index (the lower index wins), so the result is deterministic.
    """
    cand = np.flatnonzero(np.isfinite(saliency) & (saliency > floor))
    if cand.size == 0:
        return cand.astype(np.int64)
    p = points[cand]
    s = saliency[cand]
    tree = cKDTree(p)
    d, j = tree.query(p, k=min(32, len(p)), distance_upper_bound=radius)
    if d.ndim == 1:
        d, j = d[:, None], j[:, None]
    ok = np.isfinite(d)
    jj = np.minimum(j, len(p) - 1)
    s_nb = np.where(ok, s[jj], -np.inf)
    idx_nb = np.where(ok, jj, len(p))
    own = np.arange(len(p))[:, None]
    beats = (s_nb > s[:, None]) | ((s_nb == s[:, None]) & (idx_nb < own))
    keep = ~beats.any(axis=1)
    return cand[keep].astype(np.int64)
