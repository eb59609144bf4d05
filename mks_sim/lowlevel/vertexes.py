"""Vertexes of a polyhedron from triples of its face planes, supported by the data (section 2.2).

"The planar faces of the detected object are then intersected to find the vertexes of the
object." Every triple of planes whose normals are far from coplanar meets in one point; only
points that lie near the observed points of each of the three faces are kept (an intersection
of three face planes far from one of the faces is not a corner of the object). A plane the data
do not sample, e.g. the table an object rests on, can be passed as an extra face: it is trusted
without support (the vertex lies on it by construction).
"""

from __future__ import annotations

import itertools
import logging
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike, NDArray
from scipy.spatial import cKDTree

from mks_sim.errors import DataError
from mks_sim.lowlevel import _gridknn
from mks_sim.lowlevel.regions import PlanarRegion, Plane

__all__ = ["Vertexes", "plane_vertexes"]

log = logging.getLogger(__name__)
FloatArray = NDArray[np.float64]


@dataclass(frozen=True, eq=False)
class Vertexes:
    """Detected vertexes.

    Attributes:
        points: (V, 3) vertex positions.
        faces: (V, 3) int plane indices meeting at each vertex: indices < len(regions) refer
            to the regions, ``len(regions) + j`` to ``extra_planes[j]``.
        normals: (V, 3, 3) the three face normals of each vertex (rows, in ``faces`` order),
            oriented as the planes are.
        support: (V,) float, the largest of the distances from the vertex to the nearest
            observed point of each of its (region) faces.
    """

    points: FloatArray
    faces: NDArray[np.intp]
    normals: FloatArray
    support: FloatArray

    def __len__(self) -> int:
        return len(self.points)


#: Point-candidate pairs up to which :func:`_nearest_distances` compares all of them.
_BRUTE_PAIRS = 200_000


def _nearest_distances(points: FloatArray, queries: FloatArray) -> FloatArray:
    """(Q,) distance from each query to its nearest point, as ``cKDTree(points).query``
    computes it (``sqrt((dx*dx + dy*dy) + dz*dz)``, the point minus the query): by all
    pairs for a face's few hundred points and a few candidates (no tree to build), by the
    tree beyond :data:`_BRUTE_PAIRS` pairs."""
    if len(points) == 0:
        return np.full(len(queries), np.inf)  # (the tree's answer: no neighbour)
    if len(points) * len(queries) > _BRUTE_PAIRS or points.shape[1] != 3:
        return np.asarray(cKDTree(points, balanced_tree=False).query(queries)[0])
    # (Q, P): each query's row reduced along its contiguous axis (the squares do not depend
    # on the sign of the difference)
    d = queries[:, None, 0] - points[None, :, 0]
    sq = d * d
    d = queries[:, None, 1] - points[None, :, 1]
    sq += d * d
    d = queries[:, None, 2] - points[None, :, 2]
    sq += d * d
    return np.asarray(np.sqrt(sq.min(axis=1)))


