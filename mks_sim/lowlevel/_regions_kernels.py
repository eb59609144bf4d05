"""The compiled region growing of :func:`mks_sim.lowlevel.regions.grow_planar_regions` and the
multi-ring neighbourhood moments of :mod:`mks_sim.lowlevel.normals`.

Imported only when numba is used (``regions._grow(..., compiled=False)`` is the numpy loop
the tests compare the kernel with). Module-level, ``cache=True``: the first use on a machine
compiles (seconds), later processes load the machine code from ``__pycache__``.
"""

from __future__ import annotations

import numba as nb
import numpy as np


@nb.njit(cache=True)
def _scatter(
    points: np.ndarray, sel: np.ndarray, count: int
) -> tuple[float, float, float, float, float, float, float, float, float]:  # pragma: no cover
    """Centroid (3 values) and scatter matrix (upper triangle xx xy xz yy yz zz, sums of
    squared deviations, not divided) of ``points[sel[:count]]``, in two passes (the
    moments do not cancel catastrophically)."""
    m0 = 0.0
    m1 = 0.0
    m2 = 0.0
    for k in range(count):
        q = sel[k]
        m0 += points[q, 0]
        m1 += points[q, 1]
        m2 += points[q, 2]
    m0 /= count
    m1 /= count
    m2 /= count
    a00 = 0.0
    a01 = 0.0
    a02 = 0.0
    a11 = 0.0
    a12 = 0.0
    a22 = 0.0
    for k in range(count):
        q = sel[k]
        d0 = points[q, 0] - m0
        d1 = points[q, 1] - m1
        d2 = points[q, 2] - m2
        a00 += d0 * d0
        a01 += d0 * d1
        a02 += d0 * d2
        a11 += d1 * d1
        a12 += d1 * d2
        a22 += d2 * d2
    return m0, m1, m2, a00, a01, a02, a11, a12, a22


@nb.njit(cache=True)
def grow_regions(
    indptr: np.ndarray,
    indices: np.ndarray,
    points: np.ndarray,
    normals: np.ndarray,
    allowed: np.ndarray,
    order: np.ndarray,
    cos_tol: float,
    distance: float,
) -> tuple[np.ndarray, int]:  # pragma: no cover - compiled
    """Breadth-first planar region growing from the seeds in ``order`` (see ``regions._grow``).

    Returns:
        ``(labels, count)``: (N,) region of each point in seed order (-1: none), regions.
    """
    n = points.shape[0]
    labels = np.full(n, -1, np.int64)
    members = np.empty(n, np.int64)
    frontier = np.empty(n, np.int64)
    nxt = np.empty(n, np.int64)
    cand = np.empty(n, np.int64)
    mark = np.zeros(n, np.bool_)
    rid = 0
    for s in order:
        if labels[s] != -1 or not allowed[s]:
            continue
        labels[s] = rid
        members[0] = s
        size = 1
        refit_at = 8
        n0, n1, n2 = normals[s, 0], normals[s, 1], normals[s, 2]
        o0, o1, o2 = points[s, 0], points[s, 1], points[s, 2]
        frontier[0] = s
        nf = 1
        while nf > 0:
            nc = 0
            for f in range(nf):
                p = frontier[f]
                for e in range(indptr[p], indptr[p + 1]):
                    q = indices[e]
                    if labels[q] == -1 and not mark[q]:
                        mark[q] = True
                        cand[nc] = q
                        nc += 1
            if nc == 0:
                break
            sel = np.sort(cand[:nc])
            nn = 0
            for q in sel:
                mark[q] = False
                dn = abs(normals[q, 0] * n0 + normals[q, 1] * n1 + normals[q, 2] * n2)
                dp = abs(
                    (points[q, 0] - o0) * n0 + (points[q, 1] - o1) * n1 + (points[q, 2] - o2) * n2
                )
                if dn >= cos_tol and dp <= distance:
                    labels[q] = rid
                    nxt[nn] = q
                    members[size + nn] = q
                    nn += 1
            size += nn
            for f in range(nn):
                frontier[f] = nxt[f]
            nf = nn
            if nn > 0 and size >= refit_at:
                # the least-squares plane of the members: centroid, smallest principal axis
                c0, c1, c2, a00, a01, a02, a11, a12, a22 = _scatter(points, members, size)
                cov = np.array([[a00, a01, a02], [a01, a11, a12], [a02, a12, a22]])
                _, vec = np.linalg.eigh(cov)
                n0, n1, n2 = vec[0, 0], vec[1, 0], vec[2, 0]
                o0, o1, o2 = c0, c1, c2
                refit_at = 2 * size
        rid += 1
    return labels, rid


