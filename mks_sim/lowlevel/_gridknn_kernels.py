"""The compiled kernels of :mod:`mks_sim.lowlevel._gridknn` (imported only when numba is used).

Module-level functions so that numba caches their machine code (``cache=True``) in
``__pycache__``: the first use on a machine compiles (seconds), later processes load it.
"""
# mypy: ignore-errors

from __future__ import annotations

import math

import numba as nb
import numpy as np

# Cells per parallel task.
_CHUNK = 256

# A row's candidates are first those within this factor of the previous row's m-th squared
# distance (1.1 x its distance; neighbours are alike), all of them when that holds m or
# fewer: the previous row's own distance failed for 59 % of the workstation's 4,300 object
# points and every one of their ~67 block points was ranked (ring 1 of knn_cells: 3.4 ->
# 2.4 ms on one thread, with the guess carried from cell to cell). Any slack gives the same
# rows: m points within the guess bound the m-th distance.
_GUESS_SLACK = 1.21


@nb.njit(cache=True)
def cell_coords(pts, lo, h, dims):
    n = pts.shape[0]
    out = np.empty((n, 3), np.int64)
    for i in range(n):
        for a in range(3):
            c = int(math.floor((pts[i, a] - lo[a]) / h))
            if c < 0:
                c = 0
            elif c >= dims[a]:
                c = dims[a] - 1
            out[i, a] = c
    return out


@nb.njit(cache=True, parallel=True)
def cell_keys(pts, lo, h, dims):
    """(N,) linear cell key (x-major, z fastest) of each point."""
    n = pts.shape[0]
    out = np.empty(n, np.int64)
    for i in nb.prange(n):
        key = 0
        for a in range(3):
            c = int(math.floor((pts[i, a] - lo[a]) / h))
            if c < 0:
                c = 0
            elif c >= dims[a]:
                c = dims[a] - 1
            key = key * dims[a] + c
        out[i] = key
    return out


@nb.njit(cache=True)
def counting_order(keys, ncells):
    """Stable order sorting ``keys`` (all in [0, ncells)): a counting sort, O(N + ncells)."""
    return buckets(keys, ncells)[1]


@nb.njit(cache=True)
def buckets(key, ncells):
    """(start, order) of a stable counting sort of ``key`` (all in [0, ncells)): the
    indices with key c are ``order[start[c]:start[c + 1]]``, ascending."""
    start = np.zeros(ncells + 1, np.int64)
    for k in key:
        start[k + 1] += 1
    for c in range(ncells):
        start[c + 1] += start[c]
    fill = start[:-1].copy()
    order = np.empty(key.shape[0], np.int64)
    for i in range(key.shape[0]):
        order[fill[key[i]]] = i
        fill[key[i]] += 1
    return start, order


@nb.njit(cache=True, parallel=True)
def gather_columns(pts, order):
    """The three coordinate columns of ``pts[order]``, contiguous."""
    n = order.shape[0]
    sx = np.empty(n)
    sy = np.empty(n)
    sz = np.empty(n)
    for i in nb.prange(n):
        j = order[i]
        sx[i] = pts[j, 0]
        sy[i] = pts[j, 1]
        sz[i] = pts[j, 2]
    return sx, sy, sz


@nb.njit(cache=True, parallel=True)
def sort_rows(indptr, cols, data):
    """Copies of a CSR's (cols, data) with every row sorted by column (insertion sort: the
    SPG's rows are short)."""
    n = indptr.shape[0] - 1
    oc = cols.copy()
    od = data.copy()
    for r in nb.prange(n):
        a = indptr[r]
        b = indptr[r + 1]
        for i in range(a + 1, b):
            c = oc[i]
            d = od[i]
            k = i
            while k > a and oc[k - 1] > c:
                oc[k] = oc[k - 1]
                od[k] = od[k - 1]
                k -= 1
            oc[k] = c
            od[k] = d
    return oc, od


@nb.njit(cache=True)
def count_occupied(pts, lo, h, dims):
    n = pts.shape[0]
    size = 1
    while size < 2 * n:
        size *= 2
    table = np.full(size, -1, np.int64)
    mask = size - 1
    occupied = 0
    for i in range(n):
        key = 0
        for a in range(3):
            c = int(math.floor((pts[i, a] - lo[a]) / h))
            if c < 0:
                c = 0
            elif c >= dims[a]:
                c = dims[a] - 1
            key = key * dims[a] + c
        slot = ((key ^ (key >> 29)) * 0x2545F4914F6CDD1D) & mask
        while True:
            v = table[slot]
            if v == key:
                break
            if v == -1:
                table[slot] = key
                occupied += 1
                break
            slot = (slot + 1) & mask
    return occupied


@nb.njit(cache=True, parallel=True)
def knn_cells(
    sx,  # (N,) x of the points sorted by cell
    sy,
    sz,
    sidx,  # (N,) their original indices
    ccoord,  # (C, 3) cell coordinates of the occupied cells, by key
    ckey,  # (C,) their keys, ascending
    cstart,  # (C + 1,) first sorted point of each cell
    colptr,  # (X * Y + 1,) first cell of each (x, y) column
    todo,  # (N,) bool, sorted order: rows still to answer
    lo,
    h,
    dims,
    m,
    thr,
    ring,
    margin,
    max_block,
    out_nbr,  # (N, m) original order
    out_dist,
    out_len,
    done,  # (N,) bool, original order
    chunk=_CHUNK,  # cells per parallel task
):
    ncell = ckey.shape[0]
    ncol = (2 * ring + 1) * (2 * ring + 1)
    nchunk = (ncell + chunk - 1) // chunk
    for ch in nb.prange(nchunk):
        # Buffers shared by the chunk's cells (allocating per cell costs more than the work).
        rlo = np.empty(ncol, np.int64)
        rhi = np.empty(ncol, np.int64)
        bx = np.empty(max_block)
        by = np.empty(max_block)
        bz = np.empty(max_block)
        bt = np.empty(max_block, np.int64)
        d2 = np.empty(max_block)
        sel = np.empty(max_block + 1, np.int64)
        bd = np.empty(6)
        best_d = np.empty(m)
        best_d2 = np.empty(m)
        best_i = np.empty(m, np.int64)
        guess = np.full(1, np.inf)  # carried from cell to cell of the task
        for c in range(ch * chunk, min(ncell, (ch + 1) * chunk)):
            cell_rows(
                c, sx, sy, sz, sidx, ccoord, ckey, cstart, colptr, todo, lo, h, dims, m, thr, ring,
                margin, max_block, out_nbr, out_dist, out_len, done,
                rlo, rhi, bx, by, bz, bt, d2, sel, bd, best_d, best_d2, best_i, guess,
            )  # fmt: skip


@nb.njit(cache=True)
def lower_bound(a, v, lo_, hi_):
    while lo_ < hi_:
        mid = (lo_ + hi_) >> 1
        if a[mid] < v:
            lo_ = mid + 1
        else:
            hi_ = mid
    return lo_


