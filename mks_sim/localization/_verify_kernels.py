"""The compiled scene-consistency check of :func:`mks_sim.localization.verify.consistency`.

Imported only when numba is used (``consistency(..., compiled=False)`` is the numpy path the
tests compare the kernel with). Module-level, ``cache=True``: the first use on a machine
compiles (seconds), later processes load the machine code from ``__pycache__``.
"""

from __future__ import annotations

import math

import numba as nb
import numpy as np

from mks_sim.lowlevel._gridknn_kernels import _plane_grid


@nb.njit(cache=True)
def _grid2(xy, h):  # pragma: no cover
    """A 2-D bucket grid of ``xy`` with cells of edge at least ``h`` (wider when that would
    make over about 4 cells a point, as :func:`mks_sim.lowlevel._gridknn.plane_pairs`
    sizes its grid): (lo, h, nx, ny, start, order) with the points of cell (i, j) at
    ``order[start[i * ny + j]:start[i * ny + j + 1]]`` (``_plane_grid``'s counting sort)."""
    n = xy.shape[0]
    lo = np.full(2, np.inf)
    hi = np.full(2, -np.inf)
    for i in range(n):
        for a in range(2):
            lo[a] = min(lo[a], xy[i, a])
            hi[a] = max(hi[a], xy[i, a])
    cells = 4.0 * n + 16.0
    ext0 = hi[0] - lo[0]
    ext1 = hi[1] - lo[1]
    h = max(h, math.sqrt(ext0 * ext1 / cells), max(ext0, ext1) / cells)
    nx = int(ext0 / h) + 1
    ny = int(ext1 / h) + 1
    start, order = _plane_grid(xy, lo, h, nx, ny)
    return lo, h, nx, ny, start, order


@nb.njit(cache=True)
def posed_samples(R, t, S, Nm, vps, facing_cos, has_table, tn, toff, d):  # pragma: no cover
    """The model's samples posed (``S R^T + t``), which of them the sensors can see (normal
    not steeply down, facing a viewpoint within ``facing_cos`` when viewpoints are given),
    their centroid and the radius of their bounding ball about it, the fraction more than
    ``d`` under the table and the lowest height over it: (P, seen, centre, radius,
    penetration, lowest)."""
    M = S.shape[0]
    P = np.empty((M, 3))
    seen = np.empty(M, np.bool_)
    K = vps.shape[0]
    for i in range(M):
        for a in range(3):
            P[i, a] = R[a, 0] * S[i, 0] + R[a, 1] * S[i, 1] + R[a, 2] * S[i, 2] + t[a]
        n0 = R[0, 0] * Nm[i, 0] + R[0, 1] * Nm[i, 1] + R[0, 2] * Nm[i, 2]
        n1 = R[1, 0] * Nm[i, 0] + R[1, 1] * Nm[i, 1] + R[1, 2] * Nm[i, 2]
        n2 = R[2, 0] * Nm[i, 0] + R[2, 1] * Nm[i, 1] + R[2, 2] * Nm[i, 2]
        ok = n2 > -0.3
        if ok and K > 0:
            facing = -np.inf
            for k in range(K):
                r0 = vps[k, 0] - P[i, 0]
                r1 = vps[k, 1] - P[i, 1]
                r2 = vps[k, 2] - P[i, 2]
                cos = (n0 * r0 + n1 * r1 + n2 * r2) / max(
                    math.sqrt(r0 * r0 + r1 * r1 + r2 * r2), 1e-12
                )
                facing = max(facing, cos)
            ok = facing > facing_cos
        seen[i] = ok
    centre = np.zeros(3)
    for i in range(M):
        for a in range(3):
            centre[a] += P[i, a]
    for a in range(3):
        centre[a] /= M
    r2max = 0.0
    for i in range(M):
        e0 = P[i, 0] - centre[0]
        e1 = P[i, 1] - centre[1]
        e2 = P[i, 2] - centre[2]
        r2max = max(r2max, e0 * e0 + e1 * e1 + e2 * e2)
    penetration = 0.0
    lowest = np.inf
    if has_table:
        under = 0
        for i in range(M):
            dist = P[i, 0] * tn[0] + P[i, 1] * tn[1] + P[i, 2] * tn[2] - toff
            lowest = min(lowest, dist)
            if dist < -d:
                under += 1
        penetration = under / M
    return P, seen, centre, math.sqrt(r2max), penetration, lowest


