"""Surface normals and curvature by PCA over spatial-proximity-graph neighbourhoods.

The paper's "Surface_Curvature" logical sensor (section 4.1, Table 4-5) returns
``(x, y, z, n)`` with ``n = +1`` on curved and ``-1`` on planar surface points. We compute it
from the spatial proximity graph (section 1.2): each point's neighbourhood is the point and its
SPG neighbours; the covariance of that neighbourhood gives the normal (eigenvector of the
smallest eigenvalue) and the *surface variation* ``lambda_0 / (lambda_0 + lambda_1 +
lambda_2)`` (Pauly et al. 2002), which is 0 on a plane and grows with curvature (and noise).
"""

from __future__ import annotations

import logging
from dataclasses import dataclass
from functools import cached_property
from typing import Any, Protocol

import numpy as np
from numpy.typing import ArrayLike, NDArray
from scipy import sparse

from mks_sim.geometry.points import as_points
from mks_sim.lowlevel._gridknn import column_mean
from mks_sim.lowlevel.spg import SpatialProximityGraph

__all__ = [
    "DEFAULT_CURVATURE_THRESHOLD",
    "FixedGraph",
    "SurfaceNormals",
    "as_points",
    "build_graph",
    "curvature_code",
    "estimate_normals",
    "neighbour_table",
    "smallest_eigenvalue",
]

log = logging.getLogger(__name__)

FloatArray = NDArray[np.float64]

#: Surface variation above which a point is coded curved (+1), else planar (-1).
#: On a sphere of radius R with neighbourhoods of radius r the variation is about
#: r^2 / (24 R^2) (a paraboloid cap); on a plane with noise sigma about 2 sigma^2 / r^2.
#: With the default two-ring SPG neighbourhoods (m = 12, r ~ 2.5 spacings) 0.003 codes a
#: sphere whose radius is up to ~8 sampling spacings as curved and a plane with noise up
#: to ~8% of the spacing as planar (measured: docs/grouping.md). Other scales: ``threshold=``.
DEFAULT_CURVATURE_THRESHOLD = 0.003


class GraphLike(Protocol):
    """Anything with a (N, N) sparse adjacency whose row i lists i's neighbours (an SPG)."""

    @property
    def adjacency(self) -> Any: ...


class FixedGraph:
    """A graph whose CSR adjacency is built once (an SPG builds it per access) and whose
    symmetric closure ``A + A.T`` (the undirected neighbourhoods of multi-ring normals and
    region growing) is computed at most once, on first use."""

    def __init__(self, adjacency: Any) -> None:
        self.adjacency = sparse.csr_array(adjacency)

    @classmethod
    def of(cls, graph: GraphLike) -> FixedGraph:
        """``graph`` itself when it is a FixedGraph, else a FixedGraph of its adjacency."""
        return graph if isinstance(graph, FixedGraph) else cls(graph.adjacency)

    @cached_property
    def symmetric(self) -> sparse.csr_array:
        """``A + A.T`` as CSR (entries: summed edge lengths; the pattern is what counts)."""
        return sparse.csr_array(self.adjacency + self.adjacency.T)


def symmetric_adjacency(graph: GraphLike) -> sparse.csr_array:
    """``A + A.T`` of a graph's adjacency (cached on a :class:`FixedGraph`)."""
    return FixedGraph.of(graph).symmetric


@dataclass(frozen=True, eq=False)
class SurfaceNormals:
    """Per-point normals and surface variation.

    Attributes:
        normals: (N, 3) float unit normals (oriented towards the viewpoint when one was given,
            else away from the cloud's centroid).
        curvature: (N,) float surface variation in [0, 1/3].
    """

    normals: FloatArray
    curvature: FloatArray


#: Points from which :func:`build_graph` builds the SPG on the compiled grid.
_GRID_GRAPH_MIN_POINTS = 500


def build_graph(points: FloatArray, m: int = 12, threshold: float | None = None) -> GraphLike:
    """``SpatialProximityGraph(points, m=m, threshold=threshold)`` (the one SPG; this name is
    kept for callers outside the low level until they construct the SPG themselves): on the
    compiled grid from :data:`_GRID_GRAPH_MIN_POINTS` points when numba imports (the
    grouping's kernels have imported it; the same graph as the tree's, in a fraction of
    the time: ``localize_cloud``'s object points of a 640 x 480 scan), else by the tree."""
    from mks_sim.lowlevel import _gridknn

    pts = np.asarray(points, dtype=np.float64)
    grid = (
        pts.ndim == 2 and len(pts) >= _GRID_GRAPH_MIN_POINTS and pts.shape[1] <= 3
        and _gridknn.available()
    )  # fmt: skip
    return SpatialProximityGraph(points, m=m, threshold=threshold, method="grid" if grid else "auto")


