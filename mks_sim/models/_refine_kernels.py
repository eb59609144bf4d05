"""The compiled normal equations of one point-to-plane ICP iteration
(:func:`mks_sim.models.refine.icp_point_to_plane`).

Imported only when numba is used (``icp_point_to_plane(..., compiled=False)`` is the numpy
path the tests compare this with). One pass over the correspondences instead of a dozen
numpy calls, each of which costs more than its arithmetic at a few hundred points.
Module-level, ``cache=True``: the first use on a machine compiles, later processes load the
machine code from ``__pycache__``.
"""

from __future__ import annotations

import math

import numba as nb
import numpy as np

from mks_sim.lowlevel._gridknn_kernels import smallest_vectors


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
    # The 21 sums of H's upper triangle and g's 6 in scalars (registers): each is added in
    # the same order as through h[u, v] in memory, to the bit (4,000 pairs of the polish:
    # 0.089 -> 0.062 ms an iteration).
    h00 = h01 = h02 = h03 = h04 = h05 = h11 = h12 = h13 = h14 = h15 = 0.0
    h22 = h23 = h24 = h25 = h33 = h34 = h35 = h44 = h45 = h55 = 0.0
    g0 = g1 = g2 = g3 = g4 = g5 = 0.0
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
        a0 = py * nz - pz * ny
        a1 = pz * nx - px * nz
        a2 = px * ny - py * nx
        g0 += a0 * r
        g1 += a1 * r
        g2 += a2 * r
        g3 += nx * r
        g4 += ny * r
        g5 += nz * r
        h00 += a0 * a0
        h01 += a0 * a1
        h02 += a0 * a2
        h03 += a0 * nx
        h04 += a0 * ny
        h05 += a0 * nz
        h11 += a1 * a1
        h12 += a1 * a2
        h13 += a1 * nx
        h14 += a1 * ny
        h15 += a1 * nz
        h22 += a2 * a2
        h23 += a2 * nx
        h24 += a2 * ny
        h25 += a2 * nz
        h33 += nx * nx
        h34 += nx * ny
        h35 += nx * nz
        h44 += ny * ny
        h45 += ny * nz
        h55 += nz * nz
        ss += r * r
        used += 1
    upper = (
        (h00, h01, h02, h03, h04, h05),
        (h01, h11, h12, h13, h14, h15),
        (h02, h12, h22, h23, h24, h25),
        (h03, h13, h23, h33, h34, h35),
        (h04, h14, h24, h34, h44, h45),
        (h05, h15, h25, h35, h45, h55),
    )
    for u in range(6):
        for v in range(6):
            h[u, v] = upper[u][v]
    g[0] = g0
    g[1] = g1
    g[2] = g2
    g[3] = g3
    g[4] = g4
    g[5] = g5
    return h, g, ss, used


@nb.njit(cache=True)
def _cell_sample(
    px: float,
    py: float,
    pz: float,
    origin: np.ndarray,
    cell: float,
    shape: np.ndarray,
    index: np.ndarray,
) -> int:  # pragma: no cover
    """The sample the lookup grid holds for the cell nearest (px, py, pz) (its centre
    rounded), -1 off the grid."""
    cx = int(np.rint((px - origin[0]) / cell))
    cy = int(np.rint((py - origin[1]) / cell))
    cz = int(np.rint((pz - origin[2]) / cell))
    nx, ny, nz = shape[0], shape[1], shape[2]
    if cx < 0 or cx >= nx or cy < 0 or cy >= ny or cz < 0 or cz >= nz:
        return -1
    return int(index[(cx * ny + cy) * nz + cz])


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
    for i in range(n):
        q = _cell_sample(p[i, 0], p[i, 1], p[i, 2], origin, cell, shape, index)
        if q < 0:
            outside[i] = True
            continue
        dx = p[i, 0] - points[q, 0]
        dy = p[i, 1] - points[q, 1]
        dz = p[i, 2] - points[q, 2]
        di = np.sqrt(dx * dx + dy * dy + dz * dz)
        if di < max_distance:
            d[i] = di
            j[i] = q
    return d, j, outside


