"""Meshes the project does not ship, generated with trimesh for the object tests (metres)."""

from __future__ import annotations

import numpy as np
import trimesh


def l_bracket(t: float = 0.01) -> trimesh.Trimesh:
    """An L-shaped bracket: 60 x 40 mm legs, ``t`` (10 mm) thick, 25 mm wide (extruded L)."""
    poly = np.array([[0, 0], [0.06, 0], [0.06, t], [t, t], [t, 0.04], [0, 0.04]], float)
    # fan from the reflex vertex (index 3) sees every other vertex of the L
    faces = np.array([[3, 4, 5], [3, 5, 0], [3, 0, 1], [3, 1, 2]])
    return trimesh.creation.extrude_triangulation(poly, faces, 0.025)


def cylinder() -> trimesh.Trimesh:
    """A 50 mm tall cylinder of radius 20 mm (a can)."""
    return trimesh.creation.cylinder(radius=0.02, height=0.05, sections=48)


def wedge() -> trimesh.Trimesh:
    """A right-triangle prism: 60 x 35 mm triangle, 30 mm wide."""
    pts = [[0, 0, 0], [0.06, 0, 0], [0, 0.035, 0], [0, 0, 0.03], [0.06, 0, 0.03], [0, 0.035, 0.03]]
    return trimesh.convex.convex_hull(np.array(pts, float))


def blob(seed: int = 3) -> trimesh.Trimesh:
    """An asymmetric smooth blob about 6 cm across (icosphere with low-order bumps)."""
    s = trimesh.creation.icosphere(subdivisions=3, radius=0.03)
    rng = np.random.default_rng(seed)
    d = s.vertices / np.linalg.norm(s.vertices, axis=1, keepdims=True)
    bumps = sum(
        a * np.exp(4.0 * (d @ c - 1))
        for a, c in zip(rng.uniform(0.2, 0.5, 4), rng.normal(size=(4, 3)) / 2, strict=True)
    )
    s.vertices = s.vertices * (1 + 0.5 * bumps[:, None]) * [1.0, 0.8, 0.7]
    return s
