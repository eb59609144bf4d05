"""The compiled pairing consistency and triangle listing of :mod:`mks_sim.models.freeform`.

Imported only when numba is used (``freeform._consistent(..., compiled=False)`` and
``freeform._triangles(..., compiled=False)`` are the numpy paths the tests compare these
with). Both kernels compute exactly what the numpy paths compute, in the same order, without
their (C x C) temporaries: the float32 distance differences, the upper-triangle edge list in
row-major order and the triangles in edge order. Module-level, ``cache=True``: the first use
on a machine compiles, later processes load the machine code from ``__pycache__``.
"""

from __future__ import annotations

import numba as nb
import numpy as np


@nb.njit(cache=True)
def consistent_pairs(
    dk: np.ndarray,
    pair_s: np.ndarray,
    model_dist: np.ndarray,
    pair_m: np.ndarray,
    min_side: np.float32,
    tolerance: np.float32,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:  # pragma: no cover
    """Pairings ``i``, ``j`` are consistent when their scene keypoints are at least
    ``min_side`` apart (``dk[pair_s[i], pair_s[j]]``, float32) and that distance is within
    ``tolerance`` of their model points' (``model_dist[pair_m[i], pair_m[j]]``).

    Returns:
        ``(cons, a, b)``: the symmetric (C, C) boolean matrix and its upper-triangle pairs
        ``a < b`` in row-major order (``np.nonzero`` order).
    """
    c = len(pair_s)
    cons = np.zeros((c, c), dtype=np.bool_)
    edges = 0
    for i in range(c):
        si = pair_s[i]
        mi = pair_m[i]
        for j in range(i + 1, c):
            d = dk[si, pair_s[j]]
            if d >= min_side and abs(d - model_dist[mi, pair_m[j]]) <= tolerance:
                cons[i, j] = True
                cons[j, i] = True
                edges += 1
    a = np.empty(edges, dtype=np.int64)
    b = np.empty(edges, dtype=np.int64)
    k = 0
    for i in range(c):
        for j in range(i + 1, c):
            if cons[i, j]:
                a[k] = i
                b[k] = j
                k += 1
    return cons, a, b


@nb.njit(cache=True)
def edge_triangles(cons: np.ndarray, a: np.ndarray, b: np.ndarray) -> np.ndarray:  # pragma: no cover
    """(T, 3) triples ``a[e] < b[e] < k`` with ``cons[a[e], k]`` and ``cons[b[e], k]``, edge by
    edge, ``k`` ascending."""
    c = cons.shape[0]
    out = np.empty((max(16, len(a)), 3), dtype=np.int64)
    t = 0
    for e in range(len(a)):
        ra = cons[a[e]]
        rb = cons[b[e]]
        for k in range(b[e] + 1, c):
            if ra[k] and rb[k]:
                if t == len(out):  # full: twice the room
                    grown = np.empty((2 * len(out), 3), dtype=np.int64)
                    grown[:t] = out
                    out = grown
                out[t, 0] = a[e]
                out[t, 1] = b[e]
                out[t, 2] = k
                t += 1
    return out[:t].copy()


@nb.njit(cache=True)
def rotations_close(r9: np.ndarray, cos_threshold: float) -> np.ndarray:  # pragma: no cover
    """(n, n) boolean: rotations (flattened 3 x 3 rows of ``r9``) within the angle whose
    cosine is ``cos_threshold``, ``cos = (trace(Ri^T Rj) - 1) / 2``."""
    n = r9.shape[0]
    close = np.empty((n, n), dtype=np.bool_)
    for a in range(n):
        close[a, a] = True
        for b in range(a + 1, n):
            s = 0.0
            for k in range(9):
                s += r9[a, k] * r9[b, k]
            c = (s - 1.0) / 2.0 >= cos_threshold
            close[a, b] = c
            close[b, a] = c
    return close


@nb.njit(cache=True)
def triangle_rigid(
    src: np.ndarray, dst: np.ndarray
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:  # pragma: no cover
    """The closed-form rigid fits of ``freeform._triangle_rigid`` triangle by triangle:
    rotations (T, 3, 3), translations (T, 3) and the degenerate (collinear) triangles, which
    the caller fits by Kabsch."""
    t_n = src.shape[0]
    rot = np.empty((t_n, 3, 3))
    trans = np.empty((t_n, 3))
    bad = np.zeros(t_n, dtype=np.bool_)
    a = np.empty((3, 3))
    b = np.empty((3, 3))
    fs = np.empty((3, 3))
    fd = np.empty((3, 3))
    cs = np.empty(3)
    cd = np.empty(3)
    for t in range(t_n):
        for i in range(3):
            cs[i] = (src[t, 0, i] + src[t, 1, i] + src[t, 2, i]) / 3.0
            cd[i] = (dst[t, 0, i] + dst[t, 1, i] + dst[t, 2, i]) / 3.0
        scale = 0.0
        for v in range(3):
            for i in range(3):
                a[v, i] = src[t, v, i] - cs[i]
                b[v, i] = dst[t, v, i] - cd[i]
                scale = max(scale, abs(a[v, i]), abs(b[v, i]))
        nn_s = _frame(a, fs)
        nn_d = _frame(b, fd)
        if nn_s <= 1e-9 * scale**2 or nn_d <= 1e-9 * scale**2:
            bad[t] = True
            continue
        cross = 0.0
        dot = 0.0
        for v in range(3):
            ax = a[v, 0] * fs[0, 0] + a[v, 1] * fs[0, 1] + a[v, 2] * fs[0, 2]
            ay = a[v, 0] * fs[1, 0] + a[v, 1] * fs[1, 1] + a[v, 2] * fs[1, 2]
            bx = b[v, 0] * fd[0, 0] + b[v, 1] * fd[0, 1] + b[v, 2] * fd[0, 2]
            by = b[v, 0] * fd[1, 0] + b[v, 1] * fd[1, 1] + b[v, 2] * fd[1, 2]
            cross += ax * by - ay * bx
            dot += ax * bx + ay * by
        phi = np.arctan2(cross, dot)
        co = np.cos(phi)
        si = np.sin(phi)
        for i in range(3):
            m0 = co * fs[0, i] - si * fs[1, i]
            m1 = si * fs[0, i] + co * fs[1, i]
            for r in range(3):
                rot[t, r, i] = fd[0, r] * m0 + fd[1, r] * m1 + fd[2, r] * fs[2, i]
        for r in range(3):
            trans[t, r] = cd[r] - (rot[t, r, 0] * cs[0] + rot[t, r, 1] * cs[1] + rot[t, r, 2] * cs[2])
    return rot, trans, bad


@nb.njit(cache=True)
def _frame(x: np.ndarray, f: np.ndarray) -> float:  # pragma: no cover
    """Rows e1 (x0 - x1, unit), e2 = n x e1, n (the unit normal of the triangle ``x``) into
    ``f``; returns the normal's length before normalising."""
    u0 = x[1, 0] - x[0, 0]
    u1 = x[1, 1] - x[0, 1]
    u2 = x[1, 2] - x[0, 2]
    v0 = x[2, 0] - x[0, 0]
    v1 = x[2, 1] - x[0, 1]
    v2 = x[2, 2] - x[0, 2]
    n0 = u1 * v2 - u2 * v1
    n1 = u2 * v0 - u0 * v2
    n2 = u0 * v1 - u1 * v0
    nn = np.sqrt(n0 * n0 + n1 * n1 + n2 * n2)
    e0 = x[0, 0] - x[1, 0]
    e1 = x[0, 1] - x[1, 1]
    e2 = x[0, 2] - x[1, 2]
    ne = max(np.sqrt(e0 * e0 + e1 * e1 + e2 * e2), 1e-300)
    e0 /= ne
    e1 /= ne
    e2 /= ne
    d = max(nn, 1e-300)
    n0 /= d
    n1 /= d
    n2 /= d
    f[0, 0] = e0
    f[0, 1] = e1
    f[0, 2] = e2
    f[1, 0] = n1 * e2 - n2 * e1
    f[1, 1] = n2 * e0 - n0 * e2
    f[1, 2] = n0 * e1 - n1 * e0
    f[2, 0] = n0
    f[2, 1] = n1
    f[2, 2] = n2
    return nn