@nb.njit(cache=True)
def consistency_counts(
    P,  # (M, 3) posed samples (posed_samples)
    seen,  # (M,) which the sensors can see
    S,  # (M, 3) the samples, model frame
    Nm,  # (M, 3) their normals, model frame
    cloud,  # (N, 3) sensed points (world)
    near,  # (n,) rows of cloud in the posed model's bounding ball
    q,  # (n, 3) those points in the model frame
    dist,  # (n,) distance of each to its nearest sample (the lookup's or the tree's)
    idx,  # (n,) that sample
    seen_near,  # (n,) a seen sample lies within d (asked where the nearest is not seen)
    has_table,
    tn,  # (3,) table normal (towards the objects)
    toff,  # table offset
    resting,  # the posed model rests on the table (its lowest sample within d of it)
    d,
    elsewhere,  # (N,) bool, or (0,): points another object explains
    reach,
    dirs8,  # (8, 2)
):  # pragma: no cover
    """(explained, inside, below, unexplained) of the sensed points near the posed model,
    the steps of the numpy check (see :func:`mks_sim.localization.verify.consistency`):
    explained (within ``d`` of a seen sample), inside, and, for the rest, under the model
    in their vertical column unless an oblique line of sight opens under a model resting
    on the table; the loose points off the table. The (x, y) searches by a bucket grid of
    the samples, the k-d tree's distance rules; products summed in their own order: a
    count can differ from numpy's only for a point within a few units in the last place of
    a threshold."""
    M = S.shape[0]
    nn = near.shape[0]
    explained_n = 0
    inside_n = 0
    rest = np.empty(nn, np.int64)  # rows of near: neither explained, inside nor on the surface
    n_rest = 0
    loose = np.empty(nn, np.int64)  # cloud rows not explained: loose unless on the table
    n_loose = 0
    zq_min = np.inf
    for k in range(nn):
        j = near[k]
        i0 = idx[k]
        close = dist[k] <= d
        # a point whose nearest sample faces away may still have a seen one within d
        explained = close and (seen[i0] or seen_near[k])
        if explained:
            explained_n += 1
            continue
        if close:  # on the surface (a face turned from the sensors): not inside, not below
            loose[n_loose] = j
            n_loose += 1
            continue
        sd = (
            (q[k, 0] - S[i0, 0]) * Nm[i0, 0]
            + (q[k, 1] - S[i0, 1]) * Nm[i0, 1]
            + (q[k, 2] - S[i0, 2]) * Nm[i0, 2]
        )
        if sd < -d:
            inside_n += 1
            continue
        rest[n_rest] = k
        n_rest += 1
        zq_min = min(zq_min, cloud[j, 2])
    # under the model in their vertical column: at least two samples within d/2 in (x, y)
    # more than 2d above the point
    below = np.zeros(n_rest, np.bool_)
    if n_rest > 0:
        n_high = 0
        for i in range(M):
            if P[i, 2] > zq_min - d:
                n_high += 1
        if n_high >= 2:
            high = np.empty(n_high, np.int64)
            xy = np.empty((n_high, 2))
            m = 0
            for i in range(M):
                if P[i, 2] > zq_min - d:
                    high[m] = i
                    xy[m, 0] = P[i, 0]
                    xy[m, 1] = P[i, 1]
                    m += 1
            r_pair = 0.5 * d
            r_probe = 2.0 * reach
            lo, h, gx, gy, start, order = _grid2(xy, max(r_pair, r_probe) * (1.0 + 1e-9))
            rr_pair = r_pair * r_pair
            rr_probe = r_probe * r_probe
            rr_reach = reach * reach
            for u in range(n_rest):
                j = near[rest[u]]
                x = cloud[j, 0]
                y = cloud[j, 1]
                zq = cloud[j, 2]
                above = 0
                low = np.inf
                ix = int(math.floor((x - lo[0]) / h))
                iy = int(math.floor((y - lo[1]) / h))
                for a in range(max(ix - 1, 0), min(ix + 1, gx - 1) + 1):
                    for b in range(max(iy - 1, 0), min(iy + 1, gy - 1) + 1):
                        c = a * gy + b
                        for s in range(start[c], start[c + 1]):
                            w = order[s]
                            e0 = xy[w, 0] - x
                            e1 = xy[w, 1] - y
                            if e0 * e0 + e1 * e1 <= rr_pair:
                                z = P[high[w], 2]
                                if z > zq + 2.0 * d:
                                    above += 1
                                if z > zq - d:
                                    low = min(low, z)
                if above < 2:
                    continue
                if not resting:
                    below[u] = True
                    continue
                # ... unless an oblique sensor sees it under an overhang: every one of 8
                # directions blocked where the model reaches down to the line of sight
                gap = max(low - zq, 0.0)
                ray_z = zq + 1.2 * gap + 0.1 * d
                covered = True
                for v in range(8):
                    px = x + gap * dirs8[v, 0]
                    py = y + gap * dirs8[v, 1]
                    z_min = np.inf
                    nearer = False
                    ix = int(math.floor((px - lo[0]) / h))
                    iy = int(math.floor((py - lo[1]) / h))
                    for a in range(max(ix - 1, 0), min(ix + 1, gx - 1) + 1):
                        for b in range(max(iy - 1, 0), min(iy + 1, gy - 1) + 1):
                            c = a * gy + b
                            for s in range(start[c], start[c + 1]):
                                w = order[s]
                                e0 = xy[w, 0] - px
                                e1 = xy[w, 1] - py
                                s2 = e0 * e0 + e1 * e1
                                if s2 <= rr_probe:
                                    z_min = min(z_min, P[high[w], 2])
                                    if s2 < rr_reach:
                                        nearer = True
                    if not (z_min <= ray_z and nearer):
                        covered = False
                        break
                below[u] = covered
    below_n = 0
    for u in range(n_rest):
        if below[u]:
            below_n += 1
        else:
            loose[n_loose] = near[rest[u]]
            n_loose += 1
    unexplained_n = 0
    for u in range(n_loose):
        j = loose[u]
        if has_table:
            dj = cloud[j, 0] * tn[0] + cloud[j, 1] * tn[1] + cloud[j, 2] * tn[2] - toff
            if not dj > d:
                continue
        if elsewhere.shape[0] and elsewhere[j]:
            continue
        unexplained_n += 1
    return explained_n, inside_n, below_n, unexplained_n
