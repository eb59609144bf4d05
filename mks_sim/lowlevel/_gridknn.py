"""Exact m-nearest-neighbour rows on a uniform grid, compiled with numba (the SPG's fast path).

The SPG of a large 3-D point set is dominated by its tree queries (cKDTree, 1e6 points: about
1-2 s on 2 cores). For Euclidean points of dimension <= 3 a uniform grid of cells answers the
same question with far less work: points are sorted by cell, and each cell gathers the points
of the (2R+1)^3 block of cells around it once for all its own points.

Exactness. A row is accepted only when it is provably the exact answer of the SPG definition
(:mod:`mks_sim.lowlevel.spg`): every point that is not in the block is at distance >= the
distance from the query to the block's boundary (``covered``), so if the m-th best candidate
(or the threshold) is strictly closer than ``covered`` minus a rounding margin, no point outside
can enter the row. Candidates are ranked by (distance, index) with the distance computed with
the same arithmetic as :meth:`Metric.distance` (``sqrt((dx*dx + dy*dy) + dz*dz)`` on scaled
coordinates), so ties are broken by index exactly as the brute force does. Rows that cannot be
proven (outliers far from everything, a cell so crowded that the block is too expensive) are
returned as not done; the caller answers them with the k-d tree.

The cell size is chosen so that an occupied cell holds about 0.43 (m + 1) points: that makes
the cell about 1.2x the typical m-th neighbour distance both for volumes (3-D) and for surfaces
(2-D manifolds such as range scans), so nearly every row is proven with the 3x3x3 block.

numba is imported lazily (only when this path runs); :func:`available` says whether it can.
"""

from __future__ import annotations

import logging
import math
import threading
from typing import Any

import numpy as np
from numpy.typing import NDArray

__all__ = [
    "available",
    "ball_rows",
    "brute_knn",
    "column_bounds",
    "column_mean",
    "grid_knn",
    "induced_rows",
    "median",
    "neighbour_scatter",
    "norm_within",
    "plane_counts",
    "plane_pairs",
    "probe_knn",
    "ring1_cov",
    "row_norms",
    "smallest_vectors",
    "sort_order",
    "space_any",
    "voxel_means",
    "weak_components",
]

log = logging.getLogger(__name__)
_lock = threading.Lock()
#: Why the compiled kernels cannot be defined in this process (None: not known to fail).
_unavailable: str | None = None
_kernels: dict[str, Any] = {}
# Blocks with more candidates than this are left to the tree (a crowded cell would make the
# all-pairs work of the block quadratic).
_MAX_BLOCK = 4096
# Cells per parallel task of the grid's kNN (about four tasks a thread within these).
_KNN_CHUNK_MIN = 32
_KNN_CHUNK_MAX = 256
# Target points per occupied cell, times (m + 1).
_PPC = 0.43
_RINGS = (1, 2)
# probe_knn: cells of 1 / _PROBE_CELL the side of a square of the box holding k points;
# rings tried before a row is left to the tree.
_PROBE_CELL = 2.0
_PROBE_RINGS = 4


def column_bounds(a: NDArray[Any]) -> tuple[NDArray[Any], NDArray[Any]]:
    """(lo, hi): ``a.min(axis=0)`` and ``a.max(axis=0)`` of a non-empty 2-D array, column by
    column (numpy's axis-0 reduction of an (N, 3) array walks the rows with a 3-wide inner
    loop, ~20x slower than three contiguous-strided passes; the same values). A finite
    C-ordered (N, 3) float64 array of 16 rows or more: one compiled pass over the rows
    (a 43,200-point scan: 0.20 -> 0.05 ms), the same values."""
    if (
        a.ndim == 2
        and a.shape[1] == 3
        and len(a) >= _COLUMN_MIN_ROWS
        and a.dtype == np.float64
        and a.flags.c_contiguous
        and available()
    ):
        lo, hi, total = _load()["column_extrema3"](a)
        if math.isfinite(total):  # (else a NaN or inf: numpy's rules for those)
            return lo, hi
    cols = range(a.shape[1])
    return np.array([a[:, d].min() for d in cols]), np.array([a[:, d].max() for d in cols])


