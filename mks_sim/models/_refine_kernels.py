"""The compiled normal equations of one point-to-plane ICP iteration
(:func:`mks_sim.models.refine.icp_point_to_plane`).

Imported only when numba is used (``icp_point_to_plane(..., compiled=False)`` is the numpy
path the tests compare this with). One pass over the correspondences instead of a dozen
numpy calls, each of which costs more than its arithmetic at a few hundred points.
Module-level, ``cache=True``: the first use on a machine compiles, later processes load the
machine code from ``__pycache__``.
"""

from __future__ import annotations

import numba as nb
import numpy as np


@nb.njit(cache=True)
def point_to_plane_system(
    p: np.ndarray,
    dist: np.ndarray,
    j: np.ndarray,
    normals: np.ndarray,
    offsets: np.ndarray,
    trim: float,
) -> tuple[np.ndarray, np.ndarray, float, int]:  # pragma: no cover
    """``H = A^T A``, ``g = A^T r``, the sum of squared residuals and the pairs used, over
    the pairs (``p[i]``, model sample ``j[i]``) with a finite ``dist[i]`` and, when ``trim``
    < 1 and more than 10 are finite, ``dist[i]`` at most the ``trim`` quantile of them (the
    numpy path's ``np.partition`` rank). Rows of A: ``[p x n, n]``; residual ``p . n -
    offset``. Fewer than 6 finite pairs: zeros and the count."""
    n = len(p)
    h = np.zeros((6, 6))
    g = np.zeros(6)
    n_ok = 0
    for i in range(n):
        if dist[i] < np.inf:
            n_ok += 1
    if n_ok < 6:
        return h, g, 0.0, n_ok
    thr = np.inf
    if trim < 1.0 and n_ok > 10:
        d_ok = np.empty(n_ok)
        k = 0
        for i in range(n):
            if dist[i] < np.inf:
                d_ok[k] = dist[i]
                k += 1
        kth = int(trim * (n_ok - 1))
        thr = np.partition(d_ok, kth)[kth]
    a = np.empty(6)
    ss = 0.0
    used = 0
    for i in range(n):
        d = dist[i]
        if not (d < np.inf and d <= thr):
            continue
        q = j[i]
        nx = normals[q, 0]
        ny = normals[q, 1]
        nz = normals[q, 2]
        px = p[i, 0]
        py = p[i, 1]
        pz = p[i, 2]
        r = px * nx + py * ny + pz * nz - offsets[q]
        a[0] = py * nz - pz * ny
        a[1] = pz * nx - px * nz
        a[2] = px * ny - py * nx
        a[3] = nx
        a[4] = ny
        a[5] = nz
        for u in range(6):
            g[u] += a[u] * r
            for v in range(u, 6):
                h[u, v] += a[u] * a[v]
        ss += r * r
        used += 1
    for u in range(6):
        for v in range(u):
            h[u, v] = h[v, u]
    return h, g, ss, used