@nb.njit(cache=True)
def robust_plane(
    points: np.ndarray, iterations: int
) -> tuple[np.ndarray, float, float]:  # pragma: no cover
    """:func:`mks_sim.lowlevel.regions.fit_plane` in one compiled call: the least-squares
    plane of the kept points, then the points within 3 robust sigmas (1.4826 x the median
    residual) kept, until the kept set stops changing, ``iterations`` fits at most. The
    same steps; the sums' order and the eigen-solver's rounding may differ from numpy's.
    Returns ``(normal, offset, rms residual of the kept points)``."""
    n = points.shape[0]
    keep = np.empty(n, np.int64)
    for i in range(n):
        keep[i] = i
    count = n
    normal = np.array([0.0, 0.0, 1.0])
    offset = 0.0
    r = np.empty(n)
    buf = np.empty(n)
    new = np.empty(n, np.int64)
    for _ in range(max(1, iterations)):
        c0, c1, c2, a00, a01, a02, a11, a12, a22 = _scatter(points, keep, count)
        cov = np.array([[a00, a01, a02], [a01, a11, a12], [a02, a12, a22]])
        _, vec = np.linalg.eigh(cov)
        normal = np.array([vec[0, 0], vec[1, 0], vec[2, 0]])
        offset = normal[0] * c0 + normal[1] * c1 + normal[2] * c2
        for i in range(n):
            r[i] = abs(
                points[i, 0] * normal[0]
                + points[i, 1] * normal[1]
                + points[i, 2] * normal[2]
                - offset
            )
        for k in range(count):
            buf[k] = r[keep[k]]
        limit = max(3.0 * (1.4826 * np.median(buf[:count])), 1e-12)
        m = 0
        same = True
        for i in range(n):
            if r[i] <= limit:
                if m >= count or keep[m] != i:
                    same = False
                new[m] = i
                m += 1
        if m != count:
            same = False
        if m < 3 or same:
            break
        keep[:m] = new[:m]
        count = m
    ss = 0.0
    for k in range(count):
        q = keep[k]
        e = points[q, 0] * normal[0] + points[q, 1] * normal[1] + points[q, 2] * normal[2] - offset
        ss += e * e
    return normal, offset, np.sqrt(ss / count)


#: Fewest points per work item of :func:`ring_moments`; there are at most 4 items per
#: thread, each with its own (N,) scratch arrays.
_RING_CHUNK = 512