def available() -> bool:
    """True when numba can be imported and can cache machine code here (the compiled paths
    of the low level are then usable).

    The kernels are ``cache=True``: numba keeps their machine code in the package's
    ``__pycache__`` or, when that is read-only (an installed package), in the user's cache
    folder (``NUMBA_CACHE_DIR`` overrides both). Where neither can be written numba refuses
    to define a caching kernel (RuntimeError at import): the numpy paths run instead.
    """
    global _unavailable
    if _unavailable is not None:
        return False
    try:
        _load()
    except ImportError:
        return False
    except RuntimeError as exc:  # numba: "cannot cache function ...: no locator available"
        _unavailable = str(exc)
        log.warning("compiled kernels unavailable, numpy paths run: %s", exc)
        return False
    return True


def _load() -> dict[str, Any]:
    with _lock:
        if not _kernels:
            _kernels.update(_compile())
        return _kernels


def _compile() -> dict[str, Any]:
    from mks_sim.lowlevel import _gridknn_kernels as k

    return {
        "cell_keys": k.cell_keys,
        "counting_order": k.counting_order,
        "buckets": k.buckets,
        "gather_columns": k.gather_columns,
        "sort_rows": k.sort_rows,
        "count_occupied": k.count_occupied,
        "knn": k.knn_cells,
        "column_keys": k.column_keys,
        "probe_rows": k.probe_rows,
        "brute_knn": k.brute_knn,
        "radix_order": k.radix_order,
        "column_sums": k.column_sums,
        "column_extrema3": k.column_extrema3,
        "induced_rows": k.induced_rows,
        "ball_rows": k.ball_rows,
        "plane_pairs": k.plane_pairs,
        "plane_counts": k.plane_counts,
        "neighbour_scatter": k.neighbour_scatter,
        "smallest_eigenvalues": k.smallest_eigenvalues,
        "ring1_cov": k.ring1_cov,
        "order_statistics": k.order_statistics,
        "space_any": k.space_any,
        "smallest_vectors": k.smallest_vectors,
        "voxel_means": k.voxel_means,
        "face_support": k.face_support,
        "plane_band": k.plane_band,
        "footprint_inside": k.footprint_inside,
        "weak_components": k.weak_components,
        "masked_components": k.masked_components,
        "same_label_entries": k.same_label_entries,
    }


def _dims(ext: NDArray[np.float64], h: float) -> NDArray[np.int64]:
    return (np.floor(ext / h) + 1).astype(np.int64)


def _cell_size(
    pts: NDArray[np.float64], lo: NDArray[np.float64], ext: NDArray[np.float64], m: int
) -> float:
    """Cell size with about ``_PPC * (m + 1)`` points per occupied cell (secant on log h)."""
    k = _load()
    n = len(pts)
    target = _PPC * (m + 1)
    live = ext[ext > 0]
    # Start as if the points filled their bounding box (of its non-flat axes).
    h = float(np.prod(live) * target / n) ** (1.0 / len(live))
    h = max(h, float(ext.max()) / 2**20)
    prev: tuple[float, float] | None = None
    for _ in range(4):
        ppc = n / k["count_occupied"](pts, lo, h, _dims(ext, h))
        if abs(math.log(ppc / target)) < math.log(1.3):
            break
        dim = 3.0
        if prev is not None and prev[0] != h and prev[1] != ppc:
            dim = min(3.0, max(1.0, math.log(ppc / prev[1]) / math.log(h / prev[0])))
        prev = (h, ppc)
        h = h * (target / ppc) ** (1.0 / dim)
        h = max(h, float(ext.max()) / 2**20)
    return h


