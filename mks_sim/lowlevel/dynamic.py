"""A k-d tree with insert and delete (paper section 5: Overmars & van Leeuwen).

The paper notes that adding data is expensive "since the k-d tree must be completely rebuilt"
and names dynamic structures as further work. We use Overmars & van Leeuwen's *logarithmic
method*: the points live in a few static :class:`~mks_sim.lowlevel.kdtree.KDTree` blocks whose
sizes behave like a binary counter — a block of level ``L`` holds at most ``2**L`` points and
no two blocks share a level. An insert makes a new block and merges it with the block of its
level while there is one (a carry), so each point is rebuilt O(log n) times (amortised).
A delete only marks the point dead; a block is rebuilt from its live points when more than half
of it is dead, so queries (which skip dead points) never do more than twice the work.

Points have stable integer ids (issued in insertion order, never reused). Queries speak the
scipy vocabulary and return ids; a missing neighbour is ``next_id`` (one past the largest id
issued so far — for a tree that never deleted, that is ``n``, exactly as scipy) with distance
``inf``. Results are sorted nearest first, ties by id.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from mks_sim.errors import DataError, NotFound
from mks_sim.lowlevel.kdtree import KDTree
from mks_sim.lowlevel.metric import Metric, validate_points

__all__ = ["DynamicKDTree"]


def _level(size: int) -> int:
    return max(0, (size - 1).bit_length())


@dataclass
class _Block:
    ids: NDArray[np.intp]  # (s,) ids of the block's points, ascending
    tree: KDTree
    alive: NDArray[np.bool_]  # (s,)
    dead: int = 0

    @property
    def size(self) -> int:
        return len(self.ids)


class DynamicKDTree:
    """A k-d tree supporting ``insert`` and ``delete`` without a full rebuild.

    Args:
        data: (N, k) initial points (ids 0..N-1), or None for an empty tree of dimension ``k``.
        k: the dimension when ``data`` is None.
        leafsize: bucket size of the static blocks.
        metric: the distance (any :class:`Metric`, including ``sum_of``).
    """

    def __init__(
        self,
        data: ArrayLike | None = None,
        k: int | None = None,
        leafsize: int = 16,
        metric: Metric | None = None,
    ) -> None:
        self.metric = metric if metric is not None else Metric.euclidean()
        self.leafsize = leafsize
        self._blocks: dict[int, _Block] = {}
        self.next_id = 0
        self.rebuilds = 0  # number of static blocks built (for the benchmark)
        if data is None:
            if k is None:
                raise DataError("DynamicKDTree: give data or k")
            self.m = int(k)
        else:
            arr = validate_points(data, "DynamicKDTree data")
            self.m = arr.shape[1]
        self.metric.check_dim(self.m, "DynamicKDTree")
        # Indexed by id, with spare capacity (slots >= next_id are not alive).
        self._points = np.empty((0, self.m))
        self._alive = np.empty(0, dtype=bool)
        self._block_of = np.empty(0, dtype=np.intp)  # id -> block level
        if data is not None and len(arr):
            self.insert(arr)

    # ------------------------------------------------------------------ state
    @property
    def n(self) -> int:
        """Number of live points."""
        return int(self._alive.sum())

    def __len__(self) -> int:
        return self.n

    @property
    def ids(self) -> NDArray[np.intp]:
        """(n,) live ids, ascending."""
        return np.flatnonzero(self._alive)

    @property
    def data(self) -> NDArray[np.float64]:
        """(n, k) live points in id order (aligned with :attr:`ids`)."""
        return self._points[self._alive]

    def points_of(self, ids: ArrayLike) -> NDArray[np.float64]:
        """(len(ids), k) coordinates of live ids."""
        return self._points[self._check_ids(ids, "points_of")]

    def _check_ids(self, ids: ArrayLike, where: str) -> NDArray[np.intp]:
        arr = np.atleast_1d(np.asarray(ids))
        if arr.size == 0:
            return np.empty(0, np.intp)
        if arr.dtype.kind not in "iu":
            raise DataError(f"DynamicKDTree.{where}: expected integer ids, got dtype {arr.dtype}")
        arr = arr.astype(np.intp)
        bad = (arr < 0) | (arr >= self.next_id)
        bad[~bad] = ~self._alive[arr[~bad]]
        if bad.any():
            raise NotFound(
                f"DynamicKDTree.{where}: ids {arr[bad][:5].tolist()} are not live points "
                f"(ids issued: 0..{self.next_id - 1}, live: {self.n})"
            )
        return arr

    # ------------------------------------------------------------------ updates
    def _make_block(self, ids: NDArray[np.intp]) -> _Block:
        self.rebuilds += 1
        tree = KDTree(self._points[ids], leafsize=self.leafsize, metric=self.metric)
        return _Block(ids=ids, tree=tree, alive=np.ones(len(ids), dtype=bool))

    def _place(self, ids: NDArray[np.intp]) -> None:
        """Carry loop of the binary counter: merge with the block of the same level."""
        ids = ids[self._alive[ids]]
        while True:
            level = _level(len(ids))
            other = self._blocks.pop(level, None)
            if other is None:
                break
            ids = np.concatenate([ids, other.ids[other.alive]])
            ids.sort()
        if len(ids) == 0:
            return
        block = self._make_block(ids)
        self._blocks[level] = block
        self._block_of[ids] = level

    def insert(self, points: ArrayLike) -> NDArray[np.intp]:
        """Insert (b, k) points; return their new ids (b,)."""
        pts = validate_points(points, "DynamicKDTree.insert", self.m)
        b = len(pts)
        ids = np.arange(self.next_id, self.next_id + b, dtype=np.intp)
        self.next_id += b
        cap = len(self._alive)
        if self.next_id > cap:  # grow geometrically: amortised O(1) per inserted point
            grow = max(self.next_id, 2 * cap) - cap
            self._points = np.concatenate([self._points, np.zeros((grow, self.m))])
            self._alive = np.concatenate([self._alive, np.zeros(grow, dtype=bool)])
            self._block_of = np.concatenate([self._block_of, np.full(grow, -1, dtype=np.intp)])
        self._points[ids] = pts
        self._alive[ids] = True
        if b:
            self._place(ids)
        return ids

    def delete(self, ids: ArrayLike) -> None:
        """Delete live points by id (NotFound if an id is not live). Duplicates are an error."""
        arr = self._check_ids(ids, "delete")
        if len(np.unique(arr)) != len(arr):
            raise DataError("DynamicKDTree.delete: ids repeat")
        self._alive[arr] = False
        levels = np.unique(self._block_of[arr]).tolist()
        for level in levels:
            block = self._blocks[level]
            these = arr[self._block_of[arr] == level]
            pos = np.searchsorted(block.ids, these)
            block.alive[pos] = False
            block.dead += len(these)
        for level in levels:
            maybe = self._blocks.get(level)
            # More than half dead: rebuild from the live part (a carry may already have
            # merged this block away; then there is nothing to do).
            if maybe is not None and 2 * maybe.dead > maybe.size:
                del self._blocks[level]
                self._place(maybe.ids[maybe.alive])

    # ------------------------------------------------------------------ queries
    def query(
        self,
        x: ArrayLike,
        k: int = 1,
        eps: float = 0.0,
        distance_upper_bound: float = math.inf,
        workers: int = 1,
    ) -> tuple[Any, Any]:
        """k nearest live points: (d, ids) shaped as :meth:`KDTree.query`; missing = next_id."""
        if isinstance(k, bool) or not isinstance(k, int | np.integer) or k < 1:
            raise DataError(f"DynamicKDTree.query: expected an integer k >= 1, got {k!r}")
        arr = np.asarray(x, dtype=float)
        single = arr.ndim == 1
        q = validate_points(arr.reshape(1, -1) if single else arr, "DynamicKDTree.query", self.m)
        ds, idss = [np.full((len(q), k), np.inf)], [np.full((len(q), k), self.next_id, np.intp)]
        for block in self._blocks.values():
            d_b, i_b = self._query_block(block, q, k, eps, distance_upper_bound, workers)
            ds.append(d_b)
            idss.append(i_b)
        d_all = np.concatenate(ds, axis=1)
        i_all = np.concatenate(idss, axis=1)
        order = np.lexsort((i_all, d_all), axis=-1)[:, :k]
        d_out = np.take_along_axis(d_all, order, -1)
        i_out = np.take_along_axis(i_all, order, -1)
        if k == 1:
            d_out, i_out = d_out[:, 0], i_out[:, 0]
        return (d_out[0], i_out[0]) if single else (d_out, i_out)

    def _query_block(
        self, block: _Block, q: NDArray[np.float64], k: int, eps: float, dub: float, workers: int
    ) -> tuple[NDArray[np.float64], NDArray[np.intp]]:
        """The k nearest *live* points of one block: (Q, k) distances and ids.

        Asks for k + min(dead, k) neighbours first and doubles for the rows whose answer was
        saturated by dead points, so a few marks never cost a query of k + dead.
        """
        nq = len(q)
        d_out = np.full((nq, k), np.inf)
        i_out = np.full((nq, k), self.next_id, np.intp)
        rows = np.arange(nq)
        kb = min(k + min(block.dead, k), block.size)
        while rows.size:
            d, i = block.tree.query(
                q[rows], k=kb, eps=eps, distance_upper_bound=dub, workers=workers
            )
            d = np.asarray(d).reshape(len(rows), kb)
            i = np.asarray(i).reshape(len(rows), kb)
            found = i < block.size
            safe = np.minimum(i, block.size - 1)
            ok = found & block.alive[safe]
            # stable: live entries first, in the tree's (distance, index) order
            order = np.argsort(~ok, axis=1, kind="stable")[:, :k]
            dk = np.take_along_axis(np.where(ok, d, np.inf), order, 1)
            ik = np.take_along_axis(np.where(ok, block.ids[safe], self.next_id), order, 1)
            w = min(k, kb)
            d_out[rows, :w] = dk[:, :w]
            i_out[rows, :w] = ik[:, :w]
            more = (ok.sum(axis=1) < k) & found[:, -1]  # saturated: dead points may hide live ones
            if kb >= block.size or not more.any():
                break
            rows = rows[more]
            kb = min(2 * kb, block.size)
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
        """Live points within distance r (inclusive): ids (sorted ascending), as KDTree's."""
        arr = np.asarray(x, dtype=float)
        single = arr.ndim == 1
        q = validate_points(
            arr.reshape(1, -1) if single else arr, "DynamicKDTree.query_ball_point", self.m
        )
        nq = len(q)
        acc_i: list[list[NDArray[np.intp]]] = [[] for _ in range(nq)]
        acc_d: list[list[NDArray[np.float64]]] = [[] for _ in range(nq)]
        for block in self._blocks.values():
            ind, dis = block.tree.query_ball_point(
                q, r, eps=eps, workers=workers, return_sorted=False, return_distances=True
            )
            for j in range(nq):
                idx = np.asarray(ind[j], np.intp)
                keep = block.alive[idx]
                acc_i[j].append(block.ids[idx[keep]])
                acc_d[j].append(np.asarray(dis[j], float)[keep])
        ind_out = np.empty(nq, dtype=object)
        dis_out = np.empty(nq, dtype=object)
        for j in range(nq):
            ii = np.concatenate(acc_i[j]) if acc_i[j] else np.empty(0, np.intp)
            dd = np.concatenate(acc_d[j]) if acc_d[j] else np.empty(0)
            o = np.argsort(ii)
            ind_out[j] = ii[o].tolist()
            dis_out[j] = dd[o].tolist()
        if single:
            return (ind_out[0], dis_out[0]) if return_distances else ind_out[0]
        return (ind_out, dis_out) if return_distances else ind_out

    def rebuild(self) -> None:
        """Rebuild everything into one block (drops all deletion marks)."""
        self._blocks.clear()
        self._place(self.ids)

    def __repr__(self) -> str:
        sizes = {lv: b.size for lv, b in sorted(self._blocks.items())}
        return f"DynamicKDTree(n={self.n}, k={self.m}, blocks={sizes})"
