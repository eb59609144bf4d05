"""Symmetries of a mesh: the rotations that map its surface onto itself (issue 10).

Candidate axes through the solid's centroid are its principal axes and the normals of its
largest flat facets; about each, rotations of order 2..8 are tested, plus two irrational
angles that reveal a continuous (axial) symmetry. A rotation passes when the rotated surface
samples land on the surface (nearest sample within a tolerance, normals agreeing). The passing
rotations are closed under composition (a cube's 3-fold axes come from its 4-fold ones).
"""

from __future__ import annotations

import math

import numpy as np
from numpy.typing import NDArray
from scipy.spatial import cKDTree

from mks_sim.geometry.meshes import Mesh, sample_surface

__all__ = ["detect_symmetries", "is_symmetry"]

FloatArray = NDArray[np.float64]

_ORDERS = (2, 3, 4, 5, 6, 8)
_PROBES_DEG = (23.0, 71.0)  # no finite group of a mesh has these angles: continuous
MAX_GROUP = 120


class _Surface:
    def __init__(self, mesh: Mesh, n_ref: int = 20000, n_test: int = 1500) -> None:
        rng = np.random.default_rng(0)
        self.centre = np.asarray(mesh.centroid, dtype=np.float64)
        self.ref, self.ref_n = sample_surface(mesh, n_ref, rng=rng)
        self.test, self.test_n = sample_surface(mesh, n_test, rng=rng)
        self.tree = cKDTree(self.ref)
        spacing = math.sqrt(mesh.area / n_ref)
        extent = float(np.max(mesh.bounds[1] - mesh.bounds[0]))
        self.tol = max(1.5 * spacing, 0.003 * extent)

    def passes(self, R: FloatArray) -> bool:
        p = (self.test - self.centre) @ R.T + self.centre
        d, i = self.tree.query(p, distance_upper_bound=4 * self.tol)
        if not np.all(np.isfinite(d)) or np.quantile(d, 0.99) > self.tol:
            return False
        agree = np.einsum("ij,ij->i", self.test_n @ R.T, self.ref_n[i])
        return bool(np.mean(agree > 0.7) > 0.97)


def _rot(axis: FloatArray, deg: float) -> FloatArray:
    from scipy.spatial.transform import Rotation

    return Rotation.from_rotvec(axis / np.linalg.norm(axis) * math.radians(deg)).as_matrix()


def _facet_normals(mesh: Mesh, k: int = 8) -> list[FloatArray]:
    """Normals of the largest flat facets (area-weighted clusters of face normals)."""
    n = mesh.normals
    a = mesh.face_areas
    keys = np.round(n, 2)
    uniq, inv = np.unique(keys, axis=0, return_inverse=True)
    area = np.bincount(inv.ravel(), weights=a, minlength=len(uniq))
    out = []
    for j in np.argsort(area)[::-1][:k]:
        if area[j] < 0.01 * a.sum():
            break
        v = (n[inv.ravel() == j] * a[inv.ravel() == j, None]).sum(axis=0)
        out.append(v / np.linalg.norm(v))
    return out


def _unique(rots: list[FloatArray]) -> list[FloatArray]:
    out: list[FloatArray] = []
    for R in rots:
        if not any(np.abs(R - Q).max() < 1e-3 for Q in out):
            out.append(R)
    return out


def is_symmetry(mesh: Mesh, rotation: FloatArray) -> bool:
    """True when ``rotation`` about the mesh's centroid maps its surface onto itself."""
    return _Surface(mesh).passes(np.asarray(rotation, dtype=np.float64))


def detect_symmetries(mesh: Mesh) -> FloatArray:
    """(S, 4, 4) transforms (rotations about the centroid) mapping ``mesh`` onto itself.

    The identity comes first. A continuous symmetry about an axis is sampled every degree
    (with the 180-degree flips that also pass).
    """
    surf = _Surface(mesh)
    _, vecs = np.linalg.eigh(mesh.inertia())
    axes = [vecs[:, j] for j in range(3)] + _facet_normals(mesh)
    uniq_axes: list[FloatArray] = []
    for a in axes:
        if not any(abs(float(a @ b)) > 0.999 for b in uniq_axes):
            uniq_axes.append(a)
    found: list[FloatArray] = [np.eye(3)]
    continuous: FloatArray | None = None
    for a in uniq_axes:
        if continuous is None and all(surf.passes(_rot(a, d)) for d in _PROBES_DEG):
            continuous = a
            continue
        for k in _ORDERS:
            R = _rot(a, 360.0 / k)
            if surf.passes(R):
                found.append(R)
    if continuous is not None:
        ring = [_rot(continuous, float(d)) for d in range(360)]
        # A 180-degree turn about an axis perpendicular to the continuous one reverses it.
        flips = [R for R in found[1:] if np.allclose(R @ continuous, -continuous, atol=1e-3)]
        group = ring + ([Q @ flips[0] for Q in ring] if flips else [])
    else:
        group = _unique(found)
        grew = True
        while grew and len(group) < MAX_GROUP:
            grew = False
            for A in list(group):
                for B in list(group):
                    C = A @ B
                    if not any(np.abs(C - Q).max() < 1e-3 for Q in group):
                        group.append(C)
                        grew = True
    c = surf.centre
    out = np.tile(np.eye(4), (len(group), 1, 1))
    for i, R in enumerate(group):
        out[i, :3, :3] = R
        out[i, :3, 3] = c - R @ c
    return out