def neighbour_table(
    graph: GraphLike, include_self: bool = True, rings: int = 1
) -> tuple[NDArray[np.intp], NDArray[np.bool_]]:
    """The SPG's neighbour lists as a padded table.

    Args:
        graph: the SPG.
        include_self: put each point first in its own list.
        rings: 1 = the SPG neighbours; 2 = also the neighbours' neighbours (undirected), etc.

    Returns:
        ``(idx, valid)``: (N, K) int neighbour indices (column 0 is the point itself when
        ``include_self``), padded with the point's own index, and the (N, K) mask of real
        entries.
    """
    adj = sparse.csr_array(graph.adjacency)
    n = adj.shape[0]
    if rings > 1:
        one = sparse.csr_array((adj + adj.T) > 0, dtype=np.float64)
        reach = one.copy()
        for _ in range(rings - 1):
            reach = sparse.csr_array(((reach @ one) + reach) > 0, dtype=np.float64)
        reach.setdiag(0)
        reach.eliminate_zeros()
        adj = sparse.csr_array(reach)
        adj.sort_indices()
    counts = np.diff(adj.indptr)
    k = int(counts.max(initial=0)) + int(include_self)
    idx = np.repeat(np.arange(n)[:, None], max(k, 1), axis=1)
    valid = np.zeros((n, max(k, 1)), dtype=bool)
    offset = int(include_self)
    if include_self:
        valid[:, 0] = True
    if adj.nnz:
        rows = np.repeat(np.arange(n), counts)
        cols = np.arange(adj.nnz) - np.repeat(adj.indptr[:-1], counts) + offset
        idx[rows, cols] = adj.indices
        valid[rows, cols] = True
    return idx, valid


def _ring_matrix(graph: GraphLike, rings: int) -> sparse.csr_array:
    """(N, N) 0/1 matrix whose row i marks i and its neighbourhood of ``rings`` SPG rings
    (ring 1: i's own SPG row; more rings: undirected reachability, as :func:`neighbour_table`).

    More rings are powers of ``S + I`` (``S`` the symmetric 0/1 SPG): one sparse product per
    extra ring, the pattern then reset to ones (no boolean round trips).
    """
    adj = sparse.csr_array(graph.adjacency)
    n = adj.shape[0]
    ones = sparse.csr_array((np.ones(adj.nnz), adj.indices, adj.indptr), shape=(n, n))
    eye = sparse.eye_array(n, format="csr", dtype=np.float64)
    if rings > 1:
        step = sparse.csr_array(ones + ones.T + eye)
        out = step
        for _ in range(rings - 1):
            out = sparse.csr_array(out @ step)
    else:
        out = sparse.csr_array(ones + eye)
    out.data[:] = 1.0  # every stored entry is a positive sum: the pattern is the neighbourhood
    return out


def _pca_sparse(pts: FloatArray, A: sparse.csr_array) -> tuple[FloatArray, FloatArray]:
    """Normals and surface variation of every neighbourhood (rows of ``A``)."""
    return _smallest_eigen(_sparse_cov(pts, A))


def _sparse_cov(pts: FloatArray, A: sparse.csr_array) -> FloatArray:
    """(N, 6) covariances (xx xy xz yy yz zz) of every neighbourhood (rows of ``A``) from
    first and second moments accumulated by sparse products (no (N, K, 3) gather)."""
    c = pts - column_mean(pts)  # centred: the moments do not cancel catastrophically
    cnt = np.asarray(A.sum(axis=1)).reshape(-1)
    mean = (A @ c) / cnt[:, None]
    iu = (np.array([0, 0, 0, 1, 1, 2]), np.array([0, 1, 2, 1, 2, 2]))
    prod = c[:, iu[0]] * c[:, iu[1]]  # (N, 6)
    second = (A @ prod) / cnt[:, None]
    return second - mean[:, iu[0]] * mean[:, iu[1]]  # (N, 6): xx xy xz yy yz zz


#: Points from which multi-ring neighbourhoods use the compiled kernel (when numba imports).
_COMPILED_MIN_POINTS = 500


def _ring_pca(pts: FloatArray, graph: GraphLike, rings: int) -> tuple[FloatArray, FloatArray]:
    """Normals and surface variation over the neighbourhoods of ``rings`` SPG rings."""
    return _smallest_eigen(_ring_cov(pts, graph, rings))