@nb.njit(cache=True, inline="always")
def _residual(
    px: float,
    py: float,
    pz: float,
    origin: np.ndarray,
    cell: float,
    shape: np.ndarray,
    index: np.ndarray,
    points: np.ndarray,
    normals: np.ndarray,
    max_distance: float,
) -> tuple[bool, float]:  # pragma: no cover
    """(hit, r): the model-frame point's sample on the lookup grid (as :func:`lookup_nearest`:
    no hit off the grid or at ``max_distance``) and its point-to-plane residual to it."""
    q = _cell_sample(px, py, pz, origin, cell, shape, index)
    if q < 0:
        return False, 0.0
    ex = px - points[q, 0]
    ey = py - points[q, 1]
    ez = pz - points[q, 2]
    if not np.sqrt(ex * ex + ey * ey + ez * ez) < max_distance:
        return False, 0.0
    return True, ex * normals[q, 0] + ey * normals[q, 1] + ez * normals[q, 2]


@nb.njit(cache=True)
def lookup_score(
    scene: np.ndarray,
    S: np.ndarray,
    origin: np.ndarray,
    cell: float,
    shape: np.ndarray,
    index: np.ndarray,
    points: np.ndarray,
    normals: np.ndarray,
    max_distance: float,
    inlier: float,
) -> tuple[int, float]:  # pragma: no cover
    """(inliers, sum of their squared residuals) of :func:`mks_sim.models.refine.score_pose`
    in one pass: each scene point moved into the model frame by ``S`` (scene -> model), its
    sample looked up on the grid (as :func:`lookup_nearest`: a miss off the grid or at
    ``max_distance``), an inlier when its point-to-plane residual to that sample is at most
    ``inlier``. (The caller makes sure no query off the grid could have a sample within
    ``max_distance``.) The moved points and the sums round as this loop does, not as
    numpy's products and pairwise sums: the last bits of the score may differ."""
    n = scene.shape[0]
    count = 0
    ssq = 0.0
    for i in range(n):
        x = scene[i, 0]
        y = scene[i, 1]
        z = scene[i, 2]
        px = S[0, 0] * x + S[0, 1] * y + S[0, 2] * z + S[0, 3]
        py = S[1, 0] * x + S[1, 1] * y + S[1, 2] * z + S[1, 3]
        pz = S[2, 0] * x + S[2, 1] * y + S[2, 2] * z + S[2, 3]
        hit, r = _residual(px, py, pz, origin, cell, shape, index, points, normals, max_distance)
        if hit and abs(r) <= inlier:
            count += 1
            ssq += r * r
    return count, ssq