@nb.njit(cache=True, inline="always")
def _insert_ranked(best_d2, best_i, u, e2, j):
    """Insert (e2, j) into the ranked ``best_d2``/``best_i`` at slot ``u`` or before, by
    (squared distance, index); the entries from its place to ``u - 1`` move up one."""
    while u > 0 and (best_d2[u - 1] > e2 or (best_d2[u - 1] == e2 and best_i[u - 1] > j)):
        best_d2[u] = best_d2[u - 1]
        best_i[u] = best_i[u - 1]
        u -= 1
    best_d2[u] = e2
    best_i[u] = j


@nb.njit(cache=True)
def cell_rows(
    c, sx, sy, sz, sidx, ccoord, ckey, cstart, colptr, todo, lo, h, dims, m, thr, ring,
    margin, max_block, out_nbr, out_dist, out_len, done,
    rlo, rhi, bx, by, bz, bt, d2, sel, bd, best_d, best_d2, best_i, guess,
):  # fmt: skip
    """The rows of the points of cell c (see knn_cells)."""
    s0 = cstart[c]
    s1 = cstart[c + 1]
    any_todo = False
    for s in range(s0, s1):
        if todo[s]:
            any_todo = True
            break
    if not any_todo:
        return
    cx = ccoord[c, 0]
    cy = ccoord[c, 1]
    cz = ccoord[c, 2]
    # The block's columns: for each (x, y) a contiguous range of sorted points over z.
    nr = 0
    total = 0
    z0 = max(cz - ring, 0)
    z1 = min(cz + ring, dims[2] - 1)
    for x in range(max(cx - ring, 0), min(cx + ring, dims[0] - 1) + 1):
        for y in range(max(cy - ring, 0), min(cy + ring, dims[1] - 1) + 1):
            col = x * dims[1] + y
            base = col * dims[2]
            if colptr.shape[0]:
                c0 = colptr[col]
                c1 = colptr[col + 1]
            else:  # no column table (too many columns): search all cells
                c0 = 0
                c1 = ckey.shape[0]
            a = lower_bound(ckey, base + z0, c0, c1)
            b = lower_bound(ckey, base + z1 + 1, a, c1)
            if b > a:
                rlo[nr] = cstart[a]
                rhi[nr] = cstart[b]
                total += cstart[b] - cstart[a]
                nr += 1
    if total > max_block:
        return
    # The block's points, gathered once for all the points of the cell.
    u = 0
    for r in range(nr):
        for t in range(rlo[r], rhi[r]):
            bx[u] = sx[t]
            by[u] = sy[t]
            bz[u] = sz[t]
            bt[u] = sidx[t]
            u += 1
    # Distance from a point of this cell to the block's boundary, per face; faces on
    # the grid's edge have no points beyond them.
    for a in range(3):
        ca = ccoord[c, a]
        bd[2 * a] = lo[a] + (ca - ring) * h if ca - ring > 0 else -np.inf
        bd[2 * a + 1] = lo[a] + (ca + ring + 1) * h if ca + ring < dims[a] - 1 else np.inf
    lim0 = np.inf  # squared distance beyond which nothing can enter
    if thr < np.inf:
        lim0 = thr * thr * (1.0 + 1e-14) + 1e-300
    for s in range(s0, s1):
        if not todo[s]:
            continue
        me = sidx[s]
        qx = sx[s]
        qy = sy[s]
        qz = sz[s]
        for t in range(total):  # vectorised by LLVM
            dx = qx - bx[t]
            dy = qy - by[t]
            dz = qz - bz[t]
            d2[t] = (dx * dx + dy * dy) + dz * dz
        cnt = 0
        lim2 = lim0
        # Candidates within the guess (or the threshold), compacted without branches.
        lim = min(guess[0], lim0)
        nsel = 0
        for t in range(total):
            sel[nsel] = t
            nsel += d2[t] <= lim
        if nsel <= m:  # the guess holds too few (self counts): rank every candidate
            nsel = 0
            for t in range(total):
                sel[nsel] = t
                nsel += d2[t] <= lim0
        # Rank by (squared distance, index); distances (sqrt) only for the kept ones.
        for u in range(nsel):
            t = sel[u]
            e2 = d2[t]
            if e2 > lim2:
                continue
            j = bt[t]
            if j == me:
                continue
            if cnt == m:
                dl = best_d2[m - 1]
                if e2 > dl or (e2 == dl and j > best_i[m - 1]):
                    continue
                k = m - 1
            else:
                k = cnt
                cnt += 1
            _insert_ranked(best_d2, best_i, k, e2, j)
            if cnt == m:
                lim2 = min(lim2, best_d2[m - 1])
        # The SPG ranks by (distance, index): distinct squares may share a sqrt. Reorder such
        # runs by index, and give up the row (the tree answers it) when a left-out candidate
        # ties the m-th distance, or when the threshold cut falls inside a tie.
        for k in range(cnt):
            best_d[k] = math.sqrt(best_d2[k])
        for k in range(1, cnt):
            u = k
            while u > 0 and best_d[u - 1] == best_d[u] and best_i[u - 1] > best_i[u]:
                best_i[u - 1], best_i[u] = best_i[u], best_i[u - 1]
                best_d2[u - 1], best_d2[u] = best_d2[u], best_d2[u - 1]
                u -= 1
        while cnt > 0 and best_d[cnt - 1] > thr:
            cnt -= 1
        if cnt == m:
            dl = best_d2[m - 1]
            hi = dl * (1.0 + 1e-15) + 1e-300  # squares whose sqrt can equal the m-th distance
            near = 0
            for t in range(total):  # vectorised
                near += (d2[t] > dl) & (d2[t] <= hi)
            if near:
                ambiguous = False
                for t in range(total):
                    if d2[t] > dl and d2[t] <= hi and math.sqrt(d2[t]) == best_d[m - 1]:
                        ambiguous = True
                if ambiguous:
                    continue
            guess[0] = dl * _GUESS_SLACK + 1e-300
        cov = min(qx - bd[0], bd[1] - qx, qy - bd[2], bd[3] - qy, qz - bd[4], bd[5] - qz)
        reach = thr
        if cnt == m and best_d[m - 1] < reach:
            reach = best_d[m - 1]
        if not (reach < cov - margin):
            continue
        for k in range(cnt):
            out_nbr[me, k] = best_i[k]
            out_dist[me, k] = best_d[k]
        out_len[me] = cnt
        done[me] = True


@nb.njit(cache=True, parallel=True)
def column_keys(pts, lo, h, nx, ny):
    """(N,) column key (x-major) of each point on the (x, y) grid of cell h (in parallel:
    a 640 x 480 scan's 1.4 -> 0.8 ms)."""
    n = pts.shape[0]
    out = np.empty(n, np.int64)
    for i in nb.prange(n):
        cx = int(math.floor((pts[i, 0] - lo[0]) / h))
        cy = int(math.floor((pts[i, 1] - lo[1]) / h))
        cx = min(max(cx, 0), nx - 1)
        cy = min(max(cy, 0), ny - 1)
        out[i] = cx * ny + cy
    return out


