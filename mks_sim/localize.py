"""Localize a model in a 3-D point cloud: the simulator-free pipeline (paper sections 2.2, 4).

The code lives in the engine package :mod:`mks_sim.localization` (``model``: the protocol,
:class:`PolyhedralModel`, :func:`load_model`; ``hypotheses``: vertex, plane-pair and
rotation-invariant hypotheses; ``pipeline``: :func:`localize_cloud`); this module re-exports
it so that old imports keep working.

The execution flow of section 4, on one recorded cloud:

1. build the spatial proximity graph (SPG) of the scene; remove the dominant table plane (if
   the objects rest on one) and split the rest into objects by SPG connectivity ("separated
   out ... by the connectivity of the spatial proximity graph", section 4.1);
2. group each object on its SPG: normals, planar regions, vertexes from triples of face planes
   (the table counts as the face the object rests on);
3. match: model vertexes against detected vertexes. A detected vertex carries its three face
   normals, so matching one vertex to one model corner fixes the whole pose (a Hough vote in
   pose space, counted over the other vertexes); with three or more detected vertexes the
   rotation-invariant 3-D Hough of section 2.2.1 adds its maxima;
4. refine every distinct candidate with point-to-plane ICP of the model surface, score it
   (inlier fraction, residual), rank, and report symmetric equivalents once.

A model that can be localized implements :class:`LocalizableModel`; :class:`PolyhedralModel`
is the built-in one (from a mesh, a point file, or vertexes), and other rooms (e.g. a free-form
model) implement the protocol themselves.
"""

from __future__ import annotations

from mks_sim.localization.hypotheses import plane_pair_hypotheses, vertex_hypotheses
from mks_sim.localization.model import (
    Corner,
    LocalizableModel,
    ModelFace,
    PolyhedralModel,
    adapt_model,
    load_model,
)
from mks_sim.localization.pipeline import (
    VISIBLE_FRACTION,
    Localization,
    SegmentReport,
    localize_cloud,
)

__all__ = [
    "VISIBLE_FRACTION",
    "Corner",
    "LocalizableModel",
    "Localization",
    "ModelFace",
    "PolyhedralModel",
    "SegmentReport",
    "adapt_model",
    "load_model",
    "localize_cloud",
    "plane_pair_hypotheses",
    "vertex_hypotheses",
]