def plane_vertexes(
    regions: Sequence[PlanarRegion],
    points: ArrayLike,
    *,
    extra_planes: Sequence[Plane] = (),
    tolerance: float,
    min_angle_deg: float = 30.0,
    merge_distance: float | None = None,
) -> Vertexes:
    """Intersect triples of face planes; keep the intersections supported by the data.

    Args:
        regions: planar regions (faces) of one object, indices into ``points``.
        points: (N, 3) the cloud the regions index.
        extra_planes: planes trusted as faces without data support, e.g. the table under the
            object (normal pointing out of the object, i.e. down into the table).
        tolerance: a vertex must lie within this distance of an observed point of each of its
            region faces (a few sampling spacings: points within ~2 spacings of an edge get
            blurred normals and drop out of the faces).
        min_angle_deg: each pair of the three normals must be at least this far from
            parallel, and the triple must not be near-coplanar (|det| >= sin of it).
        merge_distance: vertexes closer than this are merged (more than three faces meeting);
            default ``tolerance / 2``.

    Returns:
        :class:`Vertexes` (possibly empty).
    """
    pts = np.asarray(points, dtype=np.float64)
    if pts.ndim != 2 or pts.shape[1] != 3:
        raise DataError(f"plane_vertexes: expected (N, 3) points, got {pts.shape}")
    if tolerance <= 0:
        raise DataError(f"plane_vertexes: tolerance must be > 0, got {tolerance}")
    planes = [r.plane for r in regions] + list(extra_planes)
    n_regions = len(regions)
    sin_min = np.sin(np.radians(min_angle_deg))
    V = np.zeros((0, 3))
    T = np.zeros((0, 3), dtype=np.intp)  # the candidates' (positions, face triples)
    triples = _triples(len(planes), n_regions)
    if len(triples):
        normals = np.stack([p.normal for p in planes])
        offsets = np.array([p.offset for p in planes])
        N = normals[triples]  # (C, 3, 3)
        # |n_a x n_b| of each pair: np.cross's products and differences and the norm's
        # three squares in order, on columns (the same values, without np.cross's dispatch)
        x, y, z = N[..., 0], N[..., 1], N[..., 2]  # (C, 3) each
        pair_sin = np.empty((len(N), 3))
        for k, (a, b) in enumerate(((0, 1), (0, 2), (1, 2))):
            c0 = y[:, a] * z[:, b] - z[:, a] * y[:, b]
            c1 = z[:, a] * x[:, b] - x[:, a] * z[:, b]
            c2 = x[:, a] * y[:, b] - y[:, a] * x[:, b]
            pair_sin[:, k] = np.sqrt(c0 * c0 + c1 * c1 + c2 * c2)
        ok = (pair_sin.min(axis=1) >= sin_min) & (np.abs(np.linalg.det(N)) >= sin_min * sin_min)
        V = np.linalg.solve(N[ok], offsets[triples[ok]][..., None])[..., 0]  # (C', 3)
        T = triples[ok]
    # Support: per face, the nearest of its points to each candidate it takes part in
    # (compiled: every candidate's faces in one pass, the same distances to the bit).
    worst = np.zeros(len(V))
    if len(V) and _gridknn.available():
        ridx = [np.asarray(r.indices, dtype=np.int64) for r in regions]
        rstart = np.zeros(n_regions + 1, dtype=np.int64)
        np.cumsum([len(r) for r in ridx], out=rstart[1:])
        worst = _gridknn._load()["face_support"](
            np.ascontiguousarray(pts, dtype=np.float64),
            np.concatenate(ridx) if ridx else np.zeros(0, np.int64), rstart,
            np.ascontiguousarray(V, dtype=np.float64), T.astype(np.int64), n_regions,
        )  # fmt: skip
    else:
        for t in range(n_regions):
            mine = np.flatnonzero((T == t).any(axis=1))
            if len(mine):
                dist = _nearest_distances(pts[regions[t].indices], V[mine])
                worst[mine] = np.maximum(worst[mine], dist)
    # supported, least worst first (a stable sort), each kept unless within the merge
    # distance of one kept before it (more than three faces meeting)
    found = np.flatnonzero(worst <= tolerance)
    found = found[np.argsort(worst[found], kind="stable")]
    merge = tolerance / 2 if merge_distance is None else merge_distance
    kept: list[int] = []
    for i in found.tolist():
        if all(np.linalg.norm(V[i] - V[k]) > merge for k in kept):
            kept.append(i)
    log.debug(
        "plane_vertexes: %d planes, %d candidates, %d kept", len(planes), len(found), len(kept)
    )
    if not kept:
        return Vertexes(
            np.zeros((0, 3)), np.zeros((0, 3), np.intp), np.zeros((0, 3, 3)), np.zeros(0)
        )
    faces = T[kept].astype(np.intp)
    return Vertexes(
        points=V[kept],
        faces=faces,
        normals=np.stack([p.normal for p in planes])[faces],
        support=worst[kept].astype(np.float64),
    )


def _triples(n_planes: int, n_regions: int) -> NDArray[np.intp]:
    """(C, 3) the index triples of ``n_planes`` planes in combination order with at most
    one extra plane (index >= ``n_regions``) each."""
    if n_planes < 3:
        return np.zeros((0, 3), dtype=np.intp)
    t = np.array(list(itertools.combinations(range(n_planes), 3)), dtype=np.intp)
    return t[(t >= n_regions).sum(axis=1) <= 1]