def _ring_cov(pts: FloatArray, graph: GraphLike, rings: int) -> FloatArray:
    """(N, 6) covariances of the neighbourhoods of ``rings`` SPG rings: ring 1 by the
    compiled twin of the sparse products (:func:`mks_sim.lowlevel._gridknn.ring1_cov`);
    more rings by the compiled breadth-first kernel
    (:func:`mks_sim.lowlevel._regions_kernels.ring_moments`, no (N, N) ring matrix) when
    numba imports, else by :func:`_sparse_cov` over :func:`_ring_matrix` (the reference)."""
    from mks_sim.lowlevel import _gridknn

    if len(pts) < _COMPILED_MIN_POINTS or not _gridknn.available():
        return _sparse_cov(pts, _ring_matrix(graph, rings))
    if rings < 2:  # the sparse products' values, without the ring matrix
        adj = sparse.csr_array(graph.adjacency)
        if adj.shape == (len(pts), len(pts)):
            cov = _gridknn.ring1_cov(adj, pts - column_mean(pts))
            if cov is not None:
                return cov
        return _sparse_cov(pts, _ring_matrix(graph, rings))
    import numba

    from mks_sim.lowlevel._regions_kernels import ring_moments

    sym = symmetric_adjacency(graph)
    c = np.ascontiguousarray(pts - column_mean(pts), dtype=np.float64)
    out: FloatArray = ring_moments(
        sym.indptr.astype(np.int64), sym.indices.astype(np.int64), c, rings,
        numba.get_num_threads(),
    )  # fmt: skip
    return out


def smallest_eigenvalue(
    cov: FloatArray,
) -> tuple[FloatArray, FloatArray, NDArray[np.bool_], FloatArray]:
    """``(lambda_0, q, safe, variation)`` of N symmetric 3x3 matrices given as (N, 6) upper
    triangles: the smallest eigenvalue by the trigonometric solution of the characteristic
    cubic, a third of the trace, where the solution applies (not isotropic), and the
    surface variation ``lambda_0 / trace``.

    From :data:`_COMPILED_MIN_POINTS` rows, when numba imports, one compiled pass
    (:func:`mks_sim.lowlevel._gridknn.smallest_eigenvalues`, the same arithmetic; to the bit
    where numpy's arccos and cos are the C library's); else numpy's
    (:func:`_smallest_eigenvalue_numpy`, the reference)."""
    from mks_sim.lowlevel import _gridknn

    if len(cov) >= _COMPILED_MIN_POINTS and _gridknn.available():
        return _gridknn.smallest_eigenvalues(cov)
    return _smallest_eigenvalue_numpy(cov)


def _smallest_eigenvalue_numpy(
    cov: FloatArray,
) -> tuple[FloatArray, FloatArray, NDArray[np.bool_], FloatArray]:
    """:func:`smallest_eigenvalue` by numpy's array arithmetic."""
    a00, a01, a02, a11, a12, a22 = cov.T
    q = (a00 + a11 + a22) / 3.0
    p1 = a01**2 + a02**2 + a12**2
    b00, b11, b22 = a00 - q, a11 - q, a22 - q
    p = np.sqrt((b00**2 + b11**2 + b22**2 + 2.0 * p1) / 6.0)
    safe = p > 1e-300
    ps = np.where(safe, p, 1.0)
    det = (
        b00 * (b11 * b22 - a12 * a12)
        - a01 * (a01 * b22 - a12 * a02)
        + a02 * (a01 * a12 - b11 * a02)
    ) / ps**3
    phi = np.arccos(np.clip(det / 2.0, -1.0, 1.0)) / 3.0
    lam0 = np.where(safe, q + 2.0 * p * np.cos(phi + 2.0 * np.pi / 3.0), q)
    total = 3.0 * q
    curvature = np.divide(np.clip(lam0, 0.0, None), total, out=np.zeros(len(cov)), where=total > 0)
    return lam0, q, safe, curvature


