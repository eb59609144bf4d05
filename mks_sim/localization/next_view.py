"""Choosing the next view (active sensing, issue 13): which camera pose sees most of an
instance's predicted surface that no view has seen yet.

The model is posed at its ESTIMATE (never the ground truth) and "ray-cast" into each
candidate camera with a z-buffer: a surface sample counts when it faces the camera, falls in
the image, is the nearest thing along its pixel's ray (the posed model itself and every point
sensed so far are the occluders) and no sensed point lies within ``seen_m`` of it.

Example:
    >>> n = unseen_visible(P, N, camera_to_world, K, (240, 320), occluders, seen)  # doctest: +SKIP
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np
from numpy.typing import NDArray
from scipy.spatial import cKDTree

__all__ = ["best_view", "unseen_visible"]

FloatArray = NDArray[np.float64]


def _project(
    P: FloatArray, camera_to_world: FloatArray, K: FloatArray
) -> tuple[FloatArray, FloatArray, FloatArray]:
    """(u, v, z) of world points in an OpenCV camera (z forward)."""
    R, t = camera_to_world[:3, :3], camera_to_world[:3, 3]
    Pc = (P - t) @ R
    z = Pc[:, 2]
    safe = np.where(z > 1e-6, z, np.inf)
    u = K[0, 0] * Pc[:, 0] / safe + K[0, 2]
    v = K[1, 1] * Pc[:, 1] / safe + K[1, 2]
    return u, v, z


def unseen_visible(
    surface: FloatArray,
    normals: FloatArray,
    camera_to_world: FloatArray,
    K: FloatArray,
    shape: tuple[int, int],
    occluders: FloatArray,
    seen: FloatArray,
    *,
    seen_m: float = 0.003,
    cell_px: int = 4,
    tolerance_m: float = 0.004,
    min_range_m: float = 0.05,
) -> int:
    """Surface samples (world, posed at the estimate) a camera would see that no sensed
    point has seen yet (module docstring).

    Args:
        surface: (M, 3) posed model surface samples, world.
        normals: (M, 3) their outward unit normals, world.
        camera_to_world: (4, 4) the candidate OpenCV camera pose.
        K: (3, 3) its intrinsics.
        shape: (H, W) image size in pixels.
        occluders: (N, 3) points that hide what is behind them (everything sensed).
        seen: (S, 3) points sensed so far (a sample near one is seen already).
        seen_m: "near".
        cell_px: z-buffer cell, pixels.
        tolerance_m: a sample within this of its cell's nearest depth is that surface.
        min_range_m: nearer than this is behind the lens.
    """
    h, w = shape
    surface = np.asarray(surface, dtype=np.float64)
    occ = np.asarray(occluders, dtype=np.float64).reshape(-1, 3)
    allp = np.concatenate([surface, occ])
    u, v, z = _project(allp, camera_to_world, K)
    inside = (z > min_range_m) & (u >= -0.5) & (u < w - 0.5) & (v >= -0.5) & (v < h - 0.5)
    gh, gw = -(-h // cell_px), -(-w // cell_px)
    cu = np.clip(np.floor((u + 0.5) / cell_px), 0, gw - 1).astype(np.int64)
    cv = np.clip(np.floor((v + 0.5) / cell_px), 0, gh - 1).astype(np.int64)
    cell = cv * gw + cu
    zbuf = np.full(gh * gw, np.inf)
    np.minimum.at(zbuf, cell[inside], z[inside])
    m = len(surface)
    s_in, s_cell, s_z = inside[:m], cell[:m], z[:m]
    facing = np.einsum("ij,ij->i", normals, camera_to_world[:3, 3] - surface) > 0
    nearest = np.zeros(m, dtype=bool)
    nearest[s_in] = s_z[s_in] <= zbuf[s_cell[s_in]] + tolerance_m
    visible = facing & s_in & nearest
    if not visible.any():
        return 0
    seen = np.asarray(seen, dtype=np.float64).reshape(-1, 3)
    if len(seen):
        d = cKDTree(seen).query(surface[visible], distance_upper_bound=seen_m)[0]
        return int(np.sum(~np.isfinite(d)))
    return int(visible.sum())


def best_view(
    surface: FloatArray,
    normals: FloatArray,
    cameras: Sequence[FloatArray],
    K: FloatArray,
    shape: tuple[int, int],
    occluders: FloatArray,
    seen: FloatArray,
    **kw: float,
) -> tuple[list[int], list[int]]:
    """Candidate cameras ordered best first: (order, unseen-visible count per candidate)."""
    gains = [
        unseen_visible(surface, normals, T, K, shape, occluders, seen, **kw)  # type: ignore[arg-type]
        for T in cameras
    ]
    order = sorted(range(len(cameras)), key=lambda i: -gains[i])
    return order, gains
