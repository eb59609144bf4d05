"""Simulator-free range scans of triangle meshes: vectorised numpy ray casting.

A pinhole range camera at ``eye`` looking at ``look_at`` casts one ray per pixel; the first hit
over the object and any clutter meshes (table, other objects) is the measured point, with
Gaussian range noise along the ray. Misses are NaN in the organised result (the way a Kinect-
style sensor reports them) and dropped from the unorganised one.

The intersection test is Moller-Trumbore rewritten for rays sharing one origin: every quantity
is a matrix product (rays x triangles), computed per 16 x 16-pixel tile over the triangles whose
projected bounding box overlaps the tile. Back-facing triangles are culled (closed meshes).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike

from mks_sim.errors import DataError
from mks_sim.geometry.meshes import Mesh

__all__ = [
    "ScanResult",
    "camera_rays",
    "scan_scene",
    "synthetic_scan",
    "synthetic_scan_organized",
]

_TILE = 16


@dataclass(frozen=True)
class ScanResult:
    """One simulated range image.

    Attributes:
        organized: (H, W, 3) float world-frame points, metres; NaN where the ray missed.
        mesh_index: (H, W) int: 0 = the object, k >= 1 = the k-th extra mesh, -1 = miss.
        range_m: (H, W) float range along the ray (noisy), NaN for misses.
        eye: (3,) camera centre, world frame.
    """

    organized: np.ndarray
    mesh_index: np.ndarray
    range_m: np.ndarray
    eye: np.ndarray

    @property
    def points(self) -> np.ndarray:
        """(N, 3) the hits, row-major pixel order."""
        return self.organized[self.mesh_index >= 0]

    @property
    def labels(self) -> np.ndarray:
        """(N,) int mesh index of each of :attr:`points`."""
        return self.mesh_index[self.mesh_index >= 0]


def _camera_frame(eye: np.ndarray, look_at: np.ndarray, up: np.ndarray) -> np.ndarray:
    fwd = look_at - eye
    n = np.linalg.norm(fwd)
    if n == 0:
        raise DataError("synthetic_scan: eye and look_at coincide")
    fwd = fwd / n
    right = np.cross(fwd, up)
    if np.linalg.norm(right) < 1e-9:  # looking along `up`: any perpendicular will do
        right = np.cross(fwd, [1.0, 0.0, 0.0] if abs(fwd[0]) < 0.9 else [0.0, 1.0, 0.0])
    right /= np.linalg.norm(right)
    down = np.cross(fwd, right)
    return np.stack([right, down, fwd])  # rows: camera x (right), y (down), z (forward)


def camera_rays(
    eye: ArrayLike,
    look_at: ArrayLike,
    width: int,
    height: int,
    fov_deg: float,
    up: ArrayLike = (0.0, 0.0, 1.0),
) -> tuple[np.ndarray, np.ndarray, float]:
    """Unit ray directions of a pinhole camera.

    Args:
        eye, look_at: (3,) world frame, metres.
        width, height: image size, pixels.
        fov_deg: horizontal field of view, degrees.
        up: world direction that appears up in the image.

    Returns:
        dirs (H, W, 3) unit world-frame directions, the (3, 3) world-to-camera rotation, and the
        focal length in pixels.
    """
    eye = np.asarray(eye, float)
    rot = _camera_frame(eye, np.asarray(look_at, float), np.asarray(up, float))
    f = (width / 2) / np.tan(np.radians(fov_deg) / 2)
    u = (np.arange(width) + 0.5 - width / 2) / f
    v = (np.arange(height) + 0.5 - height / 2) / f
    uu, vv = np.meshgrid(u, v)
    cam = np.stack([uu, vv, np.ones_like(uu)], -1)
    cam /= np.linalg.norm(cam, axis=-1, keepdims=True)
    return cam @ rot, rot, f


def _as_world_meshes(
    mesh: Mesh, object_to_world: np.ndarray, extra: Sequence[Mesh | tuple[Mesh, ArrayLike]]
) -> list[Mesh]:
    out = [mesh.transformed(object_to_world)]
    for item in extra:
        if isinstance(item, Mesh):
            out.append(item)
        else:
            m, tf = item
            out.append(m.transformed(np.asarray(tf, float)))
    return out


def scan_scene(
    mesh: Mesh,
    object_to_world: ArrayLike,
    eye: ArrayLike,
    look_at: ArrayLike,
    *,
    width: int = 160,
    height: int = 120,
    fov_deg: float = 45.0,
    noise_sigma: float = 0.0,
    rng: np.random.Generator | None = None,
    extra: Sequence[Mesh | tuple[Mesh, ArrayLike]] = (),
    up: ArrayLike = (0.0, 0.0, 1.0),
    max_range: float = np.inf,
) -> ScanResult:
    """Ray-cast a range image of a mesh (and clutter) from one viewpoint.

    Args:
        mesh: The object, in its own frame.
        object_to_world: (4, 4) pose of the object, column convention.
        eye, look_at: (3,) camera centre and a point it looks at, world frame, metres.
        width, height: image size, pixels.
        fov_deg: horizontal field of view, degrees.
        noise_sigma: standard deviation of Gaussian range noise, metres.
        rng: generator for the noise (default seeded 0).
        extra: clutter: meshes already in the world frame, or (mesh, mesh_to_world) pairs.
        up: world direction that appears up in the image.
        max_range: hits farther than this (metres) count as misses.

    Returns:
        The :class:`ScanResult`.
    """
    tf = np.asarray(object_to_world, float)
    if tf.shape != (4, 4):
        raise DataError(f"synthetic_scan: object_to_world must be (4, 4), got {tf.shape}")
    if width <= 0 or height <= 0:
        raise DataError(f"synthetic_scan: image size must be positive, got {width}x{height}")
    eye = np.asarray(eye, float)
    dirs, rot, f = camera_rays(eye, look_at, width, height, fov_deg, up)
    meshes = _as_world_meshes(mesh, tf, extra)
    tri = np.concatenate([m.triangles for m in meshes])  # (F, 3, 3)
    owner = np.concatenate([np.full(len(m.faces), k) for k, m in enumerate(meshes)])

    v0 = tri[:, 0]
    e1 = tri[:, 1] - v0
    e2 = tri[:, 2] - v0
    normal = np.cross(e1, e2)
    front = np.einsum("ij,ij->i", v0 - eye, normal) < 0  # faces the camera
    tri, owner, v0, e1, e2 = tri[front], owner[front], v0[front], e1[front], e2[front]
    tvec = eye - v0
    a = np.cross(e2, e1)  # det = d . a
    b = np.cross(e2, tvec)  # u * det = d . b
    q = np.cross(tvec, e1)  # v * det = d . q
    t_num = np.einsum("ij,ij->i", e2, q)  # t * det

    # Projected bounding boxes (pixels); triangles reaching behind the camera cover everything.
    cam = (tri - eye) @ rot.T  # (F, 3, 3) camera frame
    z = cam[..., 2]
    behind = (z <= 1e-9).any(axis=1)
    zs = np.where(z > 1e-9, z, 1.0)
    px = cam[..., 0] / zs * f + width / 2
    py = cam[..., 1] / zs * f + height / 2
    x_lo = np.where(behind, -np.inf, px.min(axis=1))
    x_hi = np.where(behind, np.inf, px.max(axis=1))
    y_lo = np.where(behind, -np.inf, py.min(axis=1))
    y_hi = np.where(behind, np.inf, py.max(axis=1))

    best_t = np.full((height, width), np.inf)
    best_k = np.full((height, width), -1, dtype=np.int64)
    for r0 in range(0, height, _TILE):
        r1 = min(height, r0 + _TILE)
        for c0 in range(0, width, _TILE):
            c1 = min(width, c0 + _TILE)
            cand = np.flatnonzero((x_hi >= c0) & (x_lo <= c1) & (y_hi >= r0) & (y_lo <= r1))
            if cand.size == 0:
                continue
            d = dirs[r0:r1, c0:c1].reshape(-1, 3)
            t_best, k_best = _first_hits(d, a[cand], b[cand], q[cand], t_num[cand])
            best_t[r0:r1, c0:c1] = t_best.reshape(r1 - r0, c1 - c0)
            k = np.where(k_best >= 0, cand[np.maximum(k_best, 0)], -1)
            best_k[r0:r1, c0:c1] = k.reshape(r1 - r0, c1 - c0)

    hit = np.isfinite(best_t) & (best_t <= max_range)
    rng = np.random.default_rng(0) if rng is None else rng
    rng_m = np.where(hit, best_t, np.nan)
    if noise_sigma > 0:
        rng_m = rng_m + rng.normal(0.0, noise_sigma, size=rng_m.shape)
    pts = eye + rng_m[..., None] * dirs
    mesh_index = np.where(hit, owner[np.maximum(best_k, 0)], -1)
    return ScanResult(organized=pts, mesh_index=mesh_index, range_m=rng_m, eye=eye)


def _first_hits(
    d: np.ndarray, a: np.ndarray, b: np.ndarray, q: np.ndarray, t_num: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """Nearest hit per ray: (R,) t (inf if none) and (R,) candidate index (-1 if none)."""
    det = d @ a.T  # (R, T)
    u = d @ b.T
    v = d @ q.T
    with np.errstate(divide="ignore", invalid="ignore"):
        inv = 1.0 / det
        u *= inv
        v *= inv
        t = t_num[None, :] * inv
    ok = (np.abs(det) > 1e-15) & (u >= 0) & (v >= 0) & (u + v <= 1) & (t > 1e-9)
    t = np.where(ok, t, np.inf)
    k = np.argmin(t, axis=1)
    tb = t[np.arange(len(d)), k]
    return tb, np.where(np.isfinite(tb), k, -1)


def synthetic_scan(
    mesh: Mesh,
    object_to_world: ArrayLike,
    eye: ArrayLike,
    look_at: ArrayLike,
    width: int = 160,
    height: int = 120,
    fov_deg: float = 45.0,
    noise_sigma: float = 0.0,
    rng: np.random.Generator | None = None,
    extra: Sequence[Mesh | tuple[Mesh, ArrayLike]] = (),
) -> np.ndarray:
    """(N, 3) world-frame points of a simulated range scan (misses dropped).

    See :func:`scan_scene` for the arguments.
    """
    return scan_scene(
        mesh,
        object_to_world,
        eye,
        look_at,
        width=width,
        height=height,
        fov_deg=fov_deg,
        noise_sigma=noise_sigma,
        rng=rng,
        extra=extra,
    ).points


def synthetic_scan_organized(
    mesh: Mesh,
    object_to_world: ArrayLike,
    eye: ArrayLike,
    look_at: ArrayLike,
    width: int = 160,
    height: int = 120,
    fov_deg: float = 45.0,
    noise_sigma: float = 0.0,
    rng: np.random.Generator | None = None,
    extra: Sequence[Mesh | tuple[Mesh, ArrayLike]] = (),
) -> np.ndarray:
    """(H, W, 3) organised scan with NaN for misses (Kinect-style). See :func:`scan_scene`."""
    return scan_scene(
        mesh,
        object_to_world,
        eye,
        look_at,
        width=width,
        height=height,
        fov_deg=fov_deg,
        noise_sigma=noise_sigma,
        rng=rng,
        extra=extra,
    ).organized