@nb.njit(cache=True, parallel=True)
def ring_moments(
    indptr: np.ndarray, indices: np.ndarray, c: np.ndarray, rings: int, threads: int = 1
) -> np.ndarray:  # pragma: no cover - compiled
    """(N, 6) covariances (xx xy xz yy yz zz) of every point's neighbourhood of ``rings`` hops
    over the CSR graph (``indptr``, ``indices``; the point itself included), from the
    (centred) points ``c``; the compiled twin of ``normals._pca_sparse(_ring_matrix(...))``.

    Up to 4 x ``threads`` chunks of points (a multiple of ``threads`` when there are more
    chunks than threads) run in parallel (as the SPG's grid kernel does);
    each point's breadth-first ring and sums are the same arithmetic whichever thread runs
    it, so the result does not depend on the number of threads."""
    n = c.shape[0]
    out = np.empty((n, 6))
    nchunk = max(1, min((n + _RING_CHUNK - 1) // _RING_CHUNK, 4 * max(threads, 1)))
    if nchunk > threads > 0:
        # a multiple of the threads: 5 chunks of a 2,429-point segment on 2 threads ran
        # 3 + 2 (1.51 ms); 4 run 2 + 2 (1.24 ms)
        nchunk -= nchunk % threads
    size = (n + nchunk - 1) // nchunk
    for ch in nb.prange(nchunk):
        stamp = np.full(n, -1, np.int64)
        ring = np.empty(n + 1, np.int64)  # (+1: the slot past a full ring)
        for i in range(ch * size, min(n, (ch + 1) * size)):
            stamp[i] = i
            ring[0] = i
            lo = 0
            hi = 1
            for _ in range(rings):
                end = hi
                for k in range(lo, end):
                    p = ring[k]
                    for e in range(indptr[p], indptr[p + 1]):
                        # without a branch (a visited q is written past the end and not
                        # counted): 3 in 4 of a second ring's visits meet a point already
                        # in it, unpredictably (the object points' 2-ring moments, 2
                        # threads: 1.59 -> 1.27 ms alone; in place within the noise)
                        q = indices[e]
                        ring[hi] = q
                        hi += stamp[q] != i
                        stamp[q] = i
                lo = end
            _, _, _, a00, a01, a02, a11, a12, a22 = _scatter(c, ring, hi)
            out[i, 0] = a00 / hi
            out[i, 1] = a01 / hi
            out[i, 2] = a02 / hi
            out[i, 3] = a11 / hi
            out[i, 4] = a12 / hi
            out[i, 5] = a22 / hi
    return out


@nb.njit(cache=True)
def absorb_boundary(
    indptr: np.ndarray,
    indices: np.ndarray,
    points: np.ndarray,
    labels: np.ndarray,
    normals: np.ndarray,
    offsets: np.ndarray,
    distance: float,
    passes: int,
) -> None:  # pragma: no cover - compiled
    """The compiled twin of ``regions._absorb_boundary`` (in place): per pass, each
    unlabelled point takes the label of the plane, among its labelled SPG neighbours'
    (row order; the first on ties), it lies nearest to, when within ``distance``; a pass
    reads the labels as they were before it."""
    n = labels.shape[0]
    new = labels.copy()
    for _ in range(passes):
        changed = False
        for i in range(n):
            if labels[i] >= 0:
                continue
            best = np.inf
            choice = -1
            for e in range(indptr[i], indptr[i + 1]):
                lab = labels[indices[e]]
                if lab < 0:
                    continue
                d = abs(
                    points[i, 0] * normals[lab, 0]
                    + points[i, 1] * normals[lab, 1]
                    + points[i, 2] * normals[lab, 2]
                    - offsets[lab]
                )
                if d < best:
                    best = d
                    choice = lab
            if choice >= 0 and best <= distance:
                new[i] = choice
                changed = True
        if not changed:
            return
        for i in range(n):
            labels[i] = new[i]


@nb.njit(cache=True)
def sphere_lm(pts: np.ndarray, x0: np.ndarray) -> tuple[np.ndarray, float]:  # pragma: no cover
    """The Levenberg-Marquardt refinement of :func:`mks_sim.lowlevel.regions.fit_sphere`
    (centre and radius ``x0`` to the minimum of the radial residuals ``|p - c| - r``), the
    same steps in one compiled call: the Jacobian's normal equations summed row by row
    (numpy's products sum in their own order: the last bits may differ). Returns (x, rmse)."""
    n = pts.shape[0]
    x = x0.copy()
    d = np.empty((n, 3))
    length = np.empty(n)
    res = np.empty(n)
    d_new = np.empty((n, 3))
    length_new = np.empty(n)
    res_new = np.empty(n)
    cost = 0.0
    for i in range(n):
        for a in range(3):
            d[i, a] = pts[i, a] - x[a]
        length[i] = np.sqrt(d[i, 0] * d[i, 0] + d[i, 1] * d[i, 1] + d[i, 2] * d[i, 2])
        res[i] = length[i] - x[3]
        cost += res[i] * res[i]
    damping = 1e-3
    JtJ = np.empty((4, 4))
    Jtr = np.empty(4)
    A = np.empty((4, 4))
    j = np.empty(4)
    for _ in range(100):
        JtJ[:] = 0.0
        Jtr[:] = 0.0
        for i in range(n):
            inv = 1.0 / max(length[i], 1e-300)
            j[0] = -d[i, 0] * inv
            j[1] = -d[i, 1] * inv
            j[2] = -d[i, 2] * inv
            j[3] = -1.0
            for a in range(4):
                Jtr[a] += j[a] * res[i]
                for b in range(4):
                    JtJ[a, b] += j[a] * j[b]
        improved = False
        step = np.zeros(4)
        cost_new = cost
        while damping < 1e12:
            for a in range(4):
                for b in range(4):
                    A[a, b] = JtJ[a, b]
                A[a, a] += damping * (JtJ[a, a] + 1e-300)
            step[:] = np.linalg.solve(A, -Jtr)
            cost_new = 0.0
            for i in range(n):
                for a in range(3):
                    d_new[i, a] = pts[i, a] - (x[a] + step[a])
                length_new[i] = np.sqrt(
                    d_new[i, 0] * d_new[i, 0]
                    + d_new[i, 1] * d_new[i, 1]
                    + d_new[i, 2] * d_new[i, 2]
                )
                res_new[i] = length_new[i] - (x[3] + step[3])
                cost_new += res_new[i] * res_new[i]
            if cost_new <= cost:
                improved = True
                break
            damping *= 10.0
        if not improved:
            break
        x_norm = np.sqrt(x[0] * x[0] + x[1] * x[1] + x[2] * x[2] + x[3] * x[3])
        s_norm = np.sqrt(step[0] ** 2 + step[1] ** 2 + step[2] ** 2 + step[3] ** 2)
        converged = cost - cost_new <= 1e-10 * max(cost, 1e-300) or s_norm <= 1e-10 * (
            x_norm + 1e-12
        )
        for a in range(4):
            x[a] += step[a]
        d, d_new = d_new, d
        length, length_new = length_new, length
        res, res_new = res_new, res
        cost = cost_new
        damping = max(damping / 10.0, 1e-12)
        if converged:
            break
    return x, np.sqrt(cost / n)
