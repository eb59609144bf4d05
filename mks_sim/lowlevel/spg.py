"""The spatial proximity graph (SPG) of MKS (paper sections 1.2 and 3).

"The spatial proximity graph simply takes a set of points and creates a graph whose nodes are
the points, and whose edges connect each node to the m nearest neighbors of that node" —
built by "querying the k-d tree with each data point in turn"; "the graph is not necessarily
symmetric". Points may live in any k-dimensional feature space and any :class:`Metric`.

Definition used here (every test checks it by brute force):

* row ``i`` links point ``i`` to its ``m`` nearest *other* points (a duplicate of ``i`` is
  another point, at distance 0), keeping only those at distance ``<= threshold`` (inclusive,
  like ``query_ball_point``) when a threshold is given;
* ``m="all"`` is the paper's "infinite number of neighbors": every other point within the
  threshold (a threshold is then required);
* ties are broken by index: among points at the same distance the lower index wins, and
  :meth:`SpatialProximityGraph.neighbors` lists nearest first, ties by index.

Zero distances: ``adjacency`` is a canonical ``scipy.sparse.csr_array`` whose ``data`` are the
distances, and an edge of distance 0 (duplicated points, which the paper's tables contain) is an
**explicitly stored zero**. It counts in ``nnz`` and in ``indices``/``indptr``; it vanishes if
you call ``eliminate_zeros()`` or ``toarray()``. Use :attr:`SpatialProximityGraph.pattern` (the
same structure with boolean ``True`` data) whenever you need the edges rather than the lengths;
:meth:`components` does.
"""

from __future__ import annotations

import math
from typing import Literal

import numpy as np
from numpy.typing import ArrayLike, NDArray
from scipy import sparse

from mks_sim.errors import DataError, SpecError
from mks_sim.lowlevel.dynamic import DynamicKDTree
from mks_sim.lowlevel.kdtree import KDTree
from mks_sim.lowlevel.metric import Metric, validate_points

__all__ = ["SpatialProximityGraph"]

Neighbours = int | Literal["all"]
Method = Literal["auto", "tree", "grid"]

# Entries (queries x (m + 2)) per chunk of tree queries.
_CHUNK_ENTRIES = 1 << 20
# Updates touching more runs of rows than this use the general (vectorised) splice.
_MAX_RUNS = 4096
# method="auto" uses the compiled grid from this many points on: below it, the tree is fast
# enough and a fresh process would pay numba's import (~0.5 s) for nothing.
_GRID_MIN_POINTS = 250_000
# Rows the grid leaves (x N points) up to which they are answered by brute force, not a tree.
_BRUTE_ENTRIES = 50_000_000
# Distances per block of brute-force rows (bounds the (rows, N) matrix: 32 MB).
_BRUTE_BLOCK = 4_000_000


def _check_params(m: Neighbours, threshold: float | None) -> tuple[Neighbours, float | None]:
    if m != "all" and (isinstance(m, bool) or not isinstance(m, int | np.integer) or m < 1):
        raise SpecError(f"SpatialProximityGraph: expected m = an integer >= 1 or 'all', got {m!r}")
    if threshold is not None:
        t = float(threshold)
        if not (t >= 0) or math.isnan(t):
            raise SpecError(
                f"SpatialProximityGraph: expected threshold >= 0 or None, got {threshold!r}"
            )
        threshold = t
    if m == "all" and (threshold is None or math.isinf(threshold)):
        raise SpecError(
            "SpatialProximityGraph: m='all' (the paper's infinite number of neighbours) needs a "
            f"finite threshold, got threshold={threshold!r}"
        )
    return (m if m == "all" else int(m)), threshold