def grid_knn(
    points: NDArray[np.float64],
    m: int,
    threshold: float | None,
    workers: int = -1,
    rows: NDArray[np.bool_] | None = None,
) -> tuple[NDArray[np.int64], NDArray[np.float64], NDArray[np.int64], NDArray[np.bool_]]:
    """Exact SPG rows of (N, k <= 3) Euclidean points, where the grid can prove them.

    Args:
        points: (N, k) float64, k <= 3, already scaled by the metric's coordinate scale.
        m: neighbours per row.
        threshold: keep neighbours at distance <= threshold; None: no limit.
        workers: threads (-1: all cores).
        rows: (N,) the rows to answer (None: all); the others are left not done.

    Returns:
        (nbr (N, m), dist (N, m), lens (N,), done (N,)): row i's first ``lens[i]`` entries,
        nearest first, ties by index, for every row with ``done[i]``; other rows are garbage.
    """
    import numba

    kern = _load()
    n, kdim = points.shape
    if kdim == 3:
        pts = np.ascontiguousarray(points, dtype=np.float64)
    else:  # pad with zero coordinates: the distances are unchanged, bit for bit
        pts = np.zeros((n, 3))
        pts[:, :kdim] = points
    nbr = np.empty((n, m), np.int64)  # rows not done are left as garbage (see Returns)
    dist = np.empty((n, m))
    lens = np.zeros(n, np.int64)
    done = np.zeros(n, bool)
    if n < 2:
        return nbr, dist, lens, done
    lo, hi = column_bounds(pts)
    ext = hi - lo
    if not np.any(ext > 0):
        return nbr, dist, lens, done
    h = _cell_size(pts, lo, ext, m)
    dims = _dims(ext, h)
    key = kern["cell_keys"](pts, lo, h, dims)
    ncells = int(dims[0] * dims[1] * dims[2])
    # (any order grouping the cells does: each row's answer does not depend on it)
    order = kern["counting_order"](key, ncells) if ncells <= 2 * n else sort_order(key)
    skey = key[order]
    first = np.flatnonzero(np.r_[True, skey[1:] != skey[:-1]])
    ckey = skey[first]
    cstart = np.append(first, n).astype(np.int64)
    ccoord = np.stack(
        [ckey // (dims[1] * dims[2]), (ckey // dims[2]) % dims[1], ckey % dims[2]], axis=1
    )
    if dims[0] * dims[1] <= 4 * n + 100_000:  # (x, y) column -> its first cell
        colptr = np.searchsorted(ckey // dims[2], np.arange(int(dims[0] * dims[1]) + 1))
        colptr = colptr.astype(np.int64)
    else:  # too many columns for a table (far outliers): binary search over all cells
        colptr = np.zeros(0, np.int64)
    sx, sy, sz = kern["gather_columns"](pts, order)
    sidx = order.astype(np.int64)
    thr = math.inf if threshold is None else float(threshold)
    scale = float(np.abs(pts).max())
    margin = 1e-9 * h + 1e-12 * scale
    most = int(numba.config.NUMBA_NUM_THREADS)  # type: ignore[attr-defined]
    threads = most if workers == -1 else max(1, min(workers, most))
    old = numba.get_num_threads()
    numba.set_num_threads(threads)
    try:
        todo = np.ones(n, bool) if rows is None else rows[sidx]
        # about four tasks a thread, of 32-256 cells: an object's 400 cells in 2 tasks of
        # 256 and 144 kept a thread idle (2,550 points: 2.97 -> 2.52 ms, interleaved)
        chunk = min(_KNN_CHUNK_MAX, max(_KNN_CHUNK_MIN, -(-len(ckey) // (4 * threads))))
        for ring in _RINGS:
            kern["knn"](
                sx, sy, sz, sidx, ccoord, ckey, cstart, colptr, todo, lo, h, dims, m, thr, ring, margin,
                _MAX_BLOCK, nbr, dist, lens, done, chunk,
            )  # fmt: skip
            todo = ~done[sidx] if rows is None else ~done[sidx] & todo
            if not todo.any():
                break
    finally:
        numba.set_num_threads(old)
    return nbr, dist, lens, done


def induced_rows(
    adj: Any, members: NDArray[np.intp], points: NDArray[np.float64], m: int
) -> tuple[bool, NDArray[np.int64], NDArray[Any], NDArray[np.float64]]:
    """The CSR arrays (ok, indptr, indices, data) of the SPG of one component of a
    thresholded SPG ``adj`` (sorted ``members``, their ``points``): rows of ``m`` entries
    renumbered, shorter rows (the threshold cut them) the member's ``m`` nearest among the
    points by brute force, each row in column order
    (:func:`~mks_sim.lowlevel._gridknn_kernels.induced_rows`); ok is False when a cut row
    meets a distance tie at its m-th neighbour (the grid gives such a row up too). Needs
    :func:`available`."""
    out: tuple[bool, NDArray[np.int64], NDArray[Any], NDArray[np.float64]] = _load()[
        "induced_rows"
    ](
        adj.indptr, adj.indices, adj.data, np.ascontiguousarray(members, dtype=np.int64),
        np.ascontiguousarray(points, dtype=np.float64), int(m),
    )  # fmt: skip
    return out


def probe_knn(
    points: NDArray[np.float64], rows: NDArray[np.intp], k: int
) -> tuple[NDArray[np.float64], NDArray[np.int64], NDArray[np.bool_]]:
    """The ``k`` nearest points of a few rows of (N, 3) points, as ``cKDTree(points).query(
    points[rows], k)`` answers them (the row itself first), without a tree.

    A statistic over a few hundred probes of a scan needs their neighbours only: the points
    are sorted into columns of an (x, y) grid (about ``k / 4`` points a column over the
    bounding box) and each probe ranks the points of the columns around its own, widening
    the block until no point outside it can be nearer than its k-th (the 23,700-point scan's
    800 probes in 1.2 ms, less than the tree's build alone). Rows not proven within a few
    rings (a probe far from the rest) are returned as not done: the caller asks a tree.

    Returns:
        (dist (P, k), idx (P, k), done (P,)): rows with ``done`` nearest first, ties by
        index; other rows are garbage.
    """
    kern = _load()
    pts = np.ascontiguousarray(points, dtype=np.float64)
    rows = np.ascontiguousarray(rows, dtype=np.int64)
    n = len(pts)
    out_d = np.empty((len(rows), k))
    out_i = np.empty((len(rows), k), np.int64)
    done = np.zeros(len(rows), bool)
    if n < k or k < 1 or len(rows) == 0:
        return out_d, out_i, done
    lo, hi = column_bounds(pts)
    ext = hi - lo
    span = max(float(ext[0]), float(ext[1]))
    if not span > 0:
        return out_d, out_i, done
    area = max(float(ext[0]), span / 1e3) * max(float(ext[1]), span / 1e3)
    # about k / 4 points a column over the box: the 3 x 3 block around a probe then
    # mostly holds its k nearest in a scan that fills the box (the scan's 800 probes: 1.2 ms,
    # against 1.9 with k points a column)
    h = math.sqrt(area * k / n) / _PROBE_CELL
    h = max(h, span / math.sqrt(4.0 * n))  # at most ~4 N columns
    nx = int(ext[0] // h) + 1
    ny = int(ext[1] // h) + 1
    key = kern["column_keys"](pts, lo, h, nx, ny)
    start, order = kern["buckets"](key, nx * ny)
    sx, sy, sz = kern["gather_columns"](pts, order)
    margin = 1e-9 * h + 1e-12 * float(max(np.abs(lo).max(), np.abs(lo + ext).max()))
    kern["probe_rows"](
        pts, sx, sy, sz, rows, k, lo, h, nx, ny, start, order, margin, _PROBE_RINGS, _MAX_BLOCK,
        out_d, out_i, done,
    )  # fmt: skip
    return out_d, out_i, done


def brute_knn(
    points: NDArray[np.float64], rows: NDArray[np.intp], k: int
) -> tuple[NDArray[np.float64], NDArray[np.int64]]:
    """(dist (P, k), idx (P, k)): the ``k`` nearest points of a few rows of (N >= k, 3)
    points (the row itself included), nearest first, ties by index, by one pass over all
    the points a row: what :func:`probe_knn` leaves not done (a far outlier), without a
    k-d tree of all the points (a 307,200-point scan: the tree 50 ms, a pass 1.2 ms).
    Needs :func:`available`."""
    out: tuple[NDArray[np.float64], NDArray[np.int64]] = _load()["brute_knn"](
        np.ascontiguousarray(points, dtype=np.float64),
        np.ascontiguousarray(rows, dtype=np.int64),
        int(k),
    )
    return out


#: Rows from which :func:`column_mean` adds them in the compiled loop (numpy's mean costs
#: several microseconds of checks even on a few rows: 300 rows 11.7 -> 3.7 us).
_COLUMN_MIN_ROWS = 16


def column_mean(a: NDArray[np.float64]) -> NDArray[np.float64]:
    """``a.mean(axis=0)`` of a C-ordered (N, 2 <= k <= 8) float64 array, to the bit: numpy
    adds such rows in order, and so does the compiled loop, 4x faster on a 13,000-point
    table (numpy's axis-0 reduction walks the rows with a k-wide inner loop; one column is
    a contiguous run that numpy adds pairwise, and is left to numpy)."""
    if (
        a.ndim == 2
        and 2 <= a.shape[1] <= 8
        and len(a) >= _COLUMN_MIN_ROWS
        and a.dtype == np.float64
        and a.flags.c_contiguous
        and available()
    ):
        out: NDArray[np.float64] = _load()["column_sums"](a) / len(a)
        return out
    return np.asarray(a.mean(axis=0), dtype=np.float64)


def sort_order(keys: NDArray[np.int64]) -> NDArray[np.int64]:
    """A stable order sorting 1-D non-negative int64 keys (``np.argsort(keys,
    kind="stable")``) by a compiled radix sort: the 23,700 voxel keys of the workstation's
    scan in 0.1 ms against 0.9 for numpy's (unstable) argsort."""
    top = int(keys.max()) if len(keys) else 0
    keys = np.ascontiguousarray(keys, np.int64)
    order: NDArray[np.int64] = _load()["radix_order"](keys, max(top.bit_length(), 1))
    return order


def sort_rows(
    indptr: NDArray[np.intp], cols: NDArray[np.intp], data: NDArray[np.float64]
) -> tuple[NDArray[np.intp], NDArray[np.float64]]:
    """Copies of CSR (cols, data) with each row sorted by column (compiled; short rows)."""
    return _load()["sort_rows"](indptr, cols, data)  # type: ignore[no-any-return]


def ball_rows(
    points: NDArray[np.float64], centre: NDArray[np.float64], r: float
) -> NDArray[np.intp]:
    """Ascending indices of the rows of (N, 3) ``points`` within ``r`` of ``centre`` by the
    k-d tree's rule (``cKDTree.query_ball_point``: the squared distance, summed over x, y,
    z in that order, <= r * r): one compiled pass, 17,600 points in about 20 us, where
    the tree's build alone takes 1.5 ms (half of it numpy's axis-0 min and max)."""
    pts = np.ascontiguousarray(points, dtype=np.float64)
    c = np.asarray(centre, dtype=np.float64).reshape(3)
    rr = float(r) * float(r)
    if available():
        out: NDArray[np.intp] = _load()["ball_rows"](pts, c[0], c[1], c[2], rr, False).astype(
            np.intp
        )
        return out
    d = pts - c
    return np.flatnonzero(d[:, 0] * d[:, 0] + d[:, 1] * d[:, 1] + d[:, 2] * d[:, 2] <= rr)


def plane_pairs(
    points: NDArray[np.float64],
    queries: NDArray[np.float64],
    r: float,
    *,
    strict: bool = False,
    first_only: bool = False,
) -> tuple[NDArray[np.intp], NDArray[np.intp]]:
    """(lens, flat): for each 2-D query, the indices of the 2-D ``points`` within ``r``,
    grouped by query in query order (ascending within one), by the k-d tree's rule: squared
    distance (x then y) <= r * r (``sparse_distance_matrix``, ``query_ball_point``), or
    < r * r when ``strict`` (``query``'s ``distance_upper_bound``); ``first_only``: at most
    one per query (whether there is one). A grid of cells just over ``r`` (at most about
    4 per point: wider when ``r`` is small for the points' extent) built and queried in one
    compiled call. Needs :func:`available`."""
    pts = np.ascontiguousarray(points, dtype=np.float64)[:, :2]
    qs = np.ascontiguousarray(queries, dtype=np.float64)[:, :2]
    if len(pts) == 0 or len(qs) == 0:
        return np.zeros(len(qs), dtype=np.intp), np.zeros(0, dtype=np.intp)
    lo, hi = column_bounds(pts)
    ext = hi - lo
    # just over r: a match of a query is then always in the 3 x 3 cells around its own
    # (a rounding of the cell coordinates cannot put it two cells away)
    h = max(float(r) * (1.0 + 1e-9), 1e-300)
    cells = 4.0 * len(pts) + 16.0
    h = max(h, float(np.sqrt(ext[0] * ext[1] / cells)), float(ext.max()) / cells)
    nx, ny = (int(e / h) + 1 for e in ext)
    lens, flat = _load()["plane_pairs"](
        np.ascontiguousarray(pts), np.ascontiguousarray(qs), float(r) * float(r), lo, h,
        nx, ny, strict, first_only,
    )  # fmt: skip
    return lens.astype(np.intp), flat.astype(np.intp)


def plane_counts(
    normals: NDArray[np.float64], offsets: NDArray[np.float64], points: NDArray[np.float64],
    threshold: float,
) -> NDArray[np.intp]:
    """(K,) how many of the (N, 3) ``points`` lie within ``threshold`` of each of K planes
    (unit ``normals``, ``offsets``): a RANSAC's inlier counts, one compiled pass per plane
    with no (K, N) distance matrix (100 planes and 4,000 points in about 0.2 ms against
    0.8 by products). The distances are rounded as the products round them but for the
    order of the three terms: a count can differ only for a point within a few units in
    the last place of the threshold. Needs :func:`available`."""
    out: NDArray[np.intp] = _load()["plane_counts"](
        np.ascontiguousarray(normals, dtype=np.float64),
        np.ascontiguousarray(offsets, dtype=np.float64),
        np.ascontiguousarray(points, dtype=np.float64),
        float(threshold),
    ).astype(np.intp)
    return out


def neighbour_scatter(points: NDArray[np.float64], idx: NDArray[np.intp]) -> NDArray[np.float64]:
    """(P, 6) scatter sums (xx xy xz yy yz zz) of the neighbours ``points[idx[p]]`` of each
    of P rows about their mean: ``c = nb - nb.mean(axis=1, keepdims=True)`` for ``nb =
    points[idx]`` and the six ``(c_a * c_b).sum(axis=1)``, to the bit (numpy's order of
    additions, kept in the compiled loop), without the (P, k, 3) temporaries: 800 rows of
    12 in 0.1 ms against 0.5. Needs :func:`available`."""
    out: NDArray[np.float64] = _load()["neighbour_scatter"](
        np.ascontiguousarray(points, dtype=np.float64), np.ascontiguousarray(idx, dtype=np.int64)
    )
    return out


def ring1_cov(adjacency: Any, c: NDArray[np.float64]) -> NDArray[np.float64] | None:
    """(N, 6) covariances of every point with its row of a CSR ``adjacency``, as
    :func:`mks_sim.lowlevel.normals._sparse_cov` computes them from sparse products with
    the pattern of ``A + I`` (the same values, in one compiled pass, without the ring
    matrix: 4,300 points in 0.1 ms against 0.7); None when a row is not strictly ascending
    or holds its own point (then the sparse products apply). Needs :func:`available`."""
    out, ok = _load()["ring1_cov"](
        adjacency.indptr.astype(np.int64), adjacency.indices.astype(np.int64),
        np.ascontiguousarray(c, dtype=np.float64),
    )  # fmt: skip
    return out if ok else None


def row_norms(a: NDArray[np.float64]) -> NDArray[np.float64]:
    """``np.linalg.norm(a, axis=1)`` of an (N, 3) float64 array, to the bit (numpy adds the
    three squares in order), without its dispatch: 700 rows in 5 us against 15."""
    if a.ndim != 2 or a.shape[1] != 3:
        return np.asarray(np.linalg.norm(a, axis=1), dtype=np.float64)
    x, y, z = a[:, 0], a[:, 1], a[:, 2]
    out: NDArray[np.float64] = np.sqrt(x * x + y * y + z * z)
    return out


#: Values from which :func:`median` selects in the compiled loop.
_MEDIAN_MIN = 20000


def median(x: NDArray[np.float64]) -> float:
    """``np.median`` of a 1-D float64 array with no NaN: by one partition (numpy's checks and
    copies cost several times it), or for large arrays by a compiled bin count and a sort of
    the one or two bins holding the middle ranks (the SPG's 52,000 edge lengths, full of
    ties from the voxel grid, in 0.1 ms against 0.6 for the partition; the partition when
    those bins hold over a quarter of the values). The order statistics are exact either
    way; an even count averages the two middle values as numpy does."""
    n = len(x)
    k = n // 2
    if n == 0:
        return math.nan  # (np.median's answer, without its warning)
    if n >= _MEDIAN_MIN and available() and x.dtype == np.float64:
        kern = _load()["order_statistics"]
        lo_v, hi_v, ok = kern(np.ascontiguousarray(x), k - (1 - n % 2), k, 4096)
        if ok:
            return float(hi_v) if n % 2 else float((lo_v + hi_v) / 2.0)
    if n % 2:
        # (two ranks: numpy's selection of one rank is 3-4x slower at 1,000-13,000 values)
        return float(np.partition(x, [k - 1, k] if k else k)[k])
    part = np.partition(x, [k - 1, k])
    return float((part[k - 1] + part[k]) / 2.0)


def space_any(
    points: NDArray[np.float64], queries: NDArray[np.float64], r: float
) -> NDArray[np.bool_]:
    """(Q,) whether some of the (N, 3) ``points`` lies strictly within ``r`` of each query,
    by the k-d tree's rule (``np.isfinite(cKDTree(points).query(queries,
    distance_upper_bound=r)[0])``): a grid of cells just over ``r`` (at most about 4 per
    point) built and queried in one compiled call. Needs :func:`available`."""
    pts = np.ascontiguousarray(points, dtype=np.float64)
    qs = np.ascontiguousarray(queries, dtype=np.float64)
    if len(pts) == 0 or len(qs) == 0:
        return np.zeros(len(qs), dtype=bool)
    lo, hi = column_bounds(pts)
    ext = hi - lo
    cells = 4.0 * len(pts) + 64.0
    h = max(float(r) * (1.0 + 1e-9), 1e-300, float(np.prod(np.maximum(ext, 1e-300))) ** (1 / 3)
            / cells ** (1 / 3), float(ext.max()) / cells)  # fmt: skip
    nx, ny, nz = (int(e / h) + 1 for e in ext)
    while nx * ny * nz > 8 * cells:  # (flat boxes: the volume bound alone allows many)
        h *= 2.0
        nx, ny, nz = (int(e / h) + 1 for e in ext)
    out: NDArray[np.bool_] = _load()["space_any"](pts, qs, float(r) * float(r), lo, h, nx, ny, nz)
    return out


def smallest_eigenvalues(
    cov: NDArray[np.float64],
) -> tuple[NDArray[np.float64], NDArray[np.float64], NDArray[np.bool_], NDArray[np.float64]]:
    """``(lambda_0, q, safe, variation)`` of N symmetric 3x3 matrices given as (N, 6) upper
    triangles, as :func:`mks_sim.lowlevel.normals.smallest_eigenvalue` computes them with
    numpy (to the bit where numpy's float64 arccos and cos are the C library's, as without
    AVX-512; its SVML loops there differ by a few ulps), in one compiled pass over the rows
    on the threads, without its dozen (N,) temporaries (2,500 rows: 0.35 -> 0.15 ms; the
    arccos and cosine are most of it). Needs :func:`available`."""
    out: tuple[NDArray[np.float64], NDArray[np.float64], NDArray[np.bool_], NDArray[np.float64]]
    out = _load()["smallest_eigenvalues"](np.ascontiguousarray(cov, dtype=np.float64))
    return out


def smallest_vectors(
    cov: NDArray[np.float64],
    lam0: NDArray[np.float64],
    q: NDArray[np.float64],
    safe: NDArray[np.bool_],
) -> tuple[NDArray[np.float64], NDArray[np.bool_]]:
    """(normals (N, 3), degenerate (N,)): the eigenvectors of the smallest eigenvalues of N
    symmetric 3x3 matrices, as :func:`mks_sim.lowlevel.normals._smallest_eigen` computes
    them with numpy (its cross products, norms, first largest and division, to the bit), in
    one compiled pass; the degenerate rows are the caller's (eigh). Needs :func:`available`."""
    out, bad = _load()["smallest_vectors"](
        np.ascontiguousarray(cov, dtype=np.float64), np.ascontiguousarray(lam0, dtype=np.float64),
        np.ascontiguousarray(q, dtype=np.float64), np.ascontiguousarray(safe, dtype=np.bool_),
    )  # fmt: skip
    return out, bad


def norm_within(
    points: NDArray[np.float64], centre: NDArray[np.float64], r: float
) -> NDArray[np.intp]:
    """Ascending indices of the (N, 3) ``points`` with ``np.linalg.norm(points - centre,
    axis=1) <= r``, the same rows (the norm's arithmetic, to the bit) in one compiled pass
    without the (N, 3) and (N,) temporaries (a 640 x 480 scan: 0.5 ms against 5)."""
    c = np.asarray(centre, dtype=np.float64).reshape(3)
    if points.ndim != 2 or points.shape[1] != 3 or not available():
        return np.flatnonzero(row_norms(points - c) <= r)
    pts = np.ascontiguousarray(points, dtype=np.float64)
    out: NDArray[np.intp] = _load()["ball_rows"](pts, c[0], c[1], c[2], float(r), True).astype(
        np.intp
    )
    return out


def voxel_means(
    points: NDArray[np.float64], voxel: float, shift: float = 0.0
) -> NDArray[np.float64] | None:
    """(M, 3) centroids of the (N, 3) finite ``points`` in each occupied cube of edge
    ``voxel`` (cells ``floor(p / voxel + shift)``), cells in lexicographic order, to the bit as
    :func:`mks_sim.localization.representation.voxel_average` computes them with numpy, in
    one compiled call; None when the cells span too much for one int64 key (numpy's rows
    then). Needs :func:`available`. The kernel sorts runs of consecutive points in one cell
    rather than the points, then adds the points in their order into the cells' sums
    (caches flushed first: a 640 x 480 scan, 307,200 points in 95,900 runs on 1.9 mm cells,
    23.6 -> 6.8 ms against a sort of the points; 320 x 240: 4.3 -> 4.0 ms; 240 x 180,
    about 1.3 points a run: 2.0 -> 1.9 ms)."""
    pts = np.ascontiguousarray(points, dtype=np.float64)
    out, ok = _load()["voxel_means"](pts, float(voxel), float(shift))
    return out if ok else None


def weak_components(adjacency: Any) -> tuple[int, NDArray[Any]]:
    """``scipy.sparse.csgraph.connected_components(adjacency, directed=True,
    connection="weak")``: the same count and labels (numbered in the order of each
    component's first node), by one compiled union-find over the CSR pattern when numba
    imports (an object's 1,853-point SPG: 0.26 -> 0.12 ms warm; scipy validates and
    transposes the graph first); explicit zeros are edges, as for scipy.

    Raises:
        DataError: a graph that is not square.
    """
    from scipy import sparse

    from mks_sim.errors import DataError

    is_csr = sparse.issparse(adjacency) and adjacency.format == "csr"
    csr = adjacency if is_csr else sparse.csr_array(adjacency)
    n = csr.shape[0]
    if csr.shape[1] != n:
        raise DataError(f"weak_components: expected a square graph, got shape {csr.shape}")
    if not available():
        from scipy.sparse import csgraph

        count, labels = csgraph.connected_components(csr, directed=True, connection="weak")
        return int(count), labels
    count, labels = _load()["weak_components"](
        np.asarray(csr.indptr, dtype=np.int64), np.asarray(csr.indices, dtype=np.int64), n
    )
    return int(count), labels


def masked_components(
    adjacency: Any, keep: NDArray[np.bool_] | None = None, limit: float = math.inf
) -> tuple[int, NDArray[np.intp]]:
    """(count, (n,) labels, -1 off ``keep``) of the weakly connected components of the
    nodes in ``keep`` (None: all) of a square CSR graph, over its entries of value <=
    ``limit`` between two such nodes (explicit zeros are edges): :func:`weak_components` of
    that subgraph, its labels in the order of each component's first node. One compiled
    union-find when numba imports (no subgraph built: the representation's labels of the
    workstation's 4,300 object points 0.7-0.9 -> 0.4-0.55 ms), else scipy's over the subgraph."""
    from scipy import sparse

    from mks_sim.errors import DataError

    csr = sparse.csr_array(adjacency)
    n = csr.shape[0]
    if csr.shape[1] != n:
        raise DataError(f"masked_components: expected a square graph, got shape {csr.shape}")
    mask = np.ones(n, dtype=bool) if keep is None else np.asarray(keep, dtype=bool)
    if mask.shape != (n,):
        raise DataError(f"masked_components: expected ({n},) keep, got {mask.shape}")
    if available():
        count, labels = _load()["masked_components"](
            np.asarray(csr.indptr, dtype=np.int64), np.asarray(csr.indices, dtype=np.int64),
            np.asarray(csr.data, dtype=np.float64), mask, float(limit),
        )  # fmt: skip
        return int(count), labels.astype(np.intp, copy=False)
    from scipy.sparse import csgraph

    idx = np.flatnonzero(mask)
    sub = csr[idx][:, idx].tocoo()
    link = sub.data <= limit
    joined = sparse.csr_array(
        (np.ones(int(link.sum())), (sub.row[link], sub.col[link])), shape=(len(idx), len(idx))
    )
    count, comp = csgraph.connected_components(joined, directed=True, connection="weak")
    labels = np.full(n, -1, dtype=np.intp)
    labels[idx] = comp
    return int(count), labels


def same_label_entries(adjacency: Any, labels: NDArray[Any]) -> Any:
    """The CSR graph of the entries of a square CSR ``adjacency`` that join two nodes of one
    label, each row's entries in their order (compiled when numba imports)."""
    from scipy import sparse

    csr = sparse.csr_array(adjacency)
    lab = np.asarray(labels)
    if available():
        ptr, ind, dat = _load()["same_label_entries"](
            np.asarray(csr.indptr, dtype=np.int64), csr.indices, csr.data, lab
        )
        return sparse.csr_array((dat, ind, ptr), shape=csr.shape)
    row = np.repeat(np.arange(csr.shape[0]), np.diff(csr.indptr))
    same = lab[row] == lab[csr.indices]
    indptr = np.zeros(csr.shape[0] + 1, dtype=np.int64)
    np.cumsum(np.bincount(row[same], minlength=csr.shape[0]), out=indptr[1:])
    return sparse.csr_array((csr.data[same], csr.indices[same], indptr), shape=csr.shape)