@nb.njit(cache=True)
def lookup_nearest(
    p: np.ndarray,
    origin: np.ndarray,
    cell: float,
    shape: np.ndarray,
    index: np.ndarray,
    points: np.ndarray,
    max_distance: float,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:  # pragma: no cover
    """The compiled :meth:`mks_sim.models.refine.NearestLookup.query` over the grid:
    ``(distance, index, outside)``: per query the sample of its cell (rounded to the nearest
    cell centre), the exact distance to it, a miss (inf, ``len(points)``) at or beyond
    ``max_distance``; ``outside`` marks the queries off the grid (misses here)."""
    n = p.shape[0]
    miss = points.shape[0]
    d = np.full(n, np.inf)
    j = np.full(n, miss, np.int64)
    outside = np.zeros(n, np.bool_)
    nx, ny, nz = shape[0], shape[1], shape[2]
    for i in range(n):
        cx = int(np.rint((p[i, 0] - origin[0]) / cell))
        cy = int(np.rint((p[i, 1] - origin[1]) / cell))
        cz = int(np.rint((p[i, 2] - origin[2]) / cell))
        if cx < 0 or cx >= nx or cy < 0 or cy >= ny or cz < 0 or cz >= nz:
            outside[i] = True
            continue
        q = index[(cx * ny + cy) * nz + cz]
        dx = p[i, 0] - points[q, 0]
        dy = p[i, 1] - points[q, 1]
        dz = p[i, 2] - points[q, 2]
        di = np.sqrt(dx * dx + dy * dy + dz * dz)
        if di < max_distance:
            d[i] = di
            j[i] = q
    return d, j, outside


@nb.njit(cache=True)
def lookup_inlier_counts(
    scene: np.ndarray,
    T: np.ndarray,
    origin: np.ndarray,
    cell: float,
    shape: np.ndarray,
    index: np.ndarray,
    points: np.ndarray,
    normals: np.ndarray,
    max_distance: float,
    inlier: float,
) -> np.ndarray:  # pragma: no cover
    """(K,) inlier counts of the scene points under K poses: each point moved into the
    model frame (``R^T (p - t)``), its sample looked up on the grid (as
    :func:`lookup_nearest`: a miss off the grid or at ``max_distance``), an inlier when its
    point-to-plane distance to that sample is at most ``inlier``. (The caller makes sure no
    query off the grid could have a sample within ``max_distance``.)"""
    k_poses = T.shape[0]
    n = scene.shape[0]
    nx, ny, nz = shape[0], shape[1], shape[2]
    out = np.zeros(k_poses, np.int64)
    for k in range(k_poses):
        count = 0
        for i in range(n):
            dx0 = scene[i, 0] - T[k, 0, 3]
            dx1 = scene[i, 1] - T[k, 1, 3]
            dx2 = scene[i, 2] - T[k, 2, 3]
            px = dx0 * T[k, 0, 0] + dx1 * T[k, 1, 0] + dx2 * T[k, 2, 0]
            py = dx0 * T[k, 0, 1] + dx1 * T[k, 1, 1] + dx2 * T[k, 2, 1]
            pz = dx0 * T[k, 0, 2] + dx1 * T[k, 1, 2] + dx2 * T[k, 2, 2]
            cx = int(np.rint((px - origin[0]) / cell))
            cy = int(np.rint((py - origin[1]) / cell))
            cz = int(np.rint((pz - origin[2]) / cell))
            if cx < 0 or cx >= nx or cy < 0 or cy >= ny or cz < 0 or cz >= nz:
                continue
            q = index[(cx * ny + cy) * nz + cz]
            ex = px - points[q, 0]
            ey = py - points[q, 1]
            ez = pz - points[q, 2]
            if not np.sqrt(ex * ex + ey * ey + ez * ez) < max_distance:
                continue
            if abs(ex * normals[q, 0] + ey * normals[q, 1] + ez * normals[q, 2]) <= inlier:
                count += 1
        out[k] = count
    return out


@nb.njit(cache=True)
def first_representatives(same: np.ndarray) -> np.ndarray:  # pragma: no cover
    """(H,) labels of H poses, best first: pose i joins the first earlier representative
    ``j`` with ``same[j, i]``, else it is a representative itself (label i) --
    :func:`mks_sim.models.refine.group_equivalent`'s rule, in one compiled pass."""
    h = same.shape[0]
    labels = np.arange(h)
    is_rep = np.zeros(h, np.bool_)
    for i in range(h):
        for j in range(i):
            if is_rep[j] and same[j, i]:
                labels[i] = j
                break
        else:
            is_rep[i] = True
    return labels


@nb.njit(cache=True)
def icp_lookup_loop(
    scene: np.ndarray,
    scene_to_model: np.ndarray,
    origin: np.ndarray,
    cell: float,
    shape: np.ndarray,
    index: np.ndarray,
    points: np.ndarray,
    normals: np.ndarray,
    offsets: np.ndarray,
    max_distance: float,
    trim: float,
    max_iterations: int,
    tolerance: float,
    size: float,
    stall: int,
    stall_gain: float,
    cycle_max_step: float,
    cycle_cosine: float,
) -> tuple[np.ndarray, float, int, bool]:  # pragma: no cover
    """The iterations of :func:`mks_sim.models.refine.icp_point_to_plane` (6 degrees of
    freedom) in one compiled call, correspondences from the lookup grid: the same steps
    (trim, linearised point-to-plane solve, two-cycle halving, tolerance, stall; ``stall``
    0: none), the rounding of the transforms and the solve may differ. Returns
    ``(scene_to_model, rmse, iterations, converged)``."""
    n = scene.shape[0]
    S = scene_to_model.copy()
    p = np.empty((n, 3))
    dist = np.empty(n)
    jj = np.empty(n, np.int64)
    step = np.zeros(6)
    history = np.empty(max_iterations)
    n_hist = 0
    rmse = np.inf
    converged = False
    it = 0
    miss = points.shape[0]
    nx, ny, nz = shape[0], shape[1], shape[2]
    for it in range(1, max_iterations + 1):  # noqa: B007 - returned
        for i in range(n):
            x = scene[i, 0]
            y = scene[i, 1]
            z = scene[i, 2]
            px = S[0, 0] * x + S[0, 1] * y + S[0, 2] * z + S[0, 3]
            py = S[1, 0] * x + S[1, 1] * y + S[1, 2] * z + S[1, 3]
            pz = S[2, 0] * x + S[2, 1] * y + S[2, 2] * z + S[2, 3]
            p[i, 0] = px
            p[i, 1] = py
            p[i, 2] = pz
            dist[i] = np.inf
            jj[i] = miss
            cx = int(np.rint((px - origin[0]) / cell))
            cy = int(np.rint((py - origin[1]) / cell))
            cz = int(np.rint((pz - origin[2]) / cell))
            if cx < 0 or cx >= nx or cy < 0 or cy >= ny or cz < 0 or cz >= nz:
                continue
            q = index[(cx * ny + cy) * nz + cz]
            dx = px - points[q, 0]
            dy = py - points[q, 1]
            dz = pz - points[q, 2]
            di = np.sqrt(dx * dx + dy * dy + dz * dz)
            if di < max_distance:
                dist[i] = di
                jj[i] = q
        H, g, ss, used = point_to_plane_system(p, dist, jj, normals, offsets, trim)
        if used < 6:
            break
        rmse = np.sqrt(ss / used)
        for u in range(6):
            H[u, u] += 1e-9
        x6 = np.linalg.solve(H, -g)
        scaled = np.empty(6)
        for u in range(3):
            scaled[u] = x6[u]
            scaled[u + 3] = x6[u + 3] / size
        norm = np.sqrt(np.sum(scaled * scaled))
        last = np.sqrt(np.sum(step * step))
        cycle = (
            norm < cycle_max_step
            and 0.7 * last < norm < 1.4 * last
            and np.sum(scaled * step) < -cycle_cosine * norm * last
        )
        if cycle:
            x6 = 0.5 * x6
        step = scaled
        # dT = [Rodrigues(omega), t]; S = dT @ S
        theta = np.sqrt(x6[0] * x6[0] + x6[1] * x6[1] + x6[2] * x6[2])
        R = np.eye(3)
        if theta >= 1e-12:
            k0 = x6[0] / theta
            k1 = x6[1] / theta
            k2 = x6[2] / theta
            K = np.array([[0.0, -k2, k1], [k2, 0.0, -k0], [-k1, k0, 0.0]])
            R = np.eye(3) + np.sin(theta) * K + (1.0 - np.cos(theta)) * (K @ K)
        dT = np.eye(4)
        dT[:3, :3] = R
        dT[0, 3] = x6[3]
        dT[1, 3] = x6[4]
        dT[2, 3] = x6[5]
        S = dT @ S
        trans = np.sqrt(x6[3] * x6[3] + x6[4] * x6[4] + x6[5] * x6[5])
        if cycle or theta + trans / size < tolerance:
            converged = True
            break
        history[n_hist] = rmse
        n_hist += 1
        if stall > 0 and n_hist > stall:
            if rmse > (1.0 - stall_gain) * history[n_hist - 1 - stall]:
                break
    return S, rmse, it, converged
