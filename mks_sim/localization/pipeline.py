"""The polyhedral stages over one :class:`~mks_sim.localization.representation.Representation`.

1. :func:`object_segments` — the representation's objects (SPG components, merged when one
   object's self-occlusion split it), without the points a caller set aside (spheres), each
   with its planar regions and vertexes (the table as the face it rests on) from the one
   segmentation of the snapshot;
2. :func:`polyhedral_candidates` — vertex hypotheses (and plane-pair hypotheses when too few
   vertexes are seen) per segment, pre-scored in one batch, ICP on the best few, scored by
   the explained fraction of the segment times the coverage of the expected visible surface.
"""

from __future__ import annotations

import logging
import time
from dataclasses import dataclass, replace
from typing import Any

import numpy as np
from numpy.typing import NDArray

from mks_sim.errors import DataError
from mks_sim.localization.representation import Representation
from mks_sim.models.pose import PoseHypothesis

__all__ = ["Segment", "object_segments", "polyhedral_candidates"]

log = logging.getLogger(__name__)
FloatArray = NDArray[np.float64]
IntArray = NDArray[np.intp]

#: Part of a model's surface one view is assumed to show at least (see
#: :data:`mks_sim.localize.VISIBLE_FRACTION`).
VISIBLE_FRACTION = 0.2
#: Scene points of a segment the candidates' full ICP and scores use (a random subset; the
#: final polish of the best candidate uses up to 1000 near it).
ICP_POINTS = 500
#: Scene points of the coarse ICP stage (6 iterations from every pre-screened start).
COARSE_POINTS = 300


@dataclass(frozen=True, eq=False)
class Segment:
    """One object segment of a representation.

    Attributes:
        indices: (n,) indices into ``rep.objects``.
        points: (n, 3) its points.
        planes: its planar regions (indices into ``rep.objects``).
        vertexes: its vertexes (``Vertexes``).
        on_table: the table was used as a face.
    """

    indices: IntArray
    points: FloatArray
    planes: tuple[Any, ...]
    vertexes: Any
    on_table: bool


def object_segments(
    rep: Representation,
    model_size: float,
    *,
    keep: NDArray[np.bool_] | None = None,
    min_points: int = 60,
    gap: float | None = None,
    merge: bool = True,
) -> list[Segment]:
    """Object segments of ``rep`` for a model of diameter ``model_size``.

    Args:
        rep: the representation.
        model_size: the model's diameter (components that one object could span are merged).
        keep: (K,) mask over ``rep.objects`` of the points to use (points set aside, e.g. on
            a detected sphere, are dropped from the segments).
        min_points: smaller segments are ignored.
        gap: SPG edges up to this join points into one segment (default: 4 spacings, at most
            the representation's gap).
        merge: merge components that one object could span (self-occlusion splits).
    """
    from scipy import sparse
    from scipy.sparse import csgraph

    from mks_sim.localize import _merge_components
    from mks_sim.lowlevel.vertexes import plane_vertexes

    objects = rep.objects
    if len(objects) < min_points:
        return []
    mask = np.ones(len(objects), dtype=bool) if keep is None else keep
    idx = np.flatnonzero(mask)
    if len(idx) < min_points:
        return []
    # Components of the kept points over short SPG edges (4 spacings): a sphere set aside
    # no longer bridges the cube it rests on to its other neighbours.
    adj = sparse.csr_array(rep.graph.adjacency).tocoo()
    gap = min(rep.gap, 4.0 * rep.spacing) if gap is None else gap
    link = mask[adj.row] & mask[adj.col] & (adj.data <= gap)
    pos = np.full(len(objects), -1, dtype=np.intp)
    pos[idx] = np.arange(len(idx))
    joined = sparse.csr_array(
        (np.ones(int(link.sum())), (pos[adj.row[link]], pos[adj.col[link]])),
        shape=(len(idx), len(idx)),
    )
    _, comp = csgraph.connected_components(joined, directed=True, connection="weak")
    merged = np.asarray(comp, dtype=np.intp)
    if merge:
        merged = _merge_components(objects[idx], merged, model_size)
    sizes = np.bincount(merged)
    member_of = np.full(len(objects), -1, dtype=np.intp)
    member_of[idx] = merged
    tol = 4.0 * max(rep.spacing, rep.segmentation.spacing, 1e-4)
    out: list[Segment] = []
    for c in np.argsort(-sizes, kind="stable"):
        if sizes[c] < min_points:
            break
        members = idx[merged == c]
        seg_pts = objects[members]
        planes = [
            r
            for r in rep.segmentation.planes
            if len(r.indices) >= rep.config.min_region_points
            and np.mean(member_of[r.indices] == c) >= 0.5
        ]
        on_table = False
        if rep.table is not None:
            d = float(np.min(rep.table.distance(seg_pts)))
            on_table = d <= rep.table_threshold + 4.0 * rep.spacing
        verts = plane_vertexes(
            planes,
            objects,
            extra_planes=[rep.table.flipped()] if on_table and rep.table is not None else [],
            tolerance=tol,
        )
        out.append(Segment(members, seg_pts, tuple(planes), verts, on_table))
    return out


