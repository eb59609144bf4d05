"""Grouping on the spatial proximity graph (paper sections 1.2, 2.2, 4.1): the public surface.

The work is split by concept:

- :mod:`mks_sim.lowlevel.normals` — PCA normals, surface variation, the Surface_Curvature code
  (+1 curved, -1 planar, Table 4-5).
- :mod:`mks_sim.lowlevel.regions` — region growing into planar and curved regions, robust
  plane (iterative re-weighting, RANSAC) and sphere (algebraic + geometric) fits.
- :mod:`mks_sim.lowlevel.vertexes` — vertexes from triples of supported face planes.
"""

from __future__ import annotations

from mks_sim.lowlevel.normals import (
    DEFAULT_CURVATURE_THRESHOLD,
    SurfaceNormals,
    build_graph,
    curvature_code,
    estimate_normals,
    neighbour_table,
)
from mks_sim.lowlevel.regions import (
    CurvedRegion,
    PlanarRegion,
    Plane,
    Segmentation,
    SphereFit,
    fit_plane,
    fit_plane_ransac,
    fit_sphere,
    grow_planar_regions,
    median_spacing,
    segment_surfaces,
)
from mks_sim.lowlevel.vertexes import Vertexes, plane_vertexes

__all__ = [
    "DEFAULT_CURVATURE_THRESHOLD",
    "CurvedRegion",
    "PlanarRegion",
    "Plane",
    "Segmentation",
    "SphereFit",
    "SurfaceNormals",
    "Vertexes",
    "build_graph",
    "curvature_code",
    "estimate_normals",
    "fit_plane",
    "fit_plane_ransac",
    "fit_sphere",
    "grow_planar_regions",
    "median_spacing",
    "neighbour_table",
    "plane_vertexes",
    "segment_surfaces",
]
