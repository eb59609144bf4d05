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
    n_ext = extremes.shape[1]
    out = np.empty((n_planes * n_planes * n_pairs, 4, 4))
    count = 0
    e = np.empty(3)
    f = np.empty(3)
    g = np.empty(3)
    v = np.empty(3)
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
            lo_e, hi_e, lo_f, hi_f = np.inf, -np.inf, np.inf, -np.inf
            for r in range(starts[a], starts[a + 1]):
                pe = points[r, 0] * e[0] + points[r, 1] * e[1] + points[r, 2] * e[2]
                pf = points[r, 0] * f[0] + points[r, 1] * f[1] + points[r, 2] * f[2]
                lo_e, hi_e = min(lo_e, pe), max(hi_e, pe)
                lo_f, hi_f = min(lo_f, pf), max(hi_f, pf)
            if sampled[b]:
                g[0] = Q1 * e[2] - Q2 * e[1]
                g[1] = Q2 * e[0] - Q0 * e[2]
                g[2] = Q0 * e[1] - Q1 * e[0]
                lo_qe, hi_qe, lo_qg, hi_qg = np.inf, -np.inf, np.inf, -np.inf
                for r in range(starts[b], starts[b + 1]):
                    qe = points[r, 0] * e[0] + points[r, 1] * e[1] + points[r, 2] * e[2]
                    qg = points[r, 0] * g[0] + points[r, 1] * g[1] + points[r, 2] * g[2]
                    lo_qe, hi_qe = min(lo_qe, qe), max(hi_qe, qe)
                    lo_qg, hi_qg = min(lo_qg, qg), max(hi_qg, qg)
            # lhs = [P; Q; e] and its inverse (the adjugate over the determinant)
            m00, m01, m02 = P0, P1, P2
            m10, m11, m12 = Q0, Q1, Q2
            m20, m21, m22 = e[0], e[1], e[2]
            det = (
                m00 * (m11 * m22 - m12 * m21)
                - m01 * (m10 * m22 - m12 * m20)
                + m02 * (m10 * m21 - m11 * m20)
            )
            if not abs(det) > 1e-12:
                continue
            inv = np.empty((3, 3))
            inv[0, 0] = (m11 * m22 - m12 * m21) / det
            inv[0, 1] = (m02 * m21 - m01 * m22) / det
            inv[0, 2] = (m01 * m12 - m02 * m11) / det
            inv[1, 0] = (m12 * m20 - m10 * m22) / det
            inv[1, 1] = (m00 * m22 - m02 * m20) / det
            inv[1, 2] = (m02 * m10 - m00 * m12) / det
            inv[2, 0] = (m10 * m21 - m11 * m20) / det
            inv[2, 1] = (m01 * m20 - m00 * m21) / det
            inv[2, 2] = (m00 * m11 - m01 * m10) / det
            mid_s = (hi_e + lo_e) / 2
            for k in range(n_pairs):
                if not abs(pcos[k] - cpq) <= cos_tol:
                    continue
                R = frame @ pframes[k].T
                # R^T e, R^T f (and R^T g): the scene directions in the model frame
                fa = pa[k]
                lo_ae, hi_ae, lo_af, hi_af = np.inf, -np.inf, np.inf, -np.inf
                for u in range(3):
                    v[u] = R[0, u] * e[0] + R[1, u] * e[1] + R[2, u] * e[2]
                rf0 = R[0, 0] * f[0] + R[1, 0] * f[1] + R[2, 0] * f[2]
                rf1 = R[0, 1] * f[0] + R[1, 1] * f[1] + R[2, 1] * f[2]
                rf2 = R[0, 2] * f[0] + R[1, 2] * f[1] + R[2, 2] * f[2]
                for p in range(n_ext):
                    x = extremes[fa, p, 0]
                    y = extremes[fa, p, 1]
                    z = extremes[fa, p, 2]
                    ae = x * v[0] + y * v[1] + z * v[2]
                    af = x * rf0 + y * rf1 + z * rf2
                    lo_ae, hi_ae = min(lo_ae, ae), max(hi_ae, ae)
                    lo_af, hi_af = min(lo_af, af), max(hi_af, af)
                if not (
                    hi_e - lo_e <= hi_ae - lo_ae + slack and hi_f - lo_f <= hi_af - lo_af + slack
                ):
                    continue
                if sampled[b]:
                    fb = pb[k]
                    rg0 = R[0, 0] * g[0] + R[1, 0] * g[1] + R[2, 0] * g[2]
                    rg1 = R[0, 1] * g[0] + R[1, 1] * g[1] + R[2, 1] * g[2]
                    rg2 = R[0, 2] * g[0] + R[1, 2] * g[1] + R[2, 2] * g[2]
                    lo_be, hi_be, lo_bg, hi_bg = np.inf, -np.inf, np.inf, -np.inf
                    for p in range(n_ext):
                        x = extremes[fb, p, 0]
                        y = extremes[fb, p, 1]
                        z = extremes[fb, p, 2]
                        be = x * v[0] + y * v[1] + z * v[2]
                        bg = x * rg0 + y * rg1 + z * rg2
                        lo_be, hi_be = min(lo_be, be), max(hi_be, be)
                        lo_bg, hi_bg = min(lo_bg, bg), max(hi_bg, bg)
                    if not (
                        hi_qe - lo_qe <= hi_be - lo_be + slack
                        and hi_qg - lo_qg <= hi_bg - lo_bg + slack
                    ):
                        continue
                mid_m = (hi_ae + lo_ae) / 2
                r0 = offsets[a] - face_offsets[pa[k]]
                r1 = offsets[b] - face_offsets[pb[k]]
                r2 = mid_s - mid_m
                t0 = r0 * inv[0, 0] + r1 * inv[0, 1] + r2 * inv[0, 2]
                t1 = r0 * inv[1, 0] + r1 * inv[1, 1] + r2 * inv[1, 2]
                t2 = r0 * inv[2, 0] + r1 * inv[2, 1] + r2 * inv[2, 2]
                if not (np.isfinite(t0) and np.isfinite(t1) and np.isfinite(t2)):
                    continue
                if not np.all(np.isfinite(R)):
                    continue
                T = out[count]
                T[:] = 0.0
                T[:3, :3] = R
                T[0, 3] = t0
                T[1, 3] = t1
                T[2, 3] = t2
                T[3, 3] = 1.0
                count += 1
    return out[:count].copy()
