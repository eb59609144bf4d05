"""The k-d tree of MKS (paper section 1.2): a thin, exact wrapper of ``scipy.spatial.cKDTree``.

``cKDTree(balanced_tree=True)`` *is* the paper's tree: each non-terminal splits its points at
the median key value on the axis of greatest spread, and terminals hold buckets of at most
``leafsize`` points. We do not rewrite it; we add the paper's distance functions
(:class:`~mks_sim.lowlevel.metric.Metric`):

* Minkowski metrics with weights / range normalisation: the tree is built on scaled
  coordinates, so cKDTree's answers are exact.
* ``Metric.sum_of`` (``SUM f_i``): a threshold query is answered by a Chebyshev box query that
  provably contains every point within the threshold (see ``Metric.axis_bounds``), refined by
  evaluating the exact distance. A k-nearest query takes the k cKDTree neighbours in the scaled
  space, evaluates their exact distance ``R`` (the k-th of them bounds the true k-th distance
  from above) and answers the threshold query ``R`` exactly: one superset, no guessing.

Vocabulary follows scipy: ``query(x, k, eps, distance_upper_bound, workers)`` and
``query_ball_point(x, r, eps, workers, return_sorted)``; missing neighbours are index ``n`` and
distance ``inf``. The ``p`` of scipy is the metric's.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray
from scipy.spatial import cKDTree

from mks_sim.errors import DataError
from mks_sim.lowlevel.metric import Metric, validate_points

__all__ = ["KDTree"]


def _validate_k(k: int) -> int:
    if isinstance(k, bool) or not isinstance(k, int | np.integer) or k < 1:
        raise DataError(f"KDTree.query: expected an integer k >= 1, got {k!r}")
    return int(k)


class KDTree:
    """A k-d tree over ``data`` (N, k) answering queries under ``metric``.

    Args:
        data: (N, k) float points (finite). N may be 0.
        leafsize: bucket size of the terminals (paper: "a terminal contains a bucket of points").
        metric: the distance; default Euclidean.

    Attributes:
        data: (N, k) the points (a read-only copy).
        n: N.
        m: k (scipy's name for the dimension).
        metric: the Metric.
    """

    def __init__(self, data: ArrayLike, leafsize: int = 16, metric: Metric | None = None) -> None:
        self.metric = metric if metric is not None else Metric.euclidean()
        arr = validate_points(data, "KDTree data") if np.size(data) else np.asarray(data, float)
        if arr.ndim != 2:
            raise DataError(f"KDTree data: expected an (N, k) array, got shape {arr.shape}")
        self.metric.check_dim(arr.shape[1], "KDTree")
        if not (isinstance(leafsize, int | np.integer) and leafsize >= 1):
            raise DataError(f"KDTree: expected leafsize >= 1, got {leafsize!r}")
        self.data = arr.copy()
        self.data.setflags(write=False)
        self.n, self.m = arr.shape
        self.leafsize = int(leafsize)
        self._scale = self.metric.coordinate_scale(self.m)
        self._unit_scale = bool(np.all(self._scale == 1.0))
        self._p = self.metric.p if self.metric.is_minkowski else math.inf
        self.tree = cKDTree(
            self._scaled(self.data), leafsize=self.leafsize, balanced_tree=True, compact_nodes=True
        )
        if self.n:
            self._lo = self.data.min(axis=0)
            self._hi = self.data.max(axis=0)
        else:
            self._lo = self._hi = np.zeros(self.m)

    # ------------------------------------------------------------------ helpers
    def _scaled(self, x: NDArray[np.float64]) -> NDArray[np.float64]:
        """Coordinates as the cKDTree sees them (no copy for an unscaled metric)."""
        return x if self._unit_scale else x * self._scale

    def _queries(self, x: ArrayLike, where: str) -> tuple[NDArray[np.float64], bool]:
        arr = np.asarray(x, dtype=float)
        single = arr.ndim == 1
        pts = validate_points(arr.reshape(1, -1) if single else arr, where, self.m)
        return pts, single

    def _span(self, q: NDArray[np.float64]) -> NDArray[np.float64]:
        return np.maximum(np.abs(self._hi - q), np.abs(q - self._lo))

    def _ball_sum_of(
        self, q: NDArray[np.float64], r: NDArray[np.float64], workers: int
    ) -> list[tuple[NDArray[np.intp], NDArray[np.float64]]]:
        """Exact ``sum_of`` threshold query: per query (indices, distances) with d <= r."""
        out: list[tuple[NDArray[np.intp], NDArray[np.float64]]] = []
        if self.n == 0:
            return [(np.empty(0, np.intp), np.empty(0)) for _ in range(len(q))]
        bounds = self.metric.axis_bounds(q, r, self._span(q))  # (Q, k)
        # Box query in scaled space: Chebyshev radius = max_i bound_i * scale_i, then box filter.
        radius = (bounds * self._scale).max(axis=1)
        cands = self.tree.query_ball_point(self._scaled(q), radius, p=math.inf, workers=workers)
        for j in range(len(q)):
            idx = np.asarray(cands[j], dtype=np.intp)
            if idx.size:
                pts = self.data[idx]
                inbox = np.all(np.abs(pts - q[j]) <= bounds[j], axis=1)
                idx = idx[inbox]
            d = self.metric.distance(q[j], self.data[idx]) if idx.size else np.empty(0)
            keep = d <= r[j]
            out.append((idx[keep], d[keep]))
        return out

    # ------------------------------------------------------------------ queries
    def query(
        self,
        x: ArrayLike,
        k: int = 1,
        eps: float = 0.0,
        distance_upper_bound: float = math.inf,
        workers: int = 1,
    ) -> tuple[Any, Any]:
        """The k nearest neighbours of each query point.

        Args:
            x: (k_dim,) or (Q, k_dim) query points.
            k: number of neighbours.
            eps: approximate search (Minkowski only; ``sum_of`` is always exact).
            distance_upper_bound: return only neighbours at distance < this (strict, as scipy).
            workers: threads (-1: all cores).

        Returns:
            (d, i): shapes (Q, k) — or (Q,) when k == 1, and without the Q axis for a single
            point. Sorted nearest first, ties by index. Missing neighbours: i = n, d = inf.
            For Minkowski metrics, *which* of several points tied at the k-th distance is
            returned is cKDTree's choice; ``sum_of`` (and the SPG) take the lowest index.
        """
        k = _validate_k(k)
        q, single = self._queries(x, "KDTree.query")
        if self.metric.is_minkowski:
            d, i = self.tree.query(
                self._scaled(q),
                k=k,
                eps=eps,
                p=self._p,
                distance_upper_bound=distance_upper_bound,
                workers=workers,
            )
            d = np.asarray(d, float).reshape(len(q), k)
            i = np.asarray(i, np.intp).reshape(len(q), k)
            # cKDTree sorts by distance; order equal distances by index (only rows that need it).
            need = np.flatnonzero(np.any((d[:, 1:] == d[:, :-1]) & (i[:, 1:] < i[:, :-1]), axis=1))
            if need.size:
                order = np.lexsort((i[need], d[need]), axis=-1)
                d[need] = np.take_along_axis(d[need], order, -1)
                i[need] = np.take_along_axis(i[need], order, -1)
        else:
            d, i = self._knn_sum_of(q, k, distance_upper_bound, workers)
        if k == 1:
            d, i = d[:, 0], i[:, 0]
        if single:
            return d[0], i[0]
        return d, i

    def _knn_sum_of(
        self, q: NDArray[np.float64], k: int, dub: float, workers: int
    ) -> tuple[NDArray[np.float64], NDArray[np.intp]]:
        nq = len(q)
        d_out = np.full((nq, k), np.inf)
        i_out = np.full((nq, k), self.n, dtype=np.intp)
        if self.n == 0:
            return d_out, i_out
        kk = min(k, self.n)
        _, cand = self.tree.query(self._scaled(q), k=kk, p=math.inf, workers=workers)
        cand = np.asarray(cand, np.intp).reshape(nq, kk)
        exact = self.metric.distance(q[:, None, :], self.data[cand])  # (Q, kk)
        radius = exact.max(axis=1)  # the k-th true distance is <= this (kk points reach it)
        radius = np.minimum(radius, np.nextafter(dub, -np.inf)) if math.isfinite(dub) else radius
        for j, (idx, d) in enumerate(self._ball_sum_of(q, radius, workers)):
            keep = d < dub
            idx, d = idx[keep], d[keep]
            order = np.lexsort((idx, d))[:k]
            d_out[j, : order.size] = d[order]
            i_out[j, : order.size] = idx[order]
        return d_out, i_out

    def query_ball_point(
        self,
        x: ArrayLike,
        r: ArrayLike,
        eps: float = 0.0,
        workers: int = 1,
        return_sorted: bool | None = None,
        return_distances: bool = False,
    ) -> Any:
        """All points within distance ``r`` (inclusive, as scipy) of each query point.

        Args:
            x: (k_dim,) or (Q, k_dim) query points.
            r: scalar or (Q,) radii.
            eps: approximate search (Minkowski only).
            workers: threads.
            return_sorted: indices sorted ascending (default: yes; ``False`` leaves cKDTree's order).
            return_distances: also return the distances, aligned with the indices.

        Returns:
            For one point a list of indices; for Q points an object array (Q,) of lists.
            With ``return_distances`` a pair (indices, distances) of such containers.
        """
        q, single = self._queries(x, "KDTree.query_ball_point")
        rr = np.broadcast_to(np.asarray(r, dtype=float), (len(q),)).copy()
        if np.any(np.isnan(rr)) or np.any(rr < 0):
            raise DataError(f"KDTree.query_ball_point: expected r >= 0, got {r!r}")
        sort = return_sorted is None or return_sorted
        results: list[tuple[NDArray[np.intp], NDArray[np.float64]]]
        if self.metric.is_minkowski:
            lists = self.tree.query_ball_point(
                self._scaled(q), rr, p=self._p, eps=eps, workers=workers, return_sorted=sort
            )
            results = []
            for j in range(len(q)):
                idx = np.asarray(lists[j], dtype=np.intp)
                d = (
                    self.metric.distance(q[j], self.data[idx])
                    if return_distances and idx.size
                    else np.empty(0)
                )
                results.append((idx, d))
        else:
            results = self._ball_sum_of(q, rr, workers)
            if sort:
                results = [(idx[np.argsort(idx)], d[np.argsort(idx)]) for idx, d in results]
        ind = np.empty(len(q), dtype=object)
        dis = np.empty(len(q), dtype=object)
        for j, (idx, d) in enumerate(results):
            ind[j] = idx.tolist()
            dis[j] = d.tolist()
        if single:
            return (ind[0], dis[0]) if return_distances else ind[0]
        return (ind, dis) if return_distances else ind

    def distance(self, x: ArrayLike, indices: ArrayLike) -> NDArray[np.float64]:
        """Exact metric distance from query point(s) x to the tree points ``indices``."""
        return self.metric.distance(np.asarray(x, float), self.data[np.asarray(indices, np.intp)])

    def __len__(self) -> int:
        return self.n

    def __repr__(self) -> str:
        return (
            f"KDTree(n={self.n}, k={self.m}, leafsize={self.leafsize}, metric={self.metric.kind})"
        )