@nb.njit(cache=True, parallel=True)
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
    query off the grid could have a sample within ``max_distance``.) The poses run in
    parallel: each count is the same whichever thread adds it."""
    k_poses = T.shape[0]
    n = scene.shape[0]
    out = np.zeros(k_poses, np.int64)
    for k in nb.prange(k_poses):
        count = 0
        for i in range(n):
            dx0 = scene[i, 0] - T[k, 0, 3]
            dx1 = scene[i, 1] - T[k, 1, 3]
            dx2 = scene[i, 2] - T[k, 2, 3]
            px = dx0 * T[k, 0, 0] + dx1 * T[k, 1, 0] + dx2 * T[k, 2, 0]
            py = dx0 * T[k, 0, 1] + dx1 * T[k, 1, 1] + dx2 * T[k, 2, 1]
            pz = dx0 * T[k, 0, 2] + dx1 * T[k, 1, 2] + dx2 * T[k, 2, 2]
            hit, r = _residual(
                px, py, pz, origin, cell, shape, index, points, normals, max_distance
            )
            if hit and abs(r) <= inlier:
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
def equivalent_labels(
    mats: np.ndarray, syms: np.ndarray, translation_tol: float, cos_tol: float
) -> np.ndarray:  # pragma: no cover
    """(H,) labels of H (4, 4) poses, best first, as :func:`first_representatives` gives
    them from :func:`mks_sim.models.refine.group_equivalent`'s pairs: pose i joins the
    first earlier representative j whose origin is within ``translation_tol``
    (``sqrt((dx*dx + dy*dy) + dz*dz)``, numpy's norm) and some ``R_j S`` of which is
    within the angle of ``cos_tol`` of ``R_i`` (``(trace((R_j S)^T R_i) - 1) / 2``, its
    sums in a fixed order: numpy's batched products may round their last bit otherwise);
    only the representatives' pairs are computed."""
    h = mats.shape[0]
    ns = syms.shape[0]
    labels = np.arange(h)
    reps = np.empty(h, np.int64)
    nrep = 0
    for i in range(h):
        found = -1
        for r in range(nrep):
            j = reps[r]
            dx = mats[j, 0, 3] - mats[i, 0, 3]
            dy = mats[j, 1, 3] - mats[i, 1, 3]
            dz = mats[j, 2, 3] - mats[i, 2, 3]
            if not np.sqrt((dx * dx + dy * dy) + dz * dz) <= translation_tol:
                continue
            for s in range(ns):
                acc = 0.0
                for p in range(3):
                    for q in range(3):
                        rs = (
                            mats[j, p, 0] * syms[s, 0, q] + mats[j, p, 1] * syms[s, 1, q]
                        ) + mats[j, p, 2] * syms[s, 2, q]
                        acc += rs * mats[i, p, q]
                if (acc - 1.0) / 2.0 >= cos_tol:
                    found = j
                    break
            if found >= 0:
                break
        if found >= 0:
            labels[i] = found
        else:
            reps[nrep] = i
            nrep += 1
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
    step = np.zeros(6)
    history = np.empty(max_iterations)
    n_hist = 0
    rmse = np.inf
    converged = False
    it = 0
    for it in range(1, max_iterations + 1):  # noqa: B007 - returned
        for i in range(n):
            x = scene[i, 0]
            y = scene[i, 1]
            z = scene[i, 2]
            p[i, 0] = S[0, 0] * x + S[0, 1] * y + S[0, 2] * z + S[0, 3]
            p[i, 1] = S[1, 0] * x + S[1, 1] * y + S[1, 2] * z + S[1, 3]
            p[i, 2] = S[2, 0] * x + S[2, 1] * y + S[2, 2] * z + S[2, 3]
        dist, jj, _ = lookup_nearest(p, origin, cell, shape, index, points, max_distance)
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


@nb.njit(cache=True)
def _set_pose(
    T: np.ndarray, R: np.ndarray, t0: float, t1: float, t2: float
) -> None:  # pragma: no cover
    """T <- [[R, t], [0, 0, 0, 1]]."""
    T[:] = 0.0
    T[:3, :3] = R
    T[0, 3] = t0
    T[1, 3] = t1
    T[2, 3] = t2
    T[3, 3] = 1.0


@nb.njit(cache=True)
def _spans(
    pts: np.ndarray, a0: float, a1: float, a2: float, b0: float, b1: float, b2: float
) -> tuple[float, float, float, float]:  # pragma: no cover
    """(lo, hi) of (P, 3) points projected on (a0, a1, a2), then on (b0, b1, b2)."""
    lo_a, hi_a, lo_b, hi_b = np.inf, -np.inf, np.inf, -np.inf
    for p in range(pts.shape[0]):
        x = pts[p, 0]
        y = pts[p, 1]
        z = pts[p, 2]
        pa = x * a0 + y * a1 + z * a2
        pb = x * b0 + y * b1 + z * b2
        lo_a, hi_a = min(lo_a, pa), max(hi_a, pa)
        lo_b, hi_b = min(lo_b, pb), max(hi_b, pb)
    return lo_a, hi_a, lo_b, hi_b


@nb.njit(cache=True)
def plane_pair_poses(
    normals: np.ndarray,
    offsets: np.ndarray,
    starts: np.ndarray,
    sampled: np.ndarray,
    points: np.ndarray,
    extremes: np.ndarray,
    face_offsets: np.ndarray,
    pa: np.ndarray,
    pb: np.ndarray,
    pcos: np.ndarray,
    pframes: np.ndarray,
    cos_tol: float,
    slack: float,
) -> np.ndarray:  # pragma: no cover
    """(K, 4, 4) the poses of :func:`mks_sim.localization.hypotheses.plane_pair_hypotheses`
    in one compiled pass, pairs in its order: detected planes (L,) ``normals`` and
    ``offsets``, plane l's points ``points[starts[l]:starts[l + 1]]`` when ``sampled[l]``;
    the model's face extremes and offsets and its face pairs (``pa``, ``pb``, cosines,
    frames). The same tests and solve; the rounding of the products may differ."""
    n_planes = normals.shape[0]
    n_pairs = pa.shape[0]
    out = np.empty((n_planes * n_planes * n_pairs, 4, 4))
    count = 0
    e = np.empty(3)
    f = np.empty(3)
    g = np.empty(3)
    v = np.empty(3)
    lhs = np.empty((3, 3))
    inv_t = np.empty((3, 3))
    for a in range(n_planes):
        if not sampled[a]:
            continue
        for b in range(n_planes):
            if b == a:
                continue
            P0, P1, P2 = normals[a, 0], normals[a, 1], normals[a, 2]
            Q0, Q1, Q2 = normals[b, 0], normals[b, 1], normals[b, 2]
            cpq = P0 * Q0 + P1 * Q1 + P2 * Q2
            if abs(cpq) > 0.9:
                continue
            # the frame: e1 = P / |P|, e3 = P x Q / |P x Q|, e2 = e3 x e1
            np_ = math.sqrt(P0 * P0 + P1 * P1 + P2 * P2)
            e10, e11, e12 = P0 / np_, P1 / np_, P2 / np_
            c0 = P1 * Q2 - P2 * Q1
            c1 = P2 * Q0 - P0 * Q2
            c2 = P0 * Q1 - P1 * Q0
            nc = math.sqrt(c0 * c0 + c1 * c1 + c2 * c2)
            if nc < 1e-9:
                continue
            e[0], e[1], e[2] = c0 / nc, c1 / nc, c2 / nc
            f[0] = e[1] * e12 - e[2] * e11
            f[1] = e[2] * e10 - e[0] * e12
            f[2] = e[0] * e11 - e[1] * e10
            frame = np.empty((3, 3))
            for i in range(3):
                frame[i, 0] = (e10, e11, e12)[i]
                frame[i, 1] = f[i]
                frame[i, 2] = e[i]
            # the plane's observed extents along e and f
            lo_e, hi_e, lo_f, hi_f = _spans(
                points[starts[a] : starts[a + 1]], e[0], e[1], e[2], f[0], f[1], f[2]
            )
            if sampled[b]:
                g[0] = Q1 * e[2] - Q2 * e[1]
                g[1] = Q2 * e[0] - Q0 * e[2]
                g[2] = Q0 * e[1] - Q1 * e[0]
                lo_qe, hi_qe, lo_qg, hi_qg = _spans(
                    points[starts[b] : starts[b + 1]], e[0], e[1], e[2], g[0], g[1], g[2]
                )
            # lhs = [P; Q; e] and its inverse's transpose (the cofactors over the determinant)
            lhs[0, 0], lhs[0, 1], lhs[0, 2] = P0, P1, P2
            lhs[1, 0], lhs[1, 1], lhs[1, 2] = Q0, Q1, Q2
            lhs[2, 0], lhs[2, 1], lhs[2, 2] = e[0], e[1], e[2]
            det = _det3(lhs)
            if not abs(det) > 1e-12:
                continue
            _inverse_transpose3(lhs, det, inv_t)
            mid_s = (hi_e + lo_e) / 2
            for k in range(n_pairs):
                if not abs(pcos[k] - cpq) <= cos_tol:
                    continue
                R = frame @ pframes[k].T
                # R^T e, R^T f (and R^T g): the scene directions in the model frame
                fa = pa[k]
                for u in range(3):
                    v[u] = R[0, u] * e[0] + R[1, u] * e[1] + R[2, u] * e[2]
                rf0 = R[0, 0] * f[0] + R[1, 0] * f[1] + R[2, 0] * f[2]
                rf1 = R[0, 1] * f[0] + R[1, 1] * f[1] + R[2, 1] * f[2]
                rf2 = R[0, 2] * f[0] + R[1, 2] * f[1] + R[2, 2] * f[2]
                lo_ae, hi_ae, lo_af, hi_af = _spans(extremes[fa], v[0], v[1], v[2], rf0, rf1, rf2)
                if not (
                    hi_e - lo_e <= hi_ae - lo_ae + slack and hi_f - lo_f <= hi_af - lo_af + slack
                ):
                    continue
                if sampled[b]:
                    fb = pb[k]
                    rg0 = R[0, 0] * g[0] + R[1, 0] * g[1] + R[2, 0] * g[2]
                    rg1 = R[0, 1] * g[0] + R[1, 1] * g[1] + R[2, 1] * g[2]
                    rg2 = R[0, 2] * g[0] + R[1, 2] * g[1] + R[2, 2] * g[2]
                    lo_be, hi_be, lo_bg, hi_bg = _spans(
                        extremes[fb], v[0], v[1], v[2], rg0, rg1, rg2
                    )
                    if not (
                        hi_qe - lo_qe <= hi_be - lo_be + slack
                        and hi_qg - lo_qg <= hi_bg - lo_bg + slack
                    ):
                        continue
                mid_m = (hi_ae + lo_ae) / 2
                r0 = offsets[a] - face_offsets[pa[k]]
                r1 = offsets[b] - face_offsets[pb[k]]
                r2 = mid_s - mid_m
                t0 = r0 * inv_t[0, 0] + r1 * inv_t[1, 0] + r2 * inv_t[2, 0]
                t1 = r0 * inv_t[0, 1] + r1 * inv_t[1, 1] + r2 * inv_t[2, 1]
                t2 = r0 * inv_t[0, 2] + r1 * inv_t[1, 2] + r2 * inv_t[2, 2]
                if not (np.isfinite(t0) and np.isfinite(t1) and np.isfinite(t2)):
                    continue
                if not np.all(np.isfinite(R)):
                    continue
                _set_pose(out[count], R, t0, t1, t2)
                count += 1
    return out[:count].copy()


@nb.njit(cache=True)
def _det3(X: np.ndarray) -> float:  # pragma: no cover
    return (
        X[0, 0] * (X[1, 1] * X[2, 2] - X[1, 2] * X[2, 1])
        - X[0, 1] * (X[1, 0] * X[2, 2] - X[1, 2] * X[2, 0])
        + X[0, 2] * (X[1, 0] * X[2, 1] - X[1, 1] * X[2, 0])
    )


@nb.njit(cache=True)
def _inverse_transpose3(X: np.ndarray, det: float, Y: np.ndarray) -> None:  # pragma: no cover
    """Y <- X^-T of a 3x3 ``X`` of determinant ``det``: its cofactors over ``det``."""
    Y[0, 0] = (X[1, 1] * X[2, 2] - X[1, 2] * X[2, 1]) / det
    Y[0, 1] = (X[1, 2] * X[2, 0] - X[1, 0] * X[2, 2]) / det
    Y[0, 2] = (X[1, 0] * X[2, 1] - X[1, 1] * X[2, 0]) / det
    Y[1, 0] = (X[0, 2] * X[2, 1] - X[0, 1] * X[2, 2]) / det
    Y[1, 1] = (X[0, 0] * X[2, 2] - X[0, 2] * X[2, 0]) / det
    Y[1, 2] = (X[0, 1] * X[2, 0] - X[0, 0] * X[2, 1]) / det
    Y[2, 0] = (X[0, 1] * X[1, 2] - X[0, 2] * X[1, 1]) / det
    Y[2, 1] = (X[0, 2] * X[1, 0] - X[0, 0] * X[1, 2]) / det
    Y[2, 2] = (X[0, 0] * X[1, 1] - X[0, 1] * X[1, 0]) / det


@nb.njit(cache=True)
def _kabsch3(
    H: np.ndarray, X: np.ndarray, Y: np.ndarray, R: np.ndarray
) -> None:  # pragma: no cover
    """R <- the proper rotation maximising trace(R H) of a 3x3 ``H``
    (``geometry.transforms.rotation_from_covariance``), without LAPACK: H's orthogonal
    polar factor Q by Newton's iteration ``X <- (X + X^-T) / 2`` (H = U S V^T, Q = U V^T);
    R = Q^T when det H > 0; else R = (I - 2 v v^T) Q^T = V diag(1, 1, -1) U^T, v the
    eigenvector of P = Q^T H = V S V^T of its smallest eigenvalue (the reflection guard;
    the vector by the normals' kernel, ``_gridknn_kernels.smallest_vectors``). A singular
    H, or a P whose smallest eigenvalue has no distinct eigenvector, goes to the SVD.
    ``X``, ``Y``: 3x3 scratch."""
    scale = 0.0
    for i in range(3):
        for j in range(3):
            scale += H[i, j] * H[i, j]
            X[i, j] = H[i, j]
    det_h = _det3(H)
    if abs(det_h) > 1e-6 * scale**1.5:
        for _ in range(60):
            d = _det3(X)
            _inverse_transpose3(X, d, Y)
            # scaled Newton (det-scaling) while far, plain near the limit
            g = abs(d) ** (-1.0 / 3.0)
            change = 0.0
            for i in range(3):
                for j in range(3):
                    v = 0.5 * (g * X[i, j] + Y[i, j] / g)
                    change = max(change, abs(v - X[i, j]))
                    X[i, j] = v
            if change < 1e-14:
                break
        if det_h > 0:
            for i in range(3):
                for j in range(3):
                    R[i, j] = X[j, i]
            return
        # P = Q^T H (symmetric): its smallest eigenvalue by the trigonometric solution
        p00 = X[0, 0] * H[0, 0] + X[1, 0] * H[1, 0] + X[2, 0] * H[2, 0]
        p01 = X[0, 0] * H[0, 1] + X[1, 0] * H[1, 1] + X[2, 0] * H[2, 1]
        p02 = X[0, 0] * H[0, 2] + X[1, 0] * H[1, 2] + X[2, 0] * H[2, 2]
        p11 = X[0, 1] * H[0, 1] + X[1, 1] * H[1, 1] + X[2, 1] * H[2, 1]
        p12 = X[0, 1] * H[0, 2] + X[1, 1] * H[1, 2] + X[2, 1] * H[2, 2]
        p22 = X[0, 2] * H[0, 2] + X[1, 2] * H[1, 2] + X[2, 2] * H[2, 2]
        q = (p00 + p11 + p22) / 3.0
        b00, b11, b22 = p00 - q, p11 - q, p22 - q
        pp = math.sqrt(
            (b00 * b00 + b11 * b11 + b22 * b22 + 2.0 * (p01 * p01 + p02 * p02 + p12 * p12)) / 6.0
        )
        if pp > 1e-12 * (abs(q) + 1e-300):
            det_b = (
                b00 * (b11 * b22 - p12 * p12)
                - p01 * (p01 * b22 - p12 * p02)
                + p02 * (p01 * p12 - b11 * p02)
            ) / pp**3
            phi = math.acos(min(max(det_b / 2.0, -1.0), 1.0)) / 3.0
            lam = q + 2.0 * pp * math.cos(phi + 2.0 * math.pi / 3.0)
            # its eigenvector as the normals' kernel finds it (``bad``: degenerate, the SVD)
            cov = np.array([[p00, p01, p02, p11, p12, p22]])
            vec, bad = smallest_vectors(cov, np.array([lam]), np.array([q]), np.ones(1, np.bool_))
            if not bad[0]:
                v0, v1, v2 = vec[0, 0], vec[0, 1], vec[0, 2]
                # R = (I - 2 v v^T) Q^T
                for i in range(3):
                    vi = vec[0, i]
                    for j in range(3):
                        R[i, j] = X[j, i] - 2.0 * vi * (v0 * X[j, 0] + v1 * X[j, 1] + v2 * X[j, 2])
                return
    U, _, Vt = np.linalg.svd(H)
    V = Vt.T.copy()
    Ut = U.T.copy()
    if np.linalg.det(V @ Ut) < 0:
        for r in range(3):
            V[r, 2] = -V[r, 2]
    R[:, :] = V @ Ut


@nb.njit(cache=True)
def vertex_poses(
    det_points: np.ndarray,
    det_normals: np.ndarray,
    c_point: np.ndarray,
    c_normals: np.ndarray,
    c_gram: np.ndarray,
    corners: np.ndarray,
    cos_max: float,
    vote_distance: float,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:  # pragma: no cover
    """The corner hypotheses of :func:`mks_sim.localization.hypotheses.vertex_hypotheses` in
    one compiled pass, in its order: for each detected vertex (its point and three face
    normals) and each model corner triple whose normals' Gram matrix is within 0.35 of the
    vertex's, the Kabsch rotation of the triple's normals onto the vertex's
    (:func:`_kabsch3`, reflection guarded), kept when every normal agrees within ``cos_max``; the translation takes the
    corner onto the vertex; each model corner is moved and matched to the nearest detected
    vertex strictly within ``vote_distance`` (none: the vertex count), and the votes are the
    distinct vertexes matched. Returns ``(votes (H,), matrices (H, 4, 4), matches (H, V))``.
    The same tests; the rotations (:func:`_kabsch3`) and the products may round
    differently from numpy's."""
    n_det = det_points.shape[0]
    n_trip = c_point.shape[0]
    n_corner = corners.shape[0]
    votes = np.empty(n_det * n_trip, np.int64)
    mats = np.empty((n_det * n_trip, 4, 4))
    match = np.empty((n_det * n_trip, n_corner), np.int64)
    seen = np.zeros(n_det + 1, np.int64)
    G = np.empty((3, 3))
    H = np.empty((3, 3))
    X = np.empty((3, 3))
    Y = np.empty((3, 3))
    R = np.empty((3, 3))
    count = 0
    for di in range(n_det):
        Nd = det_normals[di]
        for a in range(3):
            for b in range(3):
                G[a, b] = Nd[a, 0] * Nd[b, 0] + Nd[a, 1] * Nd[b, 1] + Nd[a, 2] * Nd[b, 2]
        for k in range(n_trip):
            close = True
            for a in range(3):
                for b in range(3):
                    if not abs(c_gram[k, a, b] - G[a, b]) <= 0.35:
                        close = False
            if not close:
                continue
            M = c_normals[k]
            for a in range(3):
                for b in range(3):
                    H[a, b] = M[0, a] * Nd[0, b] + M[1, a] * Nd[1, b] + M[2, a] * Nd[2, b]
            _kabsch3(H, X, Y, R)
            worst = np.inf
            for m in range(3):
                c = 0.0
                for i in range(3):
                    c += (R[i, 0] * M[m, 0] + R[i, 1] * M[m, 1] + R[i, 2] * M[m, 2]) * Nd[m, i]
                worst = min(worst, c)
            if not worst >= cos_max:
                continue
            t0 = det_points[di, 0] - (
                R[0, 0] * c_point[k, 0] + R[0, 1] * c_point[k, 1] + R[0, 2] * c_point[k, 2]
            )
            t1 = det_points[di, 1] - (
                R[1, 0] * c_point[k, 0] + R[1, 1] * c_point[k, 1] + R[1, 2] * c_point[k, 2]
            )
            t2 = det_points[di, 2] - (
                R[2, 0] * c_point[k, 0] + R[2, 1] * c_point[k, 1] + R[2, 2] * c_point[k, 2]
            )
            n_votes = 0
            for v in range(n_corner):
                x = R[0, 0] * corners[v, 0] + R[0, 1] * corners[v, 1] + R[0, 2] * corners[v, 2] + t0
                y = R[1, 0] * corners[v, 0] + R[1, 1] * corners[v, 1] + R[1, 2] * corners[v, 2] + t1
                z = R[2, 0] * corners[v, 0] + R[2, 1] * corners[v, 1] + R[2, 2] * corners[v, 2] + t2
                best = n_det
                best_d = vote_distance
                for q in range(n_det):
                    dx = x - det_points[q, 0]
                    dy = y - det_points[q, 1]
                    dz = z - det_points[q, 2]
                    dist = math.sqrt(dx * dx + dy * dy + dz * dz)
                    if dist < best_d:
                        best_d = dist
                        best = q
                match[count, v] = best
                if best < n_det and seen[best] != count + 1:
                    seen[best] = count + 1
                    n_votes += 1
            votes[count] = n_votes
            _set_pose(mats[count], R, t0, t1, t2)
            count += 1
    return votes[:count].copy(), mats[:count].copy(), match[:count].copy()