def _smallest_eigen(cov: FloatArray) -> tuple[FloatArray, FloatArray]:
    """Closed-form eigen-analysis of N symmetric 3x3 matrices given as (N, 6) upper
    triangles: the unit eigenvector of the smallest eigenvalue and ``lambda_0 / trace``.

    Eigenvalues by :func:`smallest_eigenvalue`; the eigenvector as the largest cross
    product of two rows of ``C - lambda_0 I``. Isotropic or degenerate neighbourhoods fall
    back to ``numpy.linalg.eigh``.
    """
    from mks_sim.lowlevel import _gridknn

    lam0, q, safe, curvature = smallest_eigenvalue(cov)
    if len(cov) >= _COMPILED_MIN_POINTS and _gridknn.available():
        # the same arithmetic in one compiled pass (4,300 rows 0.8 -> 0.06 ms)
        normals, bad = _gridknn.smallest_vectors(cov, lam0, q, safe)
    else:
        a00, a01, a02, a11, a12, a22 = cov.T
        r0 = np.stack([a00 - lam0, a01, a02], axis=1)
        r1 = np.stack([a01, a11 - lam0, a12], axis=1)
        r2 = np.stack([a02, a12, a22 - lam0], axis=1)
        cands = np.stack([np.cross(r0, r1), np.cross(r0, r2), np.cross(r1, r2)], axis=1)
        norms = np.linalg.norm(cands, axis=2)  # (N, 3)
        best = np.argmax(norms, axis=1)
        rows = np.arange(len(cov))
        vec = cands[rows, best]
        nb = norms[rows, best]
        scale = np.maximum(np.abs(lam0), np.abs(q)) ** 2
        bad = ~safe | (nb <= 1e-10 * np.maximum(scale, 1e-300))
        normals = vec / np.where(bad, 1.0, nb)[:, None]
    if bad.any():
        full = np.empty((int(bad.sum()), 3, 3))
        iu = [(0, 0), (0, 1), (0, 2), (1, 1), (1, 2), (2, 2)]
        for k, (i, j) in enumerate(iu):
            full[:, i, j] = cov[bad, k]
            full[:, j, i] = cov[bad, k]
        _, evecs = np.linalg.eigh(full)
        normals[bad] = evecs[:, :, 0]
    return normals, curvature


def estimate_normals(
    points: ArrayLike,
    graph: GraphLike | None = None,
    *,
    m: int = 12,
    viewpoint: ArrayLike | None = None,
    curvature_rings: int = 2,
    normal_rings: int = 1,
) -> SurfaceNormals:
    """Normals and surface variation by PCA over each point's SPG neighbourhood.

    Args:
        points: (N, 3) float surface points (any length unit).
        graph: the points' SPG (``SpatialProximityGraph`` or anything with ``.adjacency``);
            built with ``m`` nearest neighbours when None.
        m: neighbours per point when the graph is built here.
        viewpoint: (3,) sensor position; normals are flipped to face it. When None they face
            away from the centroid of ``points`` (right for one convex object).
        curvature_rings: SPG rings of the neighbourhood whose variation is the curvature
            (normals always use ring 1). Two rings (~4x the points of one) make the
            curvature of a sphere stand well above sensor noise on a plane, which a one-ring
            neighbourhood does not (variation grows as r^2 on a sphere and falls as 1/r^2
            for noise on a plane, r the neighbourhood radius).
        normal_rings: SPG rings of the normals' neighbourhood (2 for noisy clouds).

    Returns:
        :class:`SurfaceNormals`.
    """
    pts = as_points(points, "estimate_normals: points", min_points=3)
    graph = FixedGraph.of(graph if graph is not None else SpatialProximityGraph(pts, m=m))
    normals, curvature = _ring_pca(pts, graph, normal_rings)
    if curvature_rings != normal_rings:  # the variation alone: no eigenvectors
        curvature = smallest_eigenvalue(_ring_cov(pts, graph, curvature_rings))[3]
    if viewpoint is not None:
        vp = np.asarray(viewpoint, dtype=np.float64).reshape(3)
        toward = vp[None, :] - pts
    else:
        toward = pts - column_mean(pts)
    flip = np.einsum("ni,ni->n", normals, toward) < 0
    normals[flip] *= -1.0
    return SurfaceNormals(normals=normals, curvature=curvature)


def curvature_code(
    curvature: ArrayLike, threshold: float = DEFAULT_CURVATURE_THRESHOLD
) -> NDArray[np.int8]:
    """The Surface_Curvature code of Table 4-5: +1 curved, -1 planar.

    Args:
        curvature: (N,) surface variation from :func:`estimate_normals`.
        threshold: variation above which a point is curved (see
            :data:`DEFAULT_CURVATURE_THRESHOLD`).

    Returns:
        (N,) int8 array of +1 / -1.
    """
    c = np.asarray(curvature, dtype=np.float64)
    return np.where(c > threshold, 1, -1).astype(np.int8)