@nb.njit(cache=True)
def _rank_run(qx, qy, qz, sx, sy, sz, order, s0, s1, k, best_d2, best_i, cnt):
    """The sorted points s0 .. s1 ranked into the k best by (squared distance, index) of
    the query (``cnt`` of them held); returns the new count. Once k are held, a point
    farther than the k-th is passed over before its index is read."""
    for s in range(s0, s1):
        dx = qx - sx[s]
        dy = qy - sy[s]
        dz = qz - sz[s]
        e2 = (dx * dx + dy * dy) + dz * dz
        if cnt == k:
            worst = best_d2[k - 1]
            if e2 > worst:
                continue
            j = order[s]
            if e2 == worst and j > best_i[k - 1]:
                continue
            u = k - 1
        else:
            j = order[s]
            u = cnt
            cnt += 1
        _insert_ranked(best_d2, best_i, u, e2, j)
    return cnt


@nb.njit(cache=True, parallel=True)
def probe_rows(
    pts, sx, sy, sz, rows, k, lo, h, nx, ny, start, order, margin, max_ring, max_block, out_d,
    out_i, done,
):  # fmt: skip
    """The k nearest points (the probe itself included, nearest first, ties by index) of
    each probe row, from the (2r+1)^2 columns around its own on an (x, y) grid of cell h,
    r growing until every point outside them is provably farther than the k-th (at most
    ``max_ring``, and blocks of at most ``max_block`` points: a row not proven by then is
    left not done; a far outlier that stretches the grid leaves the dense rest to a tree).

    Each ring ranks only the columns the last one did not (the k best by (distance, index)
    do not depend on the order they are met in), an x's columns as one or two runs of the
    sorted points (1,500 probes of a 43,200-point scan: 0.95 -> 0.82 ms against column by
    column); chunks of probes run in parallel, each probe's answer the same whichever
    thread runs it."""
    n_rows = rows.shape[0]
    nchunk = max(1, min((n_rows + 63) // 64, 8))
    size = (n_rows + nchunk - 1) // nchunk
    for ch in nb.prange(nchunk):
        best_d2 = np.empty(k)
        best_i = np.empty(k, np.int64)
        for p in range(ch * size, min(n_rows, (ch + 1) * size)):
            i = rows[p]
            qx = pts[i, 0]
            qy = pts[i, 1]
            qz = pts[i, 2]
            cx = min(max(int(math.floor((qx - lo[0]) / h)), 0), nx - 1)
            cy = min(max(int(math.floor((qy - lo[1]) / h)), 0), ny - 1)
            cnt = 0
            px0 = 1
            px1 = 0  # the last ring's block (none yet)
            py0 = 1
            py1 = 0
            for r in range(1, max_ring + 1):
                x0 = max(cx - r, 0)
                x1 = min(cx + r, nx - 1)
                y0 = max(cy - r, 0)
                y1 = min(cy + r, ny - 1)
                total = 0
                for x in range(x0, x1 + 1):
                    total += start[x * ny + y1 + 1] - start[x * ny + y0]
                if total > max_block:
                    break
                for x in range(x0, x1 + 1):
                    # (x, y0 .. y1) is one run of the sorted columns; the last ring's
                    # columns of this x (ranked) split it in two
                    base = x * ny
                    if px0 <= x <= px1:
                        cnt = _rank_run(
                            qx, qy, qz, sx, sy, sz, order, start[base + y0], start[base + py0],
                            k, best_d2, best_i, cnt,
                        )  # fmt: skip
                        cnt = _rank_run(
                            qx, qy, qz, sx, sy, sz, order, start[base + py1 + 1],
                            start[base + y1 + 1], k, best_d2, best_i, cnt,
                        )  # fmt: skip
                    else:
                        cnt = _rank_run(
                            qx, qy, qz, sx, sy, sz, order, start[base + y0],
                            start[base + y1 + 1], k, best_d2, best_i, cnt,
                        )  # fmt: skip
                px0 = x0
                px1 = x1
                py0 = y0
                py1 = y1
                # points outside the block are at least this far in (x, y) alone
                cov = np.inf
                if x0 > 0:
                    cov = min(cov, qx - (lo[0] + x0 * h))
                if x1 < nx - 1:
                    cov = min(cov, lo[0] + (x1 + 1) * h - qx)
                if y0 > 0:
                    cov = min(cov, qy - (lo[1] + y0 * h))
                if y1 < ny - 1:
                    cov = min(cov, lo[1] + (y1 + 1) * h - qy)
                if cnt == k and math.sqrt(best_d2[k - 1]) < cov - margin:
                    for u in range(k):
                        out_d[p, u] = math.sqrt(best_d2[u])
                        out_i[p, u] = best_i[u]
                    done[p] = True
                    break


@nb.njit(cache=True)
def radix_order(keys, bits):
    """A stable order sorting non-negative int64 ``keys`` below 2**bits: least significant
    digit first, 11 bits a pass (2 passes for a scan's voxel keys, where a comparison sort
    takes log2(N) passes over them)."""
    return radix_pairs(keys, bits)[1]


@nb.njit(cache=True)
def column_extrema3(a):
    """(lo, hi, total) of a C-ordered (N >= 1, 3) array: each column's min and max in one
    pass (scalars in registers), and the sum of all its values -- not finite when a value
    is NaN (or inf), which min and max here would not propagate as numpy's do."""
    l0 = h0 = a[0, 0]
    l1 = h1 = a[0, 1]
    l2 = h2 = a[0, 2]
    total = 0.0
    for i in range(a.shape[0]):
        x = a[i, 0]
        y = a[i, 1]
        z = a[i, 2]
        l0 = min(l0, x)
        h0 = max(h0, x)
        l1 = min(l1, y)
        h1 = max(h1, y)
        l2 = min(l2, z)
        h2 = max(h2, z)
        total += (x + y) + z
    return np.array([l0, l1, l2]), np.array([h0, h1, h2]), total


@nb.njit(cache=True)
def column_sums(a):
    """Column sums of a 2-D array, row after row: numpy's ``a.sum(axis=0)`` of a C-ordered
    array adds in the same order (the same values to the bit), several times slower."""
    out = np.zeros(a.shape[1])
    for i in range(a.shape[0]):
        for j in range(a.shape[1]):
            out[j] += a[i, j]
    return out


@nb.njit(cache=True)
def ball_rows(pts, c0, c1, c2, bound, root):
    """Ascending indices of the rows of ``pts`` within the ball, ``d = pts - c``:
    ``(dx*dx + dy*dy) + dz*dz <= bound`` (the squared distance as the k-d tree adds it, its
    data point minus the query: ``bound`` = r * r), or with ``root``
    ``sqrt((dx*dx + dy*dy) + dz*dz) <= bound`` (numpy's ``np.linalg.norm(pts - c, axis=1)
    <= r``, to the bit)."""
    n = pts.shape[0]
    out = np.empty(n, np.int64)
    k = 0
    # with ``root``: squares clearly inside or outside need no root (its rounding is far
    # below these margins); only those near the bound take it
    inside = -1.0
    outside = np.inf
    if root and 0.0 < bound < 1e150:
        inside = bound * bound * (1.0 - 1e-9)
        outside = bound * bound * (1.0 + 1e-9)
    for i in range(n):
        dx = pts[i, 0] - c0
        dy = pts[i, 1] - c1
        dz = pts[i, 2] - c2
        s = dx * dx + dy * dy + dz * dz
        if root:
            if not s <= inside and (s > outside or not math.sqrt(s) <= bound):  # (NaN: out)
                continue
        elif not s <= bound:
            continue
        out[k] = i
        k += 1
    return out[:k]


@nb.njit(cache=True)
def _plane_grid(pts, lo, h, nx, ny):
    """Counting sort of 2-D points into the nx x ny cells of edge h from ``lo``: (start,
    order), the points of cell c being ``order[start[c]:start[c + 1]]``, ascending."""
    n = pts.shape[0]
    key = np.empty(n, np.int64)
    for i in range(n):
        cx = min(max(int(math.floor((pts[i, 0] - lo[0]) / h)), 0), nx - 1)
        cy = min(max(int(math.floor((pts[i, 1] - lo[1]) / h)), 0), ny - 1)
        key[i] = cx * ny + cy
    return buckets(key, nx * ny)


@nb.njit(cache=True)
def plane_pairs(pts, queries, rr, lo, h, nx, ny, strict, first_only):
    """For each 2-D query, the ``pts`` within it: ``dx*dx + dy*dy <= rr`` (``< rr`` when
    ``strict``), the squared distance as the k-d tree adds it. Returns (lens, flat): the
    matches grouped by query in query order (ascending within a query); with
    ``first_only`` at most one match per query (whether there is one).

    Cells of edge ``h >= sqrt(rr)`` from ``lo``, nx x ny of them, covering ``pts``: a
    match lies in the 3 x 3 cells around the query's (clamped to the grid: a point outside
    the grid's box is in its edge cells, and a query farther than one cell outside matches
    nothing)."""
    start, order = _plane_grid(pts, lo, h, nx, ny)
    nq = queries.shape[0]
    lens = np.zeros(nq, np.int64)
    cap = max(16, 4 * nq)
    flat = np.empty(cap, np.int64)
    k = 0
    for q in range(nq):
        qx = queries[q, 0]
        qy = queries[q, 1]
        fx = math.floor((qx - lo[0]) / h)
        fy = math.floor((qy - lo[1]) / h)
        if fx < -1.0 or fy < -1.0 or fx > nx or fy > ny:
            continue
        cx = int(fx)
        cy = int(fy)
        k0 = k
        for gx in range(max(cx - 1, 0), min(cx + 2, nx)):
            for gy in range(max(cy - 1, 0), min(cy + 2, ny)):
                c = gx * ny + gy
                for e in range(start[c], start[c + 1]):
                    j = order[e]
                    dx = qx - pts[j, 0]
                    dy = qy - pts[j, 1]
                    s = dx * dx + dy * dy
                    if s < rr or (s == rr and not strict):
                        if k == cap:
                            cap *= 2
                            grown = np.empty(cap, np.int64)
                            grown[:k] = flat[:k]
                            flat = grown
                        flat[k] = j
                        k += 1
                        if first_only:
                            break
                if first_only and k > k0:
                    break
            if first_only and k > k0:
                break
        lens[q] = k - k0
        if k - k0 > 1:
            flat[k0:k] = np.sort(flat[k0:k])
    return lens, flat[:k]


@nb.njit(cache=True, parallel=True)
def plane_counts(nrm, off, pts, threshold):
    """(K,) for each plane (unit normal ``nrm[k]``, offset ``off[k]``), how many of ``pts``
    lie within ``threshold`` of it: ``|n . p - off| <= threshold``."""
    k = nrm.shape[0]
    n = pts.shape[0]
    out = np.zeros(k, np.int64)
    for i in nb.prange(k):
        a = nrm[i, 0]
        b = nrm[i, 1]
        c = nrm[i, 2]
        o = off[i]
        cnt = 0
        for j in range(n):
            if abs(a * pts[j, 0] + b * pts[j, 1] + c * pts[j, 2] - o) <= threshold:
                cnt += 1
        out[i] = cnt
    return out


@nb.njit(cache=True)
def neighbour_scatter(points, idx):
    """(P, 6) scatter sums (xx xy xz yy yz zz) of each row's neighbours ``points[idx[p]]``
    about their mean, added as numpy adds ``(c * c).sum(axis=1)`` after ``nb.mean(axis=1)``
    for ``nb = points[idx]``: the mean row after row, each product sum pairwise (in order
    below 8 terms, else 8 running partials combined in a tree, the rest in order)."""
    P, k = idx.shape
    out = np.empty((P, 6))
    c = np.empty((k, 3))
    r = np.empty(8)
    for p in range(P):
        m0 = points[idx[p, 0], 0]
        m1 = points[idx[p, 0], 1]
        m2 = points[idx[p, 0], 2]
        for j in range(1, k):
            q = idx[p, j]
            m0 += points[q, 0]
            m1 += points[q, 1]
            m2 += points[q, 2]
        m0 /= k
        m1 /= k
        m2 /= k
        for j in range(k):
            q = idx[p, j]
            c[j, 0] = points[q, 0] - m0
            c[j, 1] = points[q, 1] - m1
            c[j, 2] = points[q, 2] - m2
        t = 0
        for a in range(3):
            for b in range(a, 3):
                if k < 8:
                    s = c[0, a] * c[0, b]
                    for j in range(1, k):
                        s += c[j, a] * c[j, b]
                else:
                    for j in range(8):
                        r[j] = c[j, a] * c[j, b]
                    i = 8
                    while i < k - (k % 8):
                        for j in range(8):
                            r[j] += c[i + j, a] * c[i + j, b]
                        i += 8
                    s = ((r[0] + r[1]) + (r[2] + r[3])) + ((r[4] + r[5]) + (r[6] + r[7]))
                    while i < k:
                        s += c[i, a] * c[i, b]
                        i += 1
                out[p, t] = s
                t += 1
    return out


@nb.njit(cache=True)
def ring1_cov(indptr, indices, c):
    """(N, 6) covariances (xx xy xz yy yz zz) over each point and its CSR row, as
    ``normals._sparse_cov`` computes them with sparse products: first and second moments of
    ``c`` summed over the row's columns with the point inserted in order, each divided by
    the count, then ``second - mean_a mean_b``; and False (and no result) when a row is
    not strictly ascending or holds its own point."""
    n = c.shape[0]
    out = np.empty((n, 6))
    for i in range(n):
        s0 = s1 = s2 = 0.0
        t0 = t1 = t2 = t3 = t4 = t5 = 0.0
        cnt = 0
        own = False
        e = indptr[i]
        end = indptr[i + 1]
        while e < end or not own:
            if not own and (e == end or i < indices[e]):
                j = i
                own = True
            else:
                j = indices[e]
                e += 1
                if j == i or (e < end and indices[e] <= j):
                    return out, False  # a self entry or a row not sorted: not canonical
            x = c[j, 0]
            y = c[j, 1]
            z = c[j, 2]
            s0 += x
            s1 += y
            s2 += z
            t0 += x * x
            t1 += x * y
            t2 += x * z
            t3 += y * y
            t4 += y * z
            t5 += z * z
            cnt += 1
        m0 = s0 / cnt
        m1 = s1 / cnt
        m2 = s2 / cnt
        out[i, 0] = t0 / cnt - m0 * m0
        out[i, 1] = t1 / cnt - m0 * m1
        out[i, 2] = t2 / cnt - m0 * m2
        out[i, 3] = t3 / cnt - m1 * m1
        out[i, 4] = t4 / cnt - m1 * m2
        out[i, 5] = t5 / cnt - m2 * m2
    return out, True


@nb.njit(cache=True)
def order_statistics(x, k0, k1, nbins):
    """The k0-th and k1-th smallest (0-based, k0 <= k1) of the finite 1-D ``x``: counted into
    ``nbins`` equal bins between the extremes (a monotone map, so ranks stay in order), then
    only the bins holding the two ranks sorted; (nan, nan, False) when those bins hold over
    a quarter of the values (a sort would then cost more than a partition)."""
    n = x.shape[0]
    lo = x[0]
    hi = x[0]
    for i in range(n):
        v = x[i]
        if v < lo:
            lo = v
        if v > hi:
            hi = v
    if lo == hi:
        return lo, hi, True
    scale = nbins / (hi - lo)
    counts = np.zeros(nbins, np.int64)
    for i in range(n):
        b = min(int((x[i] - lo) * scale), nbins - 1)
        counts[b] += 1
    below = 0
    b0 = -1
    b1 = -1
    first0 = 0
    for b in range(nbins):
        if b0 < 0 and below + counts[b] > k0:
            b0 = b
            first0 = below
        if below + counts[b] > k1:
            b1 = b
            break
        below += counts[b]
    m = 0
    for b in range(b0, b1 + 1):
        m += counts[b]
    if 4 * m > n:
        return np.nan, np.nan, False
    sel = np.empty(m)
    j = 0
    for i in range(n):
        b = min(int((x[i] - lo) * scale), nbins - 1)
        if b0 <= b <= b1:
            sel[j] = x[i]
            j += 1
    sel.sort()
    return sel[k0 - first0], sel[k1 - first0], True


@nb.njit(cache=True)
def space_any(pts, queries, rr, lo, h, nx, ny, nz):
    """(Q,) whether some point of ``pts`` lies strictly within the ball of each query:
    ``(dx*dx + dy*dy) + dz*dz < rr`` (the k-d tree's sums; its ``query`` with
    ``distance_upper_bound``). Cells of edge ``h >= sqrt(rr)`` from ``lo``, nx x ny x nz
    of them covering ``pts``: a match lies in the 3 x 3 x 3 cells around the query's."""
    n = pts.shape[0]
    key = np.empty(n, np.int64)
    for i in range(n):
        cx = min(max(int(math.floor((pts[i, 0] - lo[0]) / h)), 0), nx - 1)
        cy = min(max(int(math.floor((pts[i, 1] - lo[1]) / h)), 0), ny - 1)
        cz = min(max(int(math.floor((pts[i, 2] - lo[2]) / h)), 0), nz - 1)
        key[i] = (cx * ny + cy) * nz + cz
    start, order = buckets(key, nx * ny * nz)
    nq = queries.shape[0]
    out = np.zeros(nq, np.bool_)
    for q in range(nq):
        qx = queries[q, 0]
        qy = queries[q, 1]
        qz = queries[q, 2]
        fx = math.floor((qx - lo[0]) / h)
        fy = math.floor((qy - lo[1]) / h)
        fz = math.floor((qz - lo[2]) / h)
        if fx < -1.0 or fy < -1.0 or fz < -1.0 or fx > nx or fy > ny or fz > nz:
            continue
        cx = int(fx)
        cy = int(fy)
        cz = int(fz)
        found = False
        for gx in range(max(cx - 1, 0), min(cx + 2, nx)):
            for gy in range(max(cy - 1, 0), min(cy + 2, ny)):
                for gz in range(max(cz - 1, 0), min(cz + 2, nz)):
                    c = (gx * ny + gy) * nz + gz
                    for e in range(start[c], start[c + 1]):
                        j = order[e]
                        dx = pts[j, 0] - qx
                        dy = pts[j, 1] - qy
                        dz = pts[j, 2] - qz
                        if dx * dx + dy * dy + dz * dz < rr:
                            found = True
                            break
                    if found:
                        break
                if found:
                    break
            if found:
                break
        out[q] = found
    return out


@nb.njit(cache=True)
def smallest_vectors(cov, lam0, q, safe):
    """The unit eigenvectors of the smallest eigenvalues ``lam0`` of N symmetric 3x3
    matrices (``cov`` (N, 6) upper triangles; ``q`` a third of each trace; ``safe`` the
    closed form applies) as ``normals._smallest_eigen`` computes them with numpy: the
    largest of the cross products of two rows of ``C - lam0 I`` (numpy's cross and norm
    arithmetic, the first largest), divided by its length; and the (N,) rows where that is
    degenerate (left to the caller: numpy's eigh)."""
    n = cov.shape[0]
    out = np.empty((n, 3))
    bad = np.zeros(n, np.bool_)
    c = np.empty((3, 3))
    nrm = np.empty(3)
    for i in range(n):
        l0 = lam0[i]
        a00 = cov[i, 0] - l0
        a01 = cov[i, 1]
        a02 = cov[i, 2]
        a11 = cov[i, 3] - l0
        a12 = cov[i, 4]
        a22 = cov[i, 5] - l0
        # rows r0 = (a00, a01, a02), r1 = (a01, a11, a12), r2 = (a02, a12, a22)
        c[0, 0] = a01 * a12 - a02 * a11  # r0 x r1
        c[0, 1] = a02 * a01 - a00 * a12
        c[0, 2] = a00 * a11 - a01 * a01
        c[1, 0] = a01 * a22 - a02 * a12  # r0 x r2
        c[1, 1] = a02 * a02 - a00 * a22
        c[1, 2] = a00 * a12 - a01 * a02
        c[2, 0] = a11 * a22 - a12 * a12  # r1 x r2
        c[2, 1] = a12 * a02 - a01 * a22
        c[2, 2] = a01 * a12 - a11 * a02
        for k in range(3):
            nrm[k] = math.sqrt(c[k, 0] * c[k, 0] + c[k, 1] * c[k, 1] + c[k, 2] * c[k, 2])
        best = 0
        bv = nrm[0]
        if not math.isnan(bv):
            for k in range(1, 3):
                if math.isnan(nrm[k]):
                    best = k
                    break
                if nrm[k] > bv:
                    best = k
                    bv = nrm[k]
        nb_ = nrm[best]
        m = max(abs(l0), abs(q[i]))
        scale = m * m
        b = (not safe[i]) or nb_ <= 1e-10 * max(scale, 1e-300)
        bad[i] = b
        d = 1.0 if b else nb_
        out[i, 0] = c[best, 0] / d
        out[i, 1] = c[best, 1] / d
        out[i, 2] = c[best, 2] / d
    return out, bad


_TWO_THIRDS_PI = 2.0 * np.pi / 3.0  # (numpy's constant in normals.smallest_eigenvalue)


@nb.njit(cache=True, parallel=True)
def smallest_eigenvalues(cov):
    """``(lambda_0, q, safe, variation)`` of N symmetric 3x3 matrices (``cov`` (N, 6) upper
    triangles) as ``normals.smallest_eigenvalue`` computes them with numpy, row by row in
    the same order of operations (``ps ** 3`` is numpy's ``pow``; NaN passes ``clip``)."""
    n = cov.shape[0]
    lam0 = np.empty(n)
    q = np.empty(n)
    safe = np.empty(n, np.bool_)
    curvature = np.empty(n)
    for i in nb.prange(n):
        a00 = cov[i, 0]
        a01 = cov[i, 1]
        a02 = cov[i, 2]
        a11 = cov[i, 3]
        a12 = cov[i, 4]
        a22 = cov[i, 5]
        qi = (a00 + a11 + a22) / 3.0
        p1 = a01 * a01 + a02 * a02 + a12 * a12
        b00 = a00 - qi
        b11 = a11 - qi
        b22 = a22 - qi
        p = math.sqrt((b00 * b00 + b11 * b11 + b22 * b22 + 2.0 * p1) / 6.0)
        ok = p > 1e-300
        ps = p if ok else 1.0
        det = (
            b00 * (b11 * b22 - a12 * a12)
            - a01 * (a01 * b22 - a12 * a02)
            + a02 * (a01 * a12 - b11 * a02)
        ) / math.pow(ps, 3.0)
        half = det / 2.0
        if half < -1.0:
            half = -1.0
        elif half > 1.0:
            half = 1.0
        phi = math.acos(half) / 3.0
        l0 = qi + 2.0 * p * math.cos(phi + _TWO_THIRDS_PI) if ok else qi
        total = 3.0 * qi
        if total > 0:
            curvature[i] = (l0 if not l0 < 0.0 else 0.0) / total
        else:
            curvature[i] = 0.0
        lam0[i] = l0
        q[i] = qi
        safe[i] = ok
    return lam0, q, safe, curvature


@nb.njit(cache=True, parallel=True)
def voxel_keys(points, voxel, shift, lo0, lo1, lo2, s1, s2):
    """(N,) mixed-radix key of each point's cell ``floor(p / voxel + shift)`` relative to the
    lowest cell (lo0, lo1, lo2) of a box (s0, s1, s2) cells wide."""
    n = points.shape[0]
    keys = np.empty(n, np.int64)
    for i in nb.prange(n):
        c0 = math.floor(points[i, 0] / voxel + shift) - lo0
        c1 = math.floor(points[i, 1] / voxel + shift) - lo1
        c2 = math.floor(points[i, 2] / voxel + shift) - lo2
        keys[i] = (c0 * (s1 * s2) + c1 * s2) + c2
    return keys


@nb.njit(cache=True)
def radix_pairs(keys, bits):
    """(sorted keys, order): a stable LSD radix sort of non-negative int64 ``keys`` below
    2**bits, 11 bits a pass, the keys carried along (each pass reads them in sequence)."""
    n = keys.shape[0]
    ka = keys.copy()
    ia = np.arange(n)
    kb = np.empty(n, np.int64)
    ib = np.empty(n, np.int64)
    count = np.empty(2049, np.int64)
    shift = 0
    while shift < bits:
        count[:] = 0
        for i in range(n):
            count[((ka[i] >> shift) & 2047) + 1] += 1
        for d in range(2048):
            count[d + 1] += count[d]
        for i in range(n):
            d = (ka[i] >> shift) & 2047
            p = count[d]
            kb[p] = ka[i]
            ib[p] = ia[i]
            count[d] = p + 1
        ka, kb = kb, ka
        ia, ib = ib, ia
        shift += 11
    return ka, ia


@nb.njit(cache=True)
def voxel_means(points, voxel, shift):
    """(M, 3) centroids of the points in each occupied cube of edge ``voxel``, cells in
    lexicographic order, as ``representation.voxel_average`` computes them with numpy:
    cells ``floor(p / voxel + shift)``, one mixed-radix key per cell, and each centroid's
    sums added in the points' order (``np.bincount``'s), divided by the count; (empty,
    False) when the cells span too much for one int64 key. The lowest and highest cells are
    those of the coordinates' bounds (the cell of a coordinate never decreases with it).

    A scan lists neighbouring points one after another: the runs of consecutive points in
    one cell are sorted by cell (not the points one by one) to number the cells in key
    order, and the sums are then added in one pass over the points in their order (each
    cell's in that order, as before; the points read in sequence, the sums of a 640 x 480
    scan's 19,500 cells held in cache).
    """
    n = points.shape[0]
    mn, mx, _ = column_extrema3(points)
    lo0 = math.floor(mn[0] / voxel + shift)
    lo1 = math.floor(mn[1] / voxel + shift)
    lo2 = math.floor(mn[2] / voxel + shift)
    s0 = math.floor(mx[0] / voxel + shift) - lo0 + 1
    s1 = math.floor(mx[1] / voxel + shift) - lo1 + 1
    s2 = math.floor(mx[2] / voxel + shift) - lo2 + 1
    if float(s0) * float(s1) * float(s2) >= 2.0**62:
        return np.empty((0, 3)), False
    keys = voxel_keys(points, voxel, shift, lo0, lo1, lo2, s1, s2)
    nrun = 1
    for i in range(1, n):
        nrun += keys[i] != keys[i - 1]
    rkey = np.empty(nrun, np.int64)
    rstart = np.empty(nrun + 1, np.int64)
    rkey[0] = keys[0]
    rstart[0] = 0
    r = 1
    for i in range(1, n):
        if keys[i] != keys[i - 1]:
            rkey[r] = keys[i]
            rstart[r] = i
            r += 1
    rstart[nrun] = n
    top = s0 * s1 * s2 - 1
    bits = 1
    while (top >> bits) > 0:
        bits += 1
    skeys, order = radix_pairs(rkey, bits)
    cell = np.empty(nrun, np.int64)  # each run's cell, numbered in key order
    c = 0
    cell[order[0]] = 0
    for t in range(1, nrun):
        c += skeys[t] != skeys[t - 1]
        cell[order[t]] = c
    m = c + 1
    acc = np.zeros((m, 3))
    cnt = np.zeros(m, np.int64)
    for j in range(nrun):  # the points in their order: each cell's sums in that order
        c = cell[j]
        a = rstart[j]
        b = rstart[j + 1]
        if cnt[c] == 0:
            acc[c, 0] = points[a, 0]
            acc[c, 1] = points[a, 1]
            acc[c, 2] = points[a, 2]
            cnt[c] = 1
            a += 1
        x = acc[c, 0]
        y = acc[c, 1]
        z = acc[c, 2]
        for i in range(a, b):
            x += points[i, 0]
            y += points[i, 1]
            z += points[i, 2]
        acc[c, 0] = x
        acc[c, 1] = y
        acc[c, 2] = z
        cnt[c] += b - a
    out = np.empty((m, 3))
    for c in range(m):
        out[c, 0] = acc[c, 0] / cnt[c]
        out[c, 1] = acc[c, 1] / cnt[c]
        out[c, 2] = acc[c, 2] / cnt[c]
    return out, True


@nb.njit(cache=True)
def plane_band(points, normal, offset, threshold):
    """A supporting plane's band over (N, 3) points, as ``verify.find_table`` takes it:
    signed distances ``d = p . n - offset``; the band half-width ``max(threshold, 4 x 1.4826
    x median |d|)`` over the points within 3 thresholds; the (N,) masks of the points within
    the band and of those beyond twice it; and how many of the latter lie on the plane's
    positive side. Returns ``(d, band, inside, off, n_off_positive)``."""
    n = points.shape[0]
    d = np.empty(n)
    near = np.empty(n)
    k = 0
    for i in range(n):
        di = points[i, 0] * normal[0] + points[i, 1] * normal[1] + points[i, 2] * normal[2]
        di -= offset
        d[i] = di
        if abs(di) <= 3.0 * threshold:
            near[k] = abs(di)
            k += 1
    band = threshold
    if k:
        band = max(threshold, 4.0 * 1.4826 * np.median(near[:k]))
    inside = np.empty(n, np.bool_)
    off = np.empty(n, np.bool_)
    positive = 0
    for i in range(n):
        a = abs(d[i])
        inside[i] = a <= band
        off[i] = a > 2.0 * band
        if off[i] and d[i] > 0:
            positive += 1
    return d, band, inside, off, positive


@nb.njit(cache=True)
def footprint_inside(points, inside, off, u, w, spacing):
    """The fraction of the ``off`` points whose projection on (u, w) lies within the
    ``inside`` points' projected bounds shrunk by 5 % of their extent plus two spacings
    (``verify.find_table``'s footprint test); 0 when there is none of either."""
    n = points.shape[0]
    lo0 = np.inf
    lo1 = np.inf
    hi0 = -np.inf
    hi1 = -np.inf
    for i in range(n):
        if inside[i]:
            a = points[i, 0] * u[0] + points[i, 1] * u[1] + points[i, 2] * u[2]
            b = points[i, 0] * w[0] + points[i, 1] * w[1] + points[i, 2] * w[2]
            lo0 = min(lo0, a)
            hi0 = max(hi0, a)
            lo1 = min(lo1, b)
            hi1 = max(hi1, b)
    m0 = 0.05 * (hi0 - lo0) + 2.0 * spacing
    m1 = 0.05 * (hi1 - lo1) + 2.0 * spacing
    count = 0
    total = 0
    for i in range(n):
        if off[i]:
            total += 1
            a = points[i, 0] * u[0] + points[i, 1] * u[1] + points[i, 2] * u[2]
            b = points[i, 0] * w[0] + points[i, 1] * w[1] + points[i, 2] * w[2]
            if lo0 + m0 < a < hi0 - m0 and lo1 + m1 < b < hi1 - m1:
                count += 1
    return count / total if total and np.isfinite(lo0) else 0.0


@nb.njit(cache=True)
def face_support(points, ridx, rstart, cands, triples, n_regions):
    """(C,) for each candidate vertex, the largest over its faces (those below
    ``n_regions``) of the distance to the face's nearest point (face t's points:
    ``points[ridx[rstart[t]:rstart[t + 1]]]``), as ``vertexes.plane_vertexes`` takes it
    face by face: ``sqrt((dx*dx + dy*dy) + dz*dz)`` of the query minus the point, the
    square's minimum rooted, to the bit; inf for a face without points."""
    n = cands.shape[0]
    worst = np.zeros(n)
    for c in range(n):
        w = 0.0
        for s in range(3):
            t = triples[c, s]
            if t >= n_regions:
                continue
            best = np.inf
            for r in range(rstart[t], rstart[t + 1]):
                p = ridx[r]
                dx = cands[c, 0] - points[p, 0]
                dy = cands[c, 1] - points[p, 1]
                dz = cands[c, 2] - points[p, 2]
                sq = (dx * dx + dy * dy) + dz * dz
                if sq < best:
                    best = sq
            w = max(w, math.sqrt(best))
        worst[c] = w
    return worst


@nb.njit(cache=True, inline="always")
def _rank_all(points, q, m, skip_q, best_d2, best_i, d2):
    """Rank all the (N, 3) points into the m best by (squared distance, index) of point q
    (q itself left out with ``skip_q``), the distance ``(dx*dx + dy*dy) + dz*dz`` as the
    grid's rows take it; each square also into ``d2`` when it holds N entries. Returns how
    many are held (at most m)."""
    qx = points[q, 0]
    qy = points[q, 1]
    qz = points[q, 2]
    keep = d2.shape[0] == points.shape[0]
    cnt = 0
    for j in range(points.shape[0]):
        dx = qx - points[j, 0]
        dy = qy - points[j, 1]
        dz = qz - points[j, 2]
        e2 = (dx * dx + dy * dy) + dz * dz
        if keep:
            d2[j] = e2
        if skip_q and j == q:
            continue
        if cnt == m:
            if e2 >= best_d2[m - 1]:  # (an equal square: the later index loses)
                continue
            k = m - 1
        else:
            k = cnt
            cnt += 1
        _insert_ranked(best_d2, best_i, k, e2, j)  # (j ascending: an equal square goes after)
    return cnt


@nb.njit(cache=True)
def brute_knn(points, rows, k):
    """(dist (P, k), idx (P, k)): the k nearest of the (N >= k, 3) points to each of a few
    rows (the row itself included), by (squared distance, index), the distance
    ``sqrt((dx*dx + dy*dy) + dz*dz)`` -- one pass over all the points a row."""
    n_rows = rows.shape[0]
    out_d = np.empty((n_rows, k))
    out_i = np.empty((n_rows, k), np.int64)
    best_d2 = np.empty(k)
    best_i = np.empty(k, np.int64)
    none = np.empty(0)
    for p in range(n_rows):
        _rank_all(points, rows[p], k, False, best_d2, best_i, none)
        for u in range(k):
            out_d[p, u] = math.sqrt(best_d2[u])
            out_i[p, u] = best_i[u]
    return out_d, out_i


@nb.njit(cache=True)
def _brute_row(points, q, m, d2, best_d2, best_i, best_d):
    """The m nearest of the (N > m, 3) points to point q (itself left out) by (distance,
    index), the distance ``sqrt((dx*dx + dy*dy) + dz*dz)`` as the grid's rows take it, into
    ``best_i``/``best_d`` (by squared distance: the caller orders them by index; ``d2``:
    (N,) scratch); False (as the grid gives a row up) when a point left out is as far as
    the m-th (a tie the index would settle among more than m)."""
    n = points.shape[0]
    _rank_all(points, q, m, True, best_d2, best_i, d2)
    # a point left out as far as the m-th: its square at least the largest kept, its sqrt
    # the same (distinct squares may share a sqrt)
    top = best_d2[m - 1]
    d_top = math.sqrt(top)
    hi = top * (1.0 + 1e-15) + 1e-300
    for j in range(n):
        if j != q and top <= d2[j] <= hi and math.sqrt(d2[j]) == d_top:
            kept = False
            for k in range(m):
                if best_i[k] == j:
                    kept = True
            if not kept:
                return False
    for k in range(m):
        best_d[k] = math.sqrt(best_d2[k])
    return True


@nb.njit(cache=True)
def induced_rows(indptr, indices, data, members, points, m):
    """The CSR rows of the SPG of a component (sorted ``members`` of a thresholded SPG
    ``indptr``/``indices``/``data``, their ``points``): a row with ``m`` entries is the
    member's row, columns renumbered (monotonically: they stay ascending); a shorter row
    (cut by the threshold) is the member's ``m`` nearest among ``points`` by brute force,
    in column order. Returns ``(ok, indptr, indices, data)``; ok is False when a cut row
    meets a distance tie it does not settle (the caller takes another way)."""
    n = members.shape[0]
    renumber = np.full(indptr.shape[0] - 1, -1, np.int64)
    for k in range(n):
        renumber[members[k]] = k
    out_ptr = np.zeros(n + 1, np.int64)
    for k in range(n):
        i = members[k]
        ln = indptr[i + 1] - indptr[i]
        out_ptr[k + 1] = out_ptr[k] + (ln if ln >= m else m)
    total = out_ptr[n]
    out_ind = np.empty(total, indices.dtype)
    out_dat = np.empty(total, data.dtype)
    best_d2 = np.empty(m)
    best_i = np.empty(m, np.int64)
    best_d = np.empty(m)
    d2 = np.empty(n)
    for k in range(n):
        i = members[k]
        a = indptr[i]
        ln = indptr[i + 1] - a
        o = out_ptr[k]
        if ln >= m:
            for e in range(ln):
                out_ind[o + e] = renumber[indices[a + e]]
                out_dat[o + e] = data[a + e]
            continue
        if not _brute_row(points, k, m, d2, best_d2, best_i, best_d):
            return False, out_ptr, out_ind, out_dat
        # column order (the m nearest are distinct points: a plain insertion sort)
        for u in range(m):
            v = u
            while v > 0 and best_i[v - 1] > best_i[u]:
                v -= 1
            ci = best_i[u]
            cd = best_d[u]
            for w in range(u, v, -1):
                best_i[w] = best_i[w - 1]
                best_d[w] = best_d[w - 1]
            best_i[v] = ci
            best_d[v] = cd
        for u in range(m):
            out_ind[o + u] = best_i[u]
            out_dat[o + u] = best_d[u]
    return True, out_ptr, out_ind, out_dat


@nb.njit(cache=True)
def _root(parent, a):
    """The root of ``a`` in a union-find forest (path halving)."""
    while parent[a] != a:
        parent[a] = parent[parent[a]]
        a = parent[a]
    return a


@nb.njit(cache=True)
def _join(parent, a, b):
    """Join the trees of ``a`` and ``b``: the larger root under the smaller, so that every
    root is the smallest node of its tree."""
    a = _root(parent, a)
    b = _root(parent, b)
    if a < b:
        parent[b] = a
    elif b < a:
        parent[a] = b


@nb.njit(cache=True)
def _first_node_labels(parent, keep, labels):
    """Label the nodes in ``keep`` by their trees, in the order of each tree's first node
    (its root, labelled before any other of its nodes); returns the count."""
    count = 0
    for i in range(parent.shape[0]):
        if not keep[i]:
            continue
        r = _root(parent, i)
        if r == i:
            labels[i] = count
            count += 1
        else:
            labels[i] = labels[r]
    return count


@nb.njit(cache=True)
def weak_components(indptr, indices, n):
    """(count, (n,) int32 labels) of the weakly connected components of a CSR pattern:
    union-find over the entries, then labels in the order of each component's first node
    (scipy's ``connected_components`` numbers them so: a search from each unlabelled node
    in turn)."""
    parent = np.arange(n)
    for i in range(n):
        for e in range(indptr[i], indptr[i + 1]):
            _join(parent, i, indices[e])
    labels = np.empty(n, np.int32)
    count = _first_node_labels(parent, np.ones(n, np.bool_), labels)
    return count, labels


@nb.njit(cache=True)
def masked_components(indptr, indices, data, keep, limit):
    """(count, (n,) int64 labels, -1 off ``keep``) of the weakly connected components of
    the CSR graph's nodes in ``keep`` over its entries of value <= ``limit`` between two
    such nodes: :func:`weak_components` of that subgraph (the nodes in ``keep`` renumbered
    in order), labels in the order of each component's first node."""
    n = indptr.shape[0] - 1
    parent = np.arange(n)
    for i in range(n):
        if not keep[i]:
            continue
        for e in range(indptr[i], indptr[i + 1]):
            b = indices[e]
            if keep[b] and data[e] <= limit:
                _join(parent, i, b)
    labels = np.full(n, -1, np.int64)
    count = _first_node_labels(parent, keep, labels)
    return count, labels


@nb.njit(cache=True)
def same_label_entries(indptr, indices, data, labels):
    """The CSR arrays (indptr, indices, data) of the entries joining two nodes of one label,
    each row's kept entries in their order."""
    n = indptr.shape[0] - 1
    out_ptr = np.zeros(n + 1, np.int64)
    out_ind = np.empty(indices.shape[0], indices.dtype)
    out_dat = np.empty(data.shape[0], data.dtype)
    o = 0
    for i in range(n):
        li = labels[i]
        for e in range(indptr[i], indptr[i + 1]):
            j = indices[e]
            if labels[j] == li:
                out_ind[o] = j
                out_dat[o] = data[e]
                o += 1
        out_ptr[i + 1] = o
    return out_ptr, out_ind[:o].copy(), out_dat[:o].copy()