class SpatialProximityGraph:
    """Directed m-nearest-neighbour graph of points under a metric, with updates.

    Args:
        points: (N, k) float points (finite).
        m: neighbours per point (int >= 1) or ``"all"`` (needs ``threshold``).
        threshold: keep only neighbours at distance <= threshold; None: no limit.
        metric: the distance (default Euclidean); ``Metric.sum_of`` works too.
        leafsize: bucket size of the k-d tree.
        workers: threads for the tree queries (-1: all cores).
        method: how the rows are found. ``"tree"``: queries of the paper's k-d tree
            (:class:`KDTree`, balanced median splits). ``"grid"``: the compiled uniform-grid
            kernel of :mod:`mks_sim.lowlevel._gridknn` (numba; Euclidean or weighted Euclidean
            metrics, points of dimension <= 3, integer m), which proves each row exact and
            leaves the rows it cannot prove to the tree; the tree itself is then built only
            when needed (:attr:`tree`, updates, such rows). Both give the same graph (the
            tests check both against brute force). ``"auto"``: the grid from 250,000 points on
            when it applies and numba imports, else the tree.

    Attributes:
        m, threshold, metric: the parameters.
    """

    def __init__(
        self,
        points: ArrayLike,
        m: Neighbours = 8,
        threshold: float | None = None,
        metric: Metric | None = None,
        leafsize: int = 16,
        workers: int = -1,
        method: Method = "auto",
    ) -> None:
        pts = np.asarray(points, dtype=float)
        if pts.ndim != 2:
            raise DataError(f"SpatialProximityGraph points: expected (N, k), got shape {pts.shape}")
        if pts.size:
            pts = validate_points(pts, "SpatialProximityGraph points")
        if method not in ("auto", "tree", "grid"):
            raise SpecError(
                f"SpatialProximityGraph: expected method 'auto', 'tree' or 'grid', got {method!r}"
            )
        metric = metric if metric is not None else Metric.euclidean()
        if method == "grid" or (method == "auto" and len(pts) >= _GRID_MIN_POINTS):
            m_checked, _ = _check_params(m, threshold)
            why = _grid_unfit(pts, metric, m_checked)  # imports numba: only when worth it
            if method == "grid" and why:
                raise SpecError(f"SpatialProximityGraph: method='grid' needs {why}")
            if not why:
                self._init_grid(pts, m, threshold, metric, leafsize, workers)
                return
        tree = KDTree(pts, leafsize=leafsize, metric=metric)
        self._init(tree, m, threshold, workers)

    @classmethod
    def from_tree(
        cls,
        tree: KDTree | DynamicKDTree,
        m: Neighbours = 8,
        threshold: float | None = None,
        workers: int = -1,
    ) -> SpatialProximityGraph:
        """Build the SPG over the points of an existing tree (its metric is used).

        A :class:`DynamicKDTree` is shared, not copied: the graph's ``insert``/``delete`` update
        it (and its live ids, ascending, are the graph's rows). A static :class:`KDTree` is
        left untouched: the first update copies its points into a new dynamic tree.
        """
        if not isinstance(tree, KDTree | DynamicKDTree):
            raise DataError(
                f"SpatialProximityGraph.from_tree: expected a KDTree or DynamicKDTree, got {type(tree).__name__}"
            )
        self = cls.__new__(cls)
        self._init(tree, m, threshold, workers)
        return self

    def _init(
        self,
        tree: KDTree | DynamicKDTree,
        m: Neighbours,
        threshold: float | None,
        workers: int,
    ) -> None:
        self.m, self.threshold = _check_params(m, threshold)
        self.metric = tree.metric
        self.workers = workers
        self._tree: KDTree | DynamicKDTree | None = tree
        self._grid_built = False
        self._data = tree.data if isinstance(tree, KDTree) else None
        self._leafsize = tree.leafsize
        if isinstance(tree, DynamicKDTree):
            self._ids = tree.ids
        else:
            self._ids = np.arange(tree.n, dtype=np.intp)
        lens, nbr, dist = self._compute_rows(self._ids)
        self._indptr = np.concatenate([[0], np.cumsum(lens)]).astype(np.intp)
        self._nbr = nbr
        self._dist = dist
        self._adj: sparse.csr_array | None = None

    def _init_grid(
        self,
        pts: NDArray[np.float64],
        m: Neighbours,
        threshold: float | None,
        metric: Metric,
        leafsize: int,
        workers: int,
    ) -> None:
        """Rows from the compiled grid; rows it cannot prove come from the (lazy) tree."""
        from mks_sim.lowlevel._gridknn import grid_knn

        self.m, self.threshold = _check_params(m, threshold)
        self.metric = metric
        self.workers = workers
        if not (isinstance(leafsize, int | np.integer) and leafsize >= 1):
            raise DataError(f"KDTree: expected leafsize >= 1, got {leafsize!r}")
        self._leafsize = int(leafsize)
        self._tree = None
        self._grid_built = True  # numba is loaded: adjacency sorts its rows compiled too
        data = pts.copy()
        data.setflags(write=False)
        self._data = data
        n = len(data)
        self._ids = np.arange(n, dtype=np.intp)
        mm = int(self.m)
        scale = metric.coordinate_scale(data.shape[1])
        # the metric's arithmetic: |q * s - d * s| (no copy when unscaled)
        scaled = data if np.all(scale == 1.0) else data * scale
        nbr, dist, lens, done = grid_knn(scaled, mm, self.threshold, workers)
        rest = np.flatnonzero(~done)
        if rest.size:  # outliers, crowded cells: exact rows by brute force or the tree
            if rest.size * n <= _BRUTE_ENTRIES:  # a few rows: not worth building the tree
                r_len, r_nbr, r_dist = self._brute_rows(rest.astype(np.intp))
            else:
                r_len, r_nbr, r_dist = self._compute_rows(rest.astype(np.intp))
            slot = np.arange(len(r_nbr)) - np.repeat(np.cumsum(r_len) - r_len, r_len)
            rows = np.repeat(rest, r_len)
            nbr[rest] = -1
            nbr[rows, slot] = r_nbr
            dist[rows, slot] = r_dist
            lens[rest] = r_len
        if n and int(lens.min()) == mm:
            self._nbr = nbr.reshape(-1).astype(np.intp, copy=False)
            self._dist = dist.reshape(-1)
        else:
            keep = np.arange(mm) < lens[:, None]
            self._nbr = nbr[keep].astype(np.intp, copy=False)
            self._dist = dist[keep]
        self._indptr = np.zeros(n + 1, np.intp)
        np.cumsum(lens, out=self._indptr[1:])
        self._adj = None

    def _brute_rows(
        self, ids: NDArray[np.intp]
    ) -> tuple[NDArray[np.intp], NDArray[np.intp], NDArray[np.float64]]:
        """Rows of a few points (static, unreordered ids) against all points, by brute force."""
        data = self._points_of(self._ids)
        lens, nbrs, dists = [], [], []
        n = len(data)
        k = min(int(self.m), n - 1)
        # rows in blocks: one broadcast distance matrix and one partition per block (the
        # same distances as row by row: the metric is elementwise per row)
        step = max(1, _BRUTE_BLOCK // max(n, 1))
        for s in range(0, len(ids), step):
            block = ids[s : s + step]
            D = self.metric.distance(data[block][:, None, :], data[None, :, :])  # (B, N)
            D[np.arange(len(block)), block] = math.inf  # not its own neighbour
            if self.threshold is not None:
                D[D > self.threshold] = math.inf
            # the k-th smallest distance of each row: every point tied with it competes
            cuts = np.partition(D, k - 1, axis=1)[:, k - 1] if 0 < k < n else None
            for r in range(len(block)):
                d = D[r]
                if cuts is None:
                    cand = np.arange(n)
                    cut = d.max() if n else math.inf
                else:
                    cut = cuts[r]
                    cand = np.flatnonzero(d <= cut)
                if not math.isfinite(cut):
                    cand = cand[np.isfinite(d[cand])]
                order = np.lexsort((cand, d[cand]))[:k]
                sel = cand[order]
                sel = sel[np.isfinite(d[sel])]
                lens.append(len(sel))
                nbrs.append(sel)
                dists.append(d[sel])
        return (
            np.asarray(lens, np.intp),
            np.concatenate(nbrs).astype(np.intp) if nbrs else np.zeros(0, np.intp),
            np.concatenate(dists) if dists else np.zeros(0),
        )

    # ------------------------------------------------------------------ the tree side
    def _points_of(self, ids: NDArray[np.intp]) -> NDArray[np.float64]:
        if isinstance(self._tree, DynamicKDTree):
            return self._tree.points_of(ids)
        data = self._data if self._data is not None else self.tree.data
        if len(ids) == len(data) and (len(ids) == 0 or (ids[0] == 0 and ids[-1] == len(ids) - 1)):
            return data  # all points in order (ids are 0..N-1): the read-only array itself
        return data[ids]

    def _compute_rows(
        self, ids: NDArray[np.intp]
    ) -> tuple[NDArray[np.intp], NDArray[np.intp], NDArray[np.float64]]:
        """Rows of the given ids: (lengths (Q,), neighbour ids, distances), nearest first."""
        ids = np.asarray(ids, np.intp)
        nq = len(ids)
        if nq == 0:
            return np.zeros(0, np.intp), np.zeros(0, np.intp), np.zeros(0)
        q = self._points_of(ids)
        # parts: (positions in 0..nq, lengths, neighbour ids, distances), rows nearest first
        parts: list[
            tuple[NDArray[np.intp], NDArray[np.intp], NDArray[np.intp], NDArray[np.float64]]
        ]
        parts = []
        if self.m == "all":
            assert self.threshold is not None
            ball = np.arange(nq)
            radii = np.full(nq, self.threshold * (1 + 1e-12) + 1e-30)
        else:
            ball_list, radii_list = [], []
            tree = self.tree
            if isinstance(tree, KDTree) and nq == tree.n and nq > 1:
                # Query in the tree's leaf order: neighbouring queries walk the same nodes
                # (cache-friendly; 1.3-2x faster on 1e5-1e6 unordered points).
                order = np.asarray(tree.tree.indices, dtype=np.intp)
            else:
                order = np.arange(nq)
            # Chunks bound the (chunk, m + 2) temporaries: peak memory ~ the output's.
            step = max(1, _CHUNK_ENTRIES // (int(self.m) + 2))
            for s in range(0, nq, step):
                sel = order[s : s + step]
                part, b_rows, b_radii = self._knn_chunk(q[sel], ids[sel])
                parts.append((sel, *part))
                ball_list.append(sel[b_rows])
                radii_list.append(b_radii)
            ball = np.concatenate(ball_list)
            radii = np.concatenate(radii_list)
        rows = {
            j: self._ball_row(q[j], ids[j], r)
            for j, r in zip(ball.tolist(), radii.tolist(), strict=True)
        }
        if rows:
            b = np.fromiter(rows, np.intp, len(rows))
            parts.append(
                (
                    b,
                    np.array([len(rows[j][0]) for j in rows], np.intp),
                    np.concatenate([rows[j][0] for j in rows]).astype(np.intp),
                    np.concatenate([rows[j][1] for j in rows]).astype(float),
                )
            )
        # Assemble the parts in row order by scattering each into its rows' slots.
        lens = np.zeros(nq, np.intp)
        for sel, ln, _, _ in parts:
            lens[sel] = ln
        indptr = np.concatenate([[0], np.cumsum(lens)])
        nbr_out = np.empty(int(indptr[-1]), np.intp)
        dist_out = np.empty(int(indptr[-1]))
        for sel, ln, nb, dd in parts:
            if nb.size:
                offs = np.arange(len(nb)) - np.repeat(np.cumsum(ln) - ln, ln)
                dest = np.repeat(indptr[sel], ln) + offs
                nbr_out[dest] = nb
                dist_out[dest] = dd
        return lens, nbr_out, dist_out

    def _knn_chunk(
        self, q: NDArray[np.float64], self_ids: NDArray[np.intp]
    ) -> tuple[
        tuple[NDArray[np.intp], NDArray[np.intp], NDArray[np.float64]],
        NDArray[np.intp],
        NDArray[np.float64],
    ]:
        """m nearest of a chunk of queries: ((lengths, ids, distances), tied rows, their radii).

        Tied rows (a tie across the m-th place, where the tree chose among equals) come back
        empty and are redone by :meth:`_ball_row`.
        """
        m = int(self.m)
        nq = len(q)
        # Slightly generous bound; the exact threshold filters below.
        dub = math.inf if self.threshold is None else self.threshold * (1 + 1e-12) + 1e-30
        # Threads cost more than they save on a handful of rows (updates).
        workers = self.workers if nq >= 2048 else 1
        d, i = self.tree.query(q, k=m + 2, distance_upper_bound=dub, workers=workers)
        d = np.asarray(d).reshape(nq, m + 2)
        i = np.asarray(i).reshape(nq, m + 2)
        valid = np.isfinite(d) & (i != self_ids[:, None])
        rank = np.cumsum(valid, axis=1, dtype=np.int32) - 1
        take = valid & (rank < m)
        d_last = np.where(valid & (rank == m - 1), d, -np.inf).max(axis=1)
        d_next = np.where(valid & (rank == m), d, np.inf).min(axis=1)
        tied = np.flatnonzero(d_next == d_last)
        if tied.size:
            take[tied] = False
        if self.threshold is not None:
            take &= d <= self.threshold
        lens = take.sum(axis=1).astype(np.intp)
        nbr = i[take].astype(np.intp)
        # The tree's distances are the metric's to the last bit for p = 1, 2, inf (cKDTree on
        # scaled coordinates does Metric.distance's arithmetic; sum_of is refined exactly).
        dist = d[take]
        if self.metric.is_minkowski and self.metric.p not in (1.0, 2.0, math.inf) and nbr.size:
            # cKDTree's pow() path differs from numpy's in the last bit: one formula for all.
            dist = self.metric.distance(np.repeat(q, lens, axis=0), self._points_of(nbr))
            row_of = np.repeat(np.arange(nq), lens)
            same = row_of[1:] == row_of[:-1]
            bad = same & ((dist[1:] < dist[:-1]) | ((dist[1:] == dist[:-1]) & (nbr[1:] < nbr[:-1])))
            if bad.any():
                sub = np.flatnonzero(np.isin(row_of, np.unique(row_of[1:][bad])))
                o = sub[np.lexsort((nbr[sub], dist[sub], row_of[sub]))]
                nbr[sub], dist[sub] = nbr[o], dist[o]
            if self.threshold is not None and np.any(dist > self.threshold):
                keep = dist <= self.threshold
                lens = np.bincount(row_of[keep], minlength=nq).astype(np.intp)
                nbr, dist = nbr[keep], dist[keep]
        return (lens, nbr, dist), tied, d_last[tied] * (1 + 1e-12) + 1e-30

    def _ball_row(
        self, x: NDArray[np.float64], self_id: int, r: float
    ) -> tuple[NDArray[np.intp], NDArray[np.float64]]:
        """Exact row of one point from a ball query: (ids, distances), nearest first, ties by id."""
        idx = np.asarray(self.tree.query_ball_point(x, r, workers=1), dtype=np.intp)
        idx = idx[idx != self_id]
        dd = self.metric.distance(x, self._points_of(idx)) if idx.size else np.zeros(0)
        if self.threshold is not None:
            keep = dd <= self.threshold
            idx, dd = idx[keep], dd[keep]
        order = np.lexsort((idx, dd))
        if self.m != "all":
            order = order[: int(self.m)]
        return idx[order], dd[order]

    # ------------------------------------------------------------------ views
    @property
    def n(self) -> int:
        """Number of points N."""
        return len(self._ids)

    def __len__(self) -> int:
        return self.n

    @property
    def points(self) -> NDArray[np.float64]:
        """(N, k) the points, row i = node i (may be a read-only view: copy before editing)."""
        return self._points_of(self._ids)

    @property
    def tree(self) -> KDTree | DynamicKDTree:
        """The k-d tree of the graph's points (a DynamicKDTree after the first update).

        With ``method="grid"`` the (paper's) tree is built on first access.
        """
        if self._tree is None:
            assert self._data is not None
            self._tree = KDTree(self._data, leafsize=self._leafsize, metric=self.metric)
        return self._tree

    def _cols(self) -> NDArray[np.intp]:
        if self._ids_are_range:
            return self._nbr
        return np.searchsorted(self._ids, self._nbr).astype(np.intp)

    @property
    def _ids_are_range(self) -> bool:
        n = len(self._ids)
        return n == 0 or (int(self._ids[0]) == 0 and int(self._ids[-1]) == n - 1)

    @property
    def adjacency(self) -> sparse.csr_array:
        """(N, N) directed adjacency, canonical CSR; data = distances (explicit zeros kept).

        Cached until the next update; treat it as read-only.
        """
        if self._adj is None:
            n = self.n
            if self._grid_built and self._ids_are_range:
                from mks_sim.lowlevel._gridknn import sort_rows

                cols, data = sort_rows(self._indptr, self._nbr, self._dist)
                adj = sparse.csr_array((data, cols, self._indptr.copy()), shape=(n, n))
                adj.has_sorted_indices = True
            else:
                adj = sparse.csr_array(
                    (self._dist.copy(), self._cols().copy(), self._indptr.copy()), shape=(n, n)
                )
                adj.sort_indices()  # permutes within rows, keeps explicit zeros
            self._adj = adj
        return self._adj

    @property
    def pattern(self) -> sparse.csr_array:
        """(N, N) boolean directed adjacency (True for every edge, including distance 0)."""
        adj = self.adjacency
        return sparse.csr_array(
            (np.ones(adj.nnz, bool), adj.indices.copy(), adj.indptr.copy()), shape=adj.shape
        )

    def symmetric(self) -> sparse.csr_array:
        """(N, N) undirected view: i~j if i->j or j->i; data = the smaller distance."""
        n = self.n
        cols = self._cols()
        rows = np.repeat(np.arange(n, dtype=np.int64), np.diff(self._indptr))
        r = np.concatenate([rows, cols.astype(np.int64)])
        c = np.concatenate([cols.astype(np.int64), rows])
        d = np.concatenate([self._dist, self._dist])
        key = r * max(n, 1) + c
        order = np.argsort(key, kind="stable")
        key, d = key[order], d[order]
        first = np.ones(len(key), bool)
        first[1:] = key[1:] != key[:-1]
        # a pair appears at most twice (i->j and j->i): keep the smaller distance
        dup = np.flatnonzero(~first)
        d[dup - 1] = np.minimum(d[dup - 1], d[dup])
        key, d = key[first], d[first]
        r, c = key // max(n, 1), key % max(n, 1)
        indptr = np.concatenate([[0], np.cumsum(np.bincount(r, minlength=n))])
        return sparse.csr_array((d, c.astype(np.intp), indptr), shape=(n, n))

    def neighbors(self, i: int) -> NDArray[np.intp]:
        """(n_i,) neighbour rows of node i, nearest first, ties by index."""
        s = self._row_slice(i)
        return np.searchsorted(self._ids, self._nbr[s]).astype(np.intp)

    def distances(self, i: int) -> NDArray[np.float64]:
        """(n_i,) distances aligned with :meth:`neighbors`."""
        return self._dist[self._row_slice(i)].copy()

    def _row_slice(self, i: int) -> slice:
        if not isinstance(i, int | np.integer) or not (-self.n <= i < self.n):
            raise DataError(
                f"SpatialProximityGraph: expected a node index in [0, {self.n}), got {i!r}"
            )
        i = int(i) % self.n
        return slice(int(self._indptr[i]), int(self._indptr[i + 1]))

    def components(self) -> tuple[int, NDArray[np.int32]]:
        """Connected components of the symmetric view: (count, labels (N,)).

        Computed as the weakly connected components of the directed graph (the same thing).
        """
        from mks_sim.lowlevel._gridknn import weak_components

        count, labels = weak_components(self.pattern)
        return int(count), labels

    # ------------------------------------------------------------------ updates
    def _ensure_dynamic(self) -> DynamicKDTree:
        if not isinstance(self._tree, DynamicKDTree):
            data = self._data if self._data is not None else self.tree.data
            self._tree = DynamicKDTree(
                data if len(data) else None,
                k=data.shape[1],
                leafsize=self._leafsize,
                metric=self.metric,
            )
            self._data = None
        return self._tree

    def _reach(self) -> NDArray[np.float64]:
        """(N,) how far each row looks: a new point closer than this may enter the row."""
        lens = np.diff(self._indptr)
        t = math.inf if self.threshold is None else self.threshold
        reach = np.full(self.n, t)
        if self.m != "all":
            full = lens >= int(self.m)
            last = self._dist[self._indptr[1:][full] - 1]
            reach[full] = np.minimum(last, t)
        return reach

    def insert(self, points: ArrayLike) -> NDArray[np.intp]:
        """Add (b, k) points; return their node indices (they are appended: N..N+b-1).

        Only rows that can change are recomputed: the new points' rows and the rows of old
        points whose reach (m-th neighbour distance, or the threshold) the new point falls in.
        """
        tree = self._ensure_dynamic()
        pts = validate_points(points, "SpatialProximityGraph.insert", tree.m)
        if len(pts) == 0:
            return np.zeros(0, np.intp)
        reach = self._reach()
        old_ids = self._ids
        affected = np.zeros(len(old_ids), bool)
        if len(old_ids):
            r_max = float(reach.max())
            if not math.isfinite(r_max) or not self.metric.is_minkowski:
                # Unbounded reach, or an asymmetric sum_of metric: check every old row.
                cand_rows = [np.arange(len(old_ids))] * len(pts)
            else:
                lists = tree.query_ball_point(pts, r_max * (1 + 1e-12) + 1e-30)
                cand_rows = [np.searchsorted(old_ids, np.asarray(lst, np.intp)) for lst in lists]
            old_pts = self._points_of(old_ids)
            for x, rows in zip(pts, cand_rows, strict=True):
                if rows.size:
                    d = self.metric.distance(old_pts[rows], x)
                    affected[rows[d <= reach[rows]]] = True
        new_ids = tree.insert(pts)
        ids_new = np.concatenate([old_ids, new_ids])
        rec_ids = np.concatenate([old_ids[affected], new_ids])
        self._recompute(ids_new, rec_ids)
        return np.arange(len(old_ids), len(ids_new), dtype=np.intp)

    def delete(self, indices: ArrayLike) -> NDArray[np.intp]:
        """Remove nodes; the rest are renumbered in order (like ``numpy.delete``).

        Returns:
            (N_old,) map old index -> new index (-1 for deleted nodes).
        """
        idx = np.atleast_1d(np.asarray(indices))
        if idx.size and idx.dtype.kind not in "iu":
            raise DataError(
                f"SpatialProximityGraph.delete: expected integer indices, got {idx.dtype}"
            )
        idx = idx.astype(np.intp)
        if np.any((idx < -self.n) | (idx >= self.n)):
            raise DataError(
                f"SpatialProximityGraph.delete: indices out of range [0, {self.n}): {idx.tolist()[:5]}"
            )
        idx = np.unique(idx % max(self.n, 1))
        gone = self._ids[idx]
        tree = self._ensure_dynamic()
        tree.delete(gone)
        keep = np.ones(self.n, bool)
        keep[idx] = False
        ids_new = self._ids[keep]
        rows = np.repeat(self._ids, np.diff(self._indptr))
        hit = np.unique(rows[np.isin(self._nbr, gone)])
        rec_ids = hit[np.isin(hit, ids_new)] if self.m != "all" else np.zeros(0, np.intp)
        # Finite m: every row that pointed at a deleted point is recomputed, so only m="all"
        # rows need their edges to deleted points dropped.
        self._recompute(ids_new, rec_ids, drop=gone if self.m == "all" else None)
        mapping = np.full(len(keep), -1, np.intp)
        mapping[keep] = np.arange(int(keep.sum()))
        return mapping

    def _recompute(
        self,
        ids_new: NDArray[np.intp],
        rec_ids: NDArray[np.intp],
        drop: NDArray[np.intp] | None = None,
    ) -> None:
        """Rebuild storage for rows ``ids_new``: recompute ``rec_ids``, copy the others."""
        rec_ids = np.sort(rec_ids)
        r_len, r_nbr, r_dist = self._compute_rows(rec_ids)
        if (drop is None or drop.size == 0) and self._splice_runs(
            ids_new, rec_ids, r_len, r_nbr, r_dist
        ):
            return
        n_new = len(ids_new)
        # Rows are in id order before and after, so copied rows keep their relative order:
        # everything is a scatter into the new CSR, no sorting (O(N m) per call).
        rec_pos = np.searchsorted(ids_new, rec_ids)
        is_rec = np.zeros(n_new, bool)
        is_rec[rec_pos] = True
        copy_pos = np.flatnonzero(~is_rec)
        old_rows = np.searchsorted(self._ids, ids_new[copy_pos])
        old_lens = np.diff(self._indptr)
        entry_row = np.repeat(np.arange(len(old_lens)), old_lens)
        row_keep = np.zeros(len(old_lens), bool)
        row_keep[old_rows] = True
        entry_keep = row_keep[entry_row]
        if drop is not None and drop.size:
            entry_keep &= ~np.isin(self._nbr, drop)
        kept_rows = entry_row[entry_keep]
        c_nbr, c_dist = self._nbr[entry_keep], self._dist[entry_keep]
        cnt = np.bincount(kept_rows, minlength=len(old_lens))[old_rows]
        lens = np.zeros(n_new, np.intp)
        lens[copy_pos] = cnt
        lens[rec_pos] = r_len
        indptr = np.concatenate([[0], np.cumsum(lens)]).astype(np.intp)
        nbr = np.empty(int(indptr[-1]), np.intp)
        dist = np.empty(int(indptr[-1]))
        for pos, ln, nb, dd in ((copy_pos, cnt, c_nbr, c_dist), (rec_pos, r_len, r_nbr, r_dist)):
            if nb.size:
                offs = np.arange(len(nb)) - np.repeat(np.cumsum(ln) - ln, ln)
                dest = np.repeat(indptr[pos], ln) + offs
                nbr[dest] = nb
                dist[dest] = dd
        self._ids = ids_new
        self._nbr = nbr
        self._dist = dist
        self._indptr = indptr
        self._adj = None

    def _splice_runs(
        self,
        ids_new: NDArray[np.intp],
        rec_ids: NDArray[np.intp],
        r_len: NDArray[np.intp],
        r_nbr: NDArray[np.intp],
        r_dist: NDArray[np.float64],
    ) -> bool:
        """Fast splice for few changed rows: copy unchanged runs of rows as contiguous slices.

        Returns False (nothing done) when the update touches too many places to be worth it.
        """
        n_new = len(ids_new)
        rec_pos = np.searchsorted(ids_new, rec_ids)
        is_rec = np.zeros(n_new, bool)
        is_rec[rec_pos] = True
        old_row = np.searchsorted(self._ids, ids_new)
        old_row[is_rec] = -2
        start = np.ones(n_new, bool)
        start[1:] = is_rec[1:] | is_rec[:-1] | (old_row[1:] != old_row[:-1] + 1)
        starts = np.flatnonzero(start)
        if len(starts) > _MAX_RUNS:
            return False
        ends = np.append(starts[1:], n_new) if len(starts) else starts
        rec_ptr = np.concatenate([[0], np.cumsum(r_len)])
        rec_index = {int(p): j for j, p in enumerate(rec_pos.tolist())}
        nbr_parts, dist_parts, len_parts = [], [], []
        for a, b in zip(starts.tolist(), ends.tolist(), strict=True):
            if is_rec[a]:
                j = rec_index[a]
                sl = slice(int(rec_ptr[j]), int(rec_ptr[j + 1]))
                nbr_parts.append(r_nbr[sl])
                dist_parts.append(r_dist[sl])
                len_parts.append(r_len[j : j + 1])
            else:
                oa, ob = int(old_row[a]), int(old_row[b - 1]) + 1
                e0, e1 = int(self._indptr[oa]), int(self._indptr[ob])
                nbr_parts.append(self._nbr[e0:e1])
                dist_parts.append(self._dist[e0:e1])
                len_parts.append(np.diff(self._indptr[oa : ob + 1]))
        lens = np.concatenate(len_parts) if len_parts else np.zeros(0, np.intp)
        self._ids = ids_new
        self._nbr = np.concatenate(nbr_parts).astype(np.intp) if nbr_parts else np.zeros(0, np.intp)
        self._dist = np.concatenate(dist_parts) if dist_parts else np.zeros(0)
        self._indptr = np.concatenate([[0], np.cumsum(lens)]).astype(np.intp)
        self._adj = None
        return True

    def __repr__(self) -> str:
        return (
            f"SpatialProximityGraph(n={self.n}, m={self.m!r}, threshold={self.threshold!r}, "
            f"edges={len(self._nbr)}, metric={self.metric.kind})"
        )


def _grid_unfit(pts: NDArray[np.float64], metric: Metric, m: Neighbours) -> str:
    """Why the grid kernel cannot build this SPG ('' when it can)."""
    from mks_sim.lowlevel import _gridknn

    if m == "all":
        return "an integer m, got m='all'"
    if not (metric.is_minkowski and metric.p == 2):
        return f"a Euclidean metric (weights/ranges allowed), got {metric.kind} p={metric.p}"
    if pts.shape[1] > 3:
        return f"points of dimension <= 3, got {pts.shape[1]}"
    if not _gridknn.available():
        return "numba (pip install numba==0.68.1), which does not import"
    return ""