def polyhedral_candidates(
    model: Any,
    rep: Representation,
    segments: list[Segment],
    *,
    rng: np.random.Generator,
    min_score: float = 0.5,
    max_icp: int = 8,
    prescreen: int = 4,
    max_hypotheses: int = 30,
    rotinv: bool = False,
    timing: dict[str, float] | None = None,
) -> tuple[list[PoseHypothesis], list[int]]:
    """Verified candidates of a polyhedral model over the segments, best score first.

    Segments showing less than 5 % of the model's area (points x spacing^2) are skipped;
    ``rotinv`` adds the rotation-invariant Hough over each segment's vertexes (off: the
    workstation runs it on the model's logical sensor).

    Returns:
        (hypotheses, segment index of each).
    """
    from mks_sim.localization.hypotheses import plane_pair_hypotheses, vertex_hypotheses
    from mks_sim.localize import _diverse_planes
    from mks_sim.models.refine import verify_hypotheses

    timing = {} if timing is None else timing
    surface = model.surface
    syms = model.symmetries()
    spacing = rep.spacing
    from mks_sim.localization.verify import surface_coverage

    # the model's area: uniform samples have a median nearest-neighbour distance of
    # 0.47 / sqrt(density)
    model_area = len(surface.points) * (surface.spacing / 0.47) ** 2

    results: list[tuple[PoseHypothesis, int]] = []
    t_hyp = t_ver = 0.0
    for si, seg in enumerate(segments):
        seg_pts = seg.points
        noise = float(np.median([p.plane.rmse for p in seg.planes])) if seg.planes else 0.0
        inlier = max(1.0 * spacing, rep.voxel, 3.0 * noise)
        t = time.perf_counter()
        if len(seg_pts) * spacing**2 < 0.25 * VISIBLE_FRACTION * model_area:
            continue  # shows under 5 % of the model's area: a fragment, not the object
        hyps = vertex_hypotheses(
            model, seg.vertexes, seg_pts, vote_distance=4 * spacing, rotinv=rotinv
        )
        t_hyp += time.perf_counter() - t
        t = time.perf_counter()
        verified = verify_hypotheses(
            hyps,
            surface,
            seg_pts,
            inlier_distance=inlier,
            symmetries=syms,
            max_icp=max_icp,
            prescreen=prescreen,
            full_refine=2,
            max_scene_points=ICP_POINTS,
            coarse_points=COARSE_POINTS,
            rng=rng,
        )
        t_ver += time.perf_counter() - t
        best = verified[0].hypothesis.score if verified else 0.0
        if best < min_score and seg.planes:
            t = time.perf_counter()
            pairs: list[tuple[Any, FloatArray | None]] = [
                (r.plane, rep.objects[r.indices]) for r in _diverse_planes(list(seg.planes))
            ]
            if seg.on_table and rep.table is not None:
                pairs.append((rep.table.flipped(), None))
            try:
                coarse = plane_pair_hypotheses(model, pairs, seg_pts, inlier_distance=inlier)
            except DataError as exc:
                log.info("plane-pair hypotheses failed: %s", exc)
                coarse = []
            t_hyp += time.perf_counter() - t
            t = time.perf_counter()
            verified += verify_hypotheses(
                coarse,
                surface,
                seg_pts,
                inlier_distance=inlier,
                icp_distance=max(4 * inlier, 0.1 * surface.size),
                symmetries=syms,
                max_icp=max(4, max_icp // 2),
                prescreen=prescreen,
                full_refine=2,
                max_scene_points=ICP_POINTS,
                coarse_points=COARSE_POINTS,
                rng=rng,
            )
            t_ver += time.perf_counter() - t
        # coverage of the model's surface at its own sampling: density independent
        if verified:
            from scipy.spatial import cKDTree

            cover = surface_coverage(
                surface.points,
                np.stack([v.hypothesis.matrix for v in verified]),
                cKDTree(seg_pts),
                max(inlier, 1.5 * spacing, rep.voxel),
            )
        for k, v in enumerate(verified):
            coverage = min(1.0, float(cover[k]) / VISIBLE_FRACTION)
            results.append((replace(v.hypothesis, score=v.hypothesis.score * coverage), si))
    results.sort(key=lambda r: (-r[0].score, r[0].rmse))
    results = results[:max_hypotheses]
    timing["hypotheses"] = timing.get("hypotheses", 0.0) + t_hyp
    timing["verification"] = timing.get("verification", 0.0) + t_ver
    return [r[0] for r in results], [r[1] for r in results]
