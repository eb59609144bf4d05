"""The polyhedral stages over one :class:`~mks_sim.localization.representation.Representation`.

1. :func:`object_segments` — the representation's objects (SPG components, merged when one
   object's self-occlusion split it), without the points a caller set aside (spheres), each
   with its planar regions and vertexes (the table as the face it rests on) from the one
   segmentation of the snapshot;
2. :func:`polyhedral_candidates` — vertex hypotheses (and plane-pair hypotheses when too few
   vertexes are seen) per segment, pre-scored in one batch, ICP on the best few, scored by
   the explained fraction of the segment times the coverage of the expected visible surface;
3. :func:`localize_polyhedral` / :func:`localize_sphere` — the workstation's paths over a
   snapshot (chosen by the model's kind): spheres set aside, candidates, the model's own
   logical sensor, consistency over the whole cloud, support faces, polish;
4. :func:`localize_cloud` — the simulator-free pipeline on one recorded cloud (its own table,
   objects, grouping and matching; :mod:`mks_sim.localize` re-exports it).
"""

from __future__ import annotations

import functools
import itertools
import logging
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any, Literal

import numpy as np
from numpy.typing import ArrayLike, NDArray
from scipy import sparse
from scipy.spatial import cKDTree

from mks_sim.errors import DataError, MksError
from mks_sim.io.units import check_scale
from mks_sim.localization.hypotheses import (
    plane_pair_hypotheses,
    rested_pose,
    rotation_about,
    score_spheres,
    sphere_centre_hough,
    support_face_hypotheses,
    support_normals,
    vertex_hypotheses,
)
from mks_sim.localization.model import LocalizableModel, PolyhedralModel, default_db, load_model
from mks_sim.localization.representation import (
    Representation,
    spacing_and_noise,
    voxel_average,
    voxel_average_cells,
)
from mks_sim.localization.verify import Consistency, NearPoints, consistency, find_table, rank
from mks_sim.lowlevel._gridknn import (
    column_bounds,
    column_mean,
    masked_components,
    norm_within,
    row_norms,
    weak_components,
)
from mks_sim.lowlevel.grouping import (
    PlanarRegion,
    Plane,
    Segmentation,
    Vertexes,
    build_graph,
    plane_vertexes,
    segment_surfaces,
)
from mks_sim.models.pose import PoseHypothesis
from mks_sim.models.refine import (
    ModelSurface,
    batch_inlier_fractions,
    group_equivalent,
    icp_point_to_plane,
    merge_verified,
    principal_half_turns,
    score_pose,
    verify_hypotheses,
)
from mks_sim.threads import with_one_blas_thread

__all__ = [
    "VISIBLE_FRACTION",
    "Localization",
    "Segment",
    "SegmentReport",
    "localize_cloud",
    "localize_polyhedral",
    "localize_sphere",
    "object_segments",
    "polyhedral_candidates",
]

log = logging.getLogger(__name__)
FloatArray = NDArray[np.float64]
IntArray = NDArray[np.intp]

#: Part of a model's surface one view is assumed to show at least (a cube seen obliquely
#: shows ~1/2, the industrial part from above ~1/3); a hypothesis under which fewer of the
#: model's surface samples than this share have a scene point nearby has its score scaled down.
VISIBLE_FRACTION = 0.2

#: Scene points of a segment the candidates' full ICP and scores use (a random subset; the
#: final polish of the best candidate uses up to 1000 near it).
ICP_POINTS = 800
#: Scene points of the coarse ICP stage (6 iterations from every pre-screened start).
COARSE_POINTS = 300
#: The candidates' full ICP stops once its RMS residual fell by less than 0.1 % over this many
#: iterations (``stall`` of :func:`~mks_sim.models.refine.icp_point_to_plane`). Healthy
#: cube, tuning seeds 1000-1009: the full ICPs' time 12.5 -> 7.0 ms per localization;
#: tuning seeds 1000-1029, every object and mode: success and median errors unchanged.
ICP_STALL = 4
#: How a polyhedral model's candidates are verified (the workstation's and, unless
#: ``thorough``, ``localize_cloud``'s): the starts pre-scored in one batch, the best 4 get 6
#: coarse ICP iterations on :data:`COARSE_POINTS` points, the best 2 the full ICP on
#: :data:`ICP_POINTS`.
POLYHEDRAL_VERIFY: dict[str, Any] = {
    "prescreen": 4,
    "full_refine": 2,
    "max_scene_points": ICP_POINTS,
    "coarse_points": COARSE_POINTS,
    "icp_stall": ICP_STALL,
}
#: :func:`localize_cloud`'s ICPs run their iterations in one compiled call
#: (``icp_point_to_plane(fused=True)``: 2-2.6x faster, poses within 1e-15 of the loop's;
#: the tuning scans' localizations 5 % faster, up to 9 % for the part, the same successes
#: and median errors). The workstation's path runs them too (:data:`WORKSTATION_COMPILED`).
FUSED_ICP = True
#: :func:`localize_cloud`'s verification: the workstation's settings, but only the two best
#: prescreened starts refined (the workstation refines four). On the tuning scans of the
#: industrial part (``benchmarks/localize.py``'s rows, 56 at seeds 777+ and 112 at 5000+):
#: the same successes (54 and 110 with four, 54 and 111 with two), the same median errors,
#: 7-14 % less time. When both score under ``min_score`` the fallbacks run.
CLOUD_VERIFY: dict[str, Any] = {
    **POLYHEDRAL_VERIFY,
    "prescreen": 2,
    "icp_fused": FUSED_ICP,
    "compiled_score": FUSED_ICP,  # (score_pose in one compiled pass, its last bits its own)
}
#: The workstation's polyhedral path runs the compiled passes :func:`localize_cloud` runs
#: (each falls back to numpy without numba): the corner and plane-pair poses in one pass,
#: the ICPs' iterations fused, the scores compiled. The same steps; the rounding of the
#: poses may differ by ~1e-15 (tuning seeds 1000-1019, 75 localizations of the cube, the
#: part and the sphere: the same results to the reported digits; 15 % less processing for
#: the cube and the part).
WORKSTATION_COMPILED = FUSED_ICP
#: The options of the workstation's ICPs and scores (:data:`WORKSTATION_COMPILED`).
COMPILED_VERIFY: dict[str, Any] = {
    "icp_fused": WORKSTATION_COMPILED,
    "compiled_score": WORKSTATION_COMPILED,
}
#: A polyhedral pose that leaves more off-table points in its bounding sphere unexplained
#: than this fraction of the points it explains covers only part of an object (a cube pose
#: around the lower part of a taller box): not accepted (not found rather than a wrong pose).
#: Chosen on tuning seeds 1000-1049: true cube poses left at most 0.08 unexplained with all
#: devices, 0.20 with the stereo pair (seed 1031: 205 / 1039; the sphere on the cube counts);
#: the wrong box poses 0.24-0.28 (stereo pair, seeds 1005, 1008, 1026, 1040, 1046); the part
#: about 0.02. A narrow margin: see docs/localization.md.
MAX_UNEXPLAINED = 0.22
#: The final polish (a full ICP of the best pose) replaces its start when still consistent
#: with at least this fraction of the start's net support: the two are one pose and a few
#: points either way are noise (stereo cube, tuning seed 6: 1198 vs 1203).
POLISH_KEEP = 0.98
#: A best pose whose support face is within this many degrees of facing the table, its lowest
#: point within :data:`REST_GAP_D` inlier distances of the table, is turned to rest on that
#: face and refined turning about the face's normal only (:func:`_rest`). Chosen, not tuned:
#: a free ICP tilted the stereo cube up to 7 deg (tuning seeds 1044, 1063).
REST_TILT_DEG = 10.0
REST_GAP_D = 2.0
#: The rested pose replaces the best when consistent with at least this fraction of its net
#: support (the tilt the noise gave it explained a few more noisy points).
REST_KEEP = 0.9
#: How many of the best-ranked candidates are set to rest.
REST_BEST = 3


@dataclass(frozen=True, eq=False)
class Segment:
    """One object segment of a representation.

    Attributes:
        indices: (n,) indices into ``rep.objects``.
        points: (n, 3) its points.
        planes: its planar regions (indices into ``rep.objects``).
        on_table: the table was used as a face.
        rep: the representation it is a segment of (None: a segment without vertexes).
    """

    indices: IntArray
    points: FloatArray
    planes: tuple[Any, ...]
    on_table: bool
    rep: Representation | None = field(default=None, repr=False)

    @functools.cached_property
    def vertexes(self) -> Any:
        """Its vertexes (``Vertexes``; None without a representation), its planes intersected
        on first use: the segments after the one that settles the answer never need them."""
        if self.rep is None:
            return None
        return self.rep.plane_vertexes(self.planes, self.on_table)


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
    objects = rep.objects
    if len(objects) < min_points:
        return []
    mask = np.ones(len(objects), dtype=bool) if keep is None else keep
    idx = np.flatnonzero(mask)
    if len(idx) < min_points:
        return []
    # Components of the kept points over short SPG edges (4 spacings): a sphere set aside
    # no longer bridges the cube it rests on to its other neighbours.
    gap = min(rep.gap, 4.0 * rep.spacing) if gap is None else gap
    merged = masked_components(rep.spg_adjacency, mask, gap)[1][idx]
    if merge:
        merged = _merge_components(objects[idx], merged, model_size)
    sizes = np.bincount(merged)
    member_of = np.full(len(objects), -1, dtype=np.intp)
    member_of[idx] = merged
    # each plane's fraction of points in each segment (one count per plane, not per pair)
    regions = [r for r in rep.segmentation.planes if len(r.indices) >= rep.config.min_region_points]
    share = [
        np.bincount(member_of[r.indices] + 1, minlength=len(sizes) + 1)[1:] / len(r.indices)
        for r in regions
    ]
    out: list[Segment] = []
    for c in np.argsort(-sizes, kind="stable"):
        if sizes[c] < min_points:
            break
        members = idx[merged == c]
        seg_pts = objects[members]
        planes = [r for r, f in zip(regions, share, strict=True) if f[c] >= 0.5]
        out.append(Segment(members, seg_pts, tuple(planes), rep.touches_table(seg_pts), rep))
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
    settled: Callable[[list[PoseHypothesis]], bool] | None = None,
) -> tuple[list[PoseHypothesis], list[int]]:
    """Verified candidates of a polyhedral model over the segments, best score first.

    Segments showing less than 5 % of the model's area (points x spacing^2) are skipped;
    ``rotinv`` adds the rotation-invariant Hough over each segment's vertexes (off: the
    workstation runs it on the model's logical sensor). Segments are verified in the order
    of their vertex hypotheses' best pre-score (:data:`PROMISE_POINTS` of their points
    explained in one batch) and, when ``settled`` is given, the rest are skipped once it
    says the candidates so far hold the answer.

    Returns:
        (hypotheses, segment index of each).
    """
    timing = {} if timing is None else timing
    surface = model.surface
    syms = model.symmetries()
    spacing = rep.spacing
    # the model's area: uniform samples have a median nearest-neighbour distance of
    # 0.47 / sqrt(density)
    model_area = len(surface.points) * (surface.spacing / 0.47) ** 2

    t_hyp = t_ver = 0.0
    # the pre-scores' own draws: what is verified does not depend on how many were computed
    promise_rng = np.random.default_rng(rng.integers(2**63))

    def plan(si: int) -> Plan | None:
        """Segment ``si``'s vertex hypotheses and how well the best of them explains it."""
        seg = segments[si]
        if len(seg.points) * spacing**2 < 0.25 * VISIBLE_FRACTION * model_area:
            return None  # shows under 5 % of the model's area: a fragment, not the object
        noise = float(np.median([p.plane.rmse for p in seg.planes])) if seg.planes else 0.0
        inlier = max(1.0 * spacing, rep.voxel, 3.0 * noise)
        hyps = vertex_hypotheses(
            model, seg.vertexes, seg.points, vote_distance=4 * spacing, rotinv=rotinv,
            compiled=WORKSTATION_COMPILED,
        )  # fmt: skip
        return (_promise(surface, seg.points, hyps, inlier, promise_rng), si, hyps, inlier)

    # 5. the segments' plans, verified in the order of their promise (ties in segment order),
    # computed lazily: a plan whose promise is full (every point explained) goes before any
    # plan of a later segment, so the segments after it are planned only when it does not
    # settle the answer (the healthy cube's own segment was full in 17 of tuning seeds
    # 1000-1019, at a random place among four; the rest cost 1-3 ms each)
    plans = _LazyPlans(len(segments), plan)
    results: list[tuple[PoseHypothesis, int]] = []
    while True:
        t = time.perf_counter()
        nxt = plans.next()
        t_hyp += time.perf_counter() - t
        if nxt is None:
            break
        _, si, hyps, inlier = nxt
        seg = segments[si]
        pairs_of = functools.partial(_plane_pairs, seg, rep.objects, rep.table)
        scored, dt_h, dt_v = _segment_verified(
            model,
            hyps,
            seg.points,
            pairs_of,
            inlier=inlier,
            cover_distance=max(inlier, 1.5 * spacing, rep.voxel),
            min_score=min_score,
            max_icp=max_icp,
            verify_options={**POLYHEDRAL_VERIFY, "prescreen": prescreen, **COMPILED_VERIFY},
            rng=rng,
            surface=surface,
            symmetries=syms,
            compiled_pairs=WORKSTATION_COMPILED,
        )
        t_hyp += dt_h
        t_ver += dt_v
        results.extend((h, si) for h, _ in scored)
        results.sort(key=lambda r: (-r[0].score, r[0].rmse))
        t = time.perf_counter()
        unranked = bool(results) and _unranked_rest(plans, segments, results)
        t_hyp += time.perf_counter() - t  # (it may plan the segments left)
        if unranked:
            continue  # a segment that may hold the object is still to verify
        if settled is not None and results:
            t = time.perf_counter()
            done = settled([r[0] for r in results[:max_hypotheses]])
            t_ver += time.perf_counter() - t
            if done:
                break
    results = results[:max_hypotheses]
    timing["hypotheses"] = timing.get("hypotheses", 0.0) + t_hyp
    timing["verification"] = timing.get("verification", 0.0) + t_ver
    return [r[0] for r in results], [r[1] for r in results]


#: A segment's plan: (promise, segment index, vertex hypotheses, inlier distance).
Plan = tuple[float, int, list[PoseHypothesis], float]


class _LazyPlans:
    """The segments' plans in the order of their promise (ties in segment order), each
    computed when the order needs it: a full promise (1.0, the most a plan can have) is
    next before any later segment's plan, whatever those promise."""

    def __init__(self, n: int, plan: Callable[[int], Plan | None]) -> None:
        self._plan = plan
        self._todo = list(range(n))
        self.computed: list[Plan] = []  # in segment order
        self.verified: set[int] = set()

    def _compute(self, to_full: bool) -> None:
        while self._todo:
            p = self._plan(self._todo.pop(0))
            if p is not None:
                self.computed.append(p)
                if to_full and p[0] >= 1.0:
                    return

    def pending(self, complete: bool = False) -> list[Plan]:
        """The plans not yet verified, in order; ``complete``: every segment planned (else
        only as many as settle which one is next)."""
        while True:
            left = sorted(
                (p for p in self.computed if p[1] not in self.verified), key=lambda p: -p[0]
            )
            if not self._todo or (not complete and left and left[0][0] >= 1.0):
                return left
            self._compute(to_full=not complete)

    def next(self) -> Plan | None:
        """The next plan to verify (marked verified), or None when none is left."""
        left = self.pending()
        if not left:
            return None
        self.verified.add(left[0][1])
        return left[0]

    def hyps_of(self, si: int) -> list[PoseHypothesis] | None:
        """Segment ``si``'s hypotheses, when it was planned."""
        return next((p[2] for p in self.computed if p[1] == si), None)


#: A segment without vertex hypotheses (no pre-score: ordered last) with at least this
#: fraction of the points of the best candidate's segment is verified before the candidates
#: may settle (:func:`_unranked_rest`).
UNRANKED_FRACTION = 0.5


def _unranked_rest(
    plans: _LazyPlans,
    segments: list[Segment],
    results: list[tuple[PoseHypothesis, int]],
) -> bool:
    """The best candidate so far comes from a segment without vertex hypotheses (its plane
    pairs), and a segment still to verify has none either and at least
    :data:`UNRANKED_FRACTION` of its points: nothing ranks the two, verify that one too.

    With the stereo pair's noise a cube's faces gave planes but no vertex, its segment went
    last, and a cube pose wrapped around a clutter box (from that box's plane pairs) settled
    before it was verified (tuning seed 1192). A best candidate from vertex hypotheses
    settles as before (a clean cloud's clutter has no vertex either: verifying it cost the
    healthy cube and part 20-35 % more time on tuning seeds 1000-1049)."""
    best_si = results[0][1]
    if plans.hyps_of(best_si):
        return False
    best = len(segments[best_si].points)
    return any(not hyps and len(segments[si].points) >= UNRANKED_FRACTION * best
               for _, si, hyps, _ in plans.pending(complete=True))  # fmt: skip


#: Segment points the pre-score of a segment's vertex hypotheses uses (their order of
#: verification).
PROMISE_POINTS = 100


def _promise(
    surface: ModelSurface,
    points: FloatArray,
    hyps: list[PoseHypothesis],
    inlier: float,
    rng: np.random.Generator,
) -> float:
    """The largest fraction of :data:`PROMISE_POINTS` of a segment's points that one of its
    40 most voted vertex hypotheses explains within 2 ``inlier`` (one batch query; 0 for
    none): the cube's own segment scores about 1, a clutter box's 0.7-0.9 (healthy tuning
    seeds 0-9)."""
    if not hyps:
        return 0.0
    top = sorted(hyps, key=lambda h: -h.votes)[:40]
    sub = points[rng.permutation(len(points))[:PROMISE_POINTS]]
    frac = batch_inlier_fractions(surface, sub, np.stack([h.matrix for h in top]), 2 * inlier)
    return float(np.max(frac))


def _plane_pairs(
    seg: Segment | SegmentReport, points: FloatArray, table: Plane | None
) -> list[tuple[Plane, FloatArray | None]]:
    """Plane pairs of a segment (a representation's :class:`Segment`, plane indices into the
    representation's object points, or a :func:`localize_cloud` :class:`SegmentReport`,
    indices into the segment's points): its diverse planes, the table flipped when it rests
    on it; none when it has no planes."""
    if not seg.planes:
        return []
    pairs: list[tuple[Plane, FloatArray | None]] = [
        (r.plane, points[r.indices]) for r in _diverse_planes(list(seg.planes))
    ]
    if seg.on_table and table is not None:
        pairs.append((table.flipped(), None))
    return pairs


def _segment_verified(
    model: Any,
    hyps: list[PoseHypothesis],
    seg_pts: FloatArray,
    plane_pairs: Any,
    *,
    inlier: float,
    cover_distance: float,
    min_score: float,
    max_icp: int,
    verify_options: dict[str, Any],
    rng: np.random.Generator,
    surface: ModelSurface,
    symmetries: Any,
    more: Callable[[], list[PoseHypothesis]] | None = None,
    compiled_pairs: bool = False,
) -> tuple[list[tuple[PoseHypothesis, Any]], float, float]:
    """One segment's verification: the hypotheses refined and scored; when the best scores
    under ``min_score``, ``more()`` hypotheses (when given) refined too, and then, when the
    best still scores under it and ``model`` is polyhedral (not None), plane-pair hypotheses
    (``plane_pairs()``: too few vertexes visible); when ``model`` is None
    (free-form), ICP also from the best's half turns about the model's principal axes
    (:func:`~mks_sim.models.refine.principal_half_turns`), merged; every score multiplied by
    the coverage of the model's surface (its fixed sampling within ``cover_distance`` of a
    segment point, over :data:`VISIBLE_FRACTION`; density independent). ``compiled_pairs``:
    the plane pairs' poses in one compiled pass (``plane_pair_hypotheses(compiled=True)``).

    Returns:
        ((hypothesis with the coverage-weighted score, its VerifiedHypothesis) pairs,
        seconds of hypothesis generation, seconds of verification).
    """
    from mks_sim.localization.verify import surface_coverage

    syms = symmetries

    def check(candidates: list[PoseHypothesis], **how: Any) -> list[Any]:
        """The candidates refined and scored on this segment (``how``: the ICP's limits)."""
        return verify_hypotheses(
            candidates, surface, seg_pts, inlier_distance=inlier, symmetries=syms, rng=rng,
            **verify_options, **how,
        )  # fmt: skip

    t = time.perf_counter()
    verified = check(hyps, max_icp=max_icp)
    t_ver = time.perf_counter() - t
    t_hyp = 0.0
    best = verified[0].hypothesis.score if verified else 0.0
    if more is not None and best < min_score:
        t = time.perf_counter()
        extra = more()
        t_hyp += time.perf_counter() - t
        if extra:
            t = time.perf_counter()
            verified += check(extra, max_icp=max_icp)
            verified.sort(key=lambda v: (-v.hypothesis.score, v.hypothesis.rmse))
            best = verified[0].hypothesis.score if verified else 0.0
            t_ver += time.perf_counter() - t
    if model is not None and best < min_score:
        t = time.perf_counter()
        pairs = plane_pairs()
        coarse: list[PoseHypothesis] = []
        if pairs:
            try:
                coarse = plane_pair_hypotheses(
                    model, pairs, seg_pts, inlier_distance=inlier, compiled=compiled_pairs
                )
            except DataError as exc:
                log.info("plane-pair hypotheses failed: %s", exc)
        t_hyp += time.perf_counter() - t
        t = time.perf_counter()
        verified += check(
            coarse, icp_distance=max(4 * inlier, 0.1 * surface.size), max_icp=max(4, max_icp // 2)
        )
        t_ver += time.perf_counter() - t
    if verified and model is None:
        # A free-form match can settle on the half-turned copy of a rounded shape (the
        # generated blob, tuning seed 1042: 178 deg about its long axis, scoring 0.97 where
        # the truth scores 0.99, never among the matcher's starts): ICP from the best's
        # half turns about the model's principal axes, and the better fit wins.
        t = time.perf_counter()
        h0 = verified[0].hypothesis
        starts = [
            replace(h0, matrix=h0.matrix @ H, votes=0) for H in principal_half_turns(surface.points)
        ]
        turned = check(starts, max_icp=len(starts), full_refine=len(starts))
        verified = merge_verified(verified + turned, syms, max(inlier, 0.01 * surface.size))
        t_ver += time.perf_counter() - t
    if not verified:
        return [], t_hyp, t_ver
    # Coverage: a pose must show about as much of the model's surface as one view does, or
    # a small segment (clutter, a fragment) that a piece of the model fits would win.
    cover = surface_coverage(
        surface.points,
        np.stack([v.hypothesis.matrix for v in verified]),
        NearPoints(seg_pts),  # (the tree's answers, without its build)
        cover_distance,
    )
    out = []
    for k, v in enumerate(verified):
        coverage = min(1.0, float(cover[k]) / VISIBLE_FRACTION)
        out.append((replace(v.hypothesis, score=v.hypothesis.score * coverage), v))
    return out, t_hyp, t_ver


# --------------------------------------------------------------------------- one cloud


# --------------------------------------------------------------------------- the pipeline


@dataclass(frozen=True, eq=False)
class SegmentReport:
    """What grouping found in one object segment.

    Attributes:
        indices: (n,) indices of the segment's points in the NaN-free scene (in the
            voxel-averaged scene when :attr:`Localization.voxel` > 0; when
            :attr:`Localization.object_voxel` > 0, every averaged point whose coarser cell is
            in the segment).
        planes: planar regions (indices into the segment's points as grouped: the coarser
            cells' averages when :attr:`Localization.object_voxel` > 0).
        vertexes: detected vertexes (segment frame = scene frame).
        on_table: the table plane was used as a face of this segment.
    """

    indices: NDArray[np.intp]
    planes: tuple[PlanarRegion, ...]
    vertexes: Vertexes
    on_table: bool


@dataclass(frozen=True, eq=False)
class Localization:
    """Result of :func:`localize_cloud`.

    Attributes:
        found: the best hypothesis passed ``min_score``.
        hypotheses: verified hypotheses, best first (``matrix`` model -> scene, ``votes``,
            ``score`` in [0, 1] = inlier fraction x residual factor (see
            :func:`~mks_sim.models.refine.score_pose`) x coverage (the fraction of the
            model's surface samples with a scene point nearby over :data:`VISIBLE_FRACTION`,
            capped at 1: independent of the scan density),
            ``rmse`` in scene units).
        equivalents: per hypothesis, (E, 4, 4) poses equivalent to it under the model's
            symmetries that the matcher also proposed.
        inlier_fractions: per hypothesis, the fraction of its segment's points explained.
        segment_of: per hypothesis, the index into ``segments``.
        segments: grouping diagnostics per object segment.
        table: the removed table plane (normal towards the objects) or None.
        spacing: median nearest-neighbour distance of the (averaged) scene.
        noise: estimated noise sigma of the (averaged) scene (RMS distance from local planes).
        voxel: voxel edge the scene was averaged on (0: not averaged).
        object_voxel: voxel edge the object points were averaged on again before grouping
            (0: they were not; see ``object_points`` of :func:`localize_cloud`).
        dropped_nan: NaN/inf scene rows dropped on input.
        warnings: what the caller should hear about (e.g. model and scene sizes that differ by
            orders of magnitude: wrong units or a missing ``scale``).
        timing: seconds per stage (``graph``, ``table``, ``grouping``, ``matching``,
            ``refinement``; the engine's stage names ``representation`` = graph + table +
            grouping, ``hypotheses`` = matching, ``verification`` = refinement; ``total``).
    """

    found: bool
    hypotheses: tuple[PoseHypothesis, ...]
    equivalents: tuple[FloatArray, ...]
    inlier_fractions: tuple[float, ...]
    segment_of: tuple[int, ...]
    segments: tuple[SegmentReport, ...]
    table: Plane | None
    spacing: float
    noise: float
    voxel: float
    dropped_nan: int
    timing: dict[str, float]
    warnings: tuple[str, ...] = ()
    object_voxel: float = 0.0

    @property
    def best(self) -> PoseHypothesis | None:
        """The best hypothesis, or None."""
        return self.hypotheses[0] if self.hypotheses else None


#: ``localize_cloud`` averages a polyhedral model's object points again, when they are more
#: than ``object_points``, on cells no wider than its :attr:`~PolyhedralModel.feature_width`
#: over this: a face then still holds about this many cells across its narrowest width.
#: Tuning scans of ``benchmarks/localize.py``: the industrial part's (faces 21.5 mm) at 2 mm
#: range noise, 8 of 8 found on cells up to 2.7 mm (8 here), 5 of 8 on 3.1 mm (7) and 3.6
#: (6); 9 keeps a quarter below that edge (the cube's 49.7 mm faces allow 5.5 mm cells).
FEATURE_CELLS = 9.0

#: localize_cloud's voxel cells are centred on the frame's origin (``floor(p / v + 0.5)``).
#: A scan given in its table's frame has the table at z = 0: on cells that start at the
#: origin, the table's noisy points fell on both sides of a cell border and averaged to two
#: layers a fraction of a millimetre apart. That doubled the table's points and halved the
#: spacing estimate (a 640 x 480 scan averaged on 2.35 mm cells: 23.0k points at a 0.47 mm
#: spacing; centred, 12.1k at 2.26 mm), and the SPG's gap threshold, 4 spacings, then cut
#: the object into fragments at a budget of 10,000 points (not found).
_VOXEL_SHIFT = 0.5


def _spacing_and_noise(points: FloatArray, rng: np.random.Generator) -> tuple[float, float]:
    """Median nearest-neighbour distance and noise sigma (``representation.spacing_and_noise``).

    (800 probes, as the workstation's representation asks, took 1.7 -> 1.2 ms on a 240 x 180
    scan, but the changed estimates turned a bin replay into a false positive: tuning bin
    58, ``tests/test_bin_instances.py``; kept at 1500.)"""
    return spacing_and_noise(points, rng)


def _find_table(
    points: FloatArray,
    spacing: float,
    noise: float,
    viewpoint: FloatArray | None,
    rng: np.random.Generator,
) -> tuple[Plane | None, NDArray[np.bool_]]:
    """The dominant plane if it looks like a support, and the mask of its band (the one table
    finder, :func:`mks_sim.localization.verify.find_table`)."""
    plane, _, band = find_table(points, rng, spacing=spacing, noise=noise, viewpoint=viewpoint)
    return plane, band


def _as_localizable(model: Any, scale: float) -> LocalizableModel:
    if scale != 1.0:
        if not callable(getattr(model, "scaled", None)):
            raise DataError(
                f"model {getattr(model, 'name', model)!r}: scale needs a model with a "
                "scaled(factor) method (PolyhedralModel, FreeformModel)"
            )
        model = model.scaled(scale)
    if isinstance(model, PolyhedralModel):
        return model
    if isinstance(model, LocalizableModel):
        return model
    raise DataError(
        f"localize_cloud: expected a LocalizableModel, PolyhedralModel, mesh, file or model "
        f"name, got {type(model).__name__}"
    )


@with_one_blas_thread
def localize_cloud(
    model: Any,
    scene_points: ArrayLike,
    *,
    scale: float = 1.0,
    viewpoint: ArrayLike | None = None,
    table: Literal["auto", "none"] | Plane = "auto",
    voxel: float | Literal["auto"] | None = "auto",
    max_points: int = 15000,
    object_points: int | None = 1200,
    m: int = 12,
    min_segment_points: int = 60,
    min_score: float = 0.5,
    max_hypotheses: int = 10,
    max_icp: int = 8,
    thorough: bool = False,
    rng: np.random.Generator | None = None,
) -> Localization:
    """Localize a model in a point cloud (paper section 4: SPG -> grouping -> Hough -> pose).

    Args:
        model: a :class:`LocalizableModel` (e.g. :class:`PolyhedralModel`), a ``Mesh``, a
            file path (mesh or point cloud) or a model-database name (see :func:`load_model`).
        scene_points: (N, 3) scene points in the model's unit times ``scale``; NaN/inf rows
            are dropped and counted.
        scale: model coordinates are multiplied by this to get scene units (e.g. 0.001 for a
            model in mm and a scene in m); the reported matrices map the scaled model.
        viewpoint: (3,) sensor position in the scene frame (orients normals; else normals
            point away from each segment's centroid).
        table: ``"auto"`` detects and removes a supporting plane (and uses it as the face the
            object rests on), ``"none"`` keeps every point, or a known :class:`Plane`
            (normal towards the objects).
        voxel: ``"auto"`` averages the cloud on a voxel grid of edge max(spacing, 3 sigma)
            when the estimated noise sigma exceeds 0.2 x the spacing, or of edge about
            spacing x sqrt(N / max_points) when there are more than ``max_points`` points; a
            number forces that edge; None never averages.
        max_points: point budget of ``voxel="auto"``. The voxel-averaged cloud finds the
            pose and the raw points polish it, so 15,000 keep the accuracy of 30,000
            (tuning trials of ``benchmarks/localize.py``, 240 x 180 to 640 x 480 scans: the
            same 112/112 found, the same median errors; a 240 x 180 scan of the part 40 ->
            32 ms); at 10,000-12,000 one noisy part of 56 was lost.
        object_points: after the table is removed from an averaged cloud, a polyhedral
            model's object points, when more than this, are averaged again on cells of
            edge ``voxel x sqrt(points / object_points)``, at most the model's
            :attr:`~PolyhedralModel.feature_width` / :data:`FEATURE_CELLS`, when that is at
            least 1.2 voxels (grouping, hypotheses and verification run on them; the pose is
            still polished on the raw points). A dense 50 mm cube's 2,400 points become
            ~1,200 (its localization 8-16 % faster); the industrial part's narrow faces
            allow cells of 2.39 mm at most (4-12 %); the tuning scans' 112 of 112 still
            found, about as accurately (docs/localize_cloud.md, "Point budgets"). None:
            never.
        m: SPG neighbours.
        min_segment_points: smaller SPG components are ignored.
        min_score: ``found`` needs the best score at least this.
        max_hypotheses: report at most this many distinct hypotheses.
        max_icp: ICP-refine at most this many distinct candidates per segment.
        thorough: a polyhedral model's candidates verified as before the workstation's
            settings were shared (every start's coarse ICP, three fully refined on 1500
            points) and the rotation-invariant Hough run on every segment with three or more
            vertexes; by default they are verified as the workstation verifies them
            (:data:`POLYHEDRAL_VERIFY`) and the rotation-invariant Hough is a fallback, run
            when the vertexes' own hypotheses score under ``min_score`` (its cost grows with
            the cube of the vertexes: 10-35 ms for the industrial part seen with 9-13).
            Thorough grouping also orders the region seeds by two-ring flatness (touching
            parts in a bin; see :func:`_group_segment`), and the planes, hypotheses and
            verification keep numpy's arithmetic: by default they run their compiled passes
            (``compiled``/``fused`` flags: the same steps, rounding may differ by ~1e-15).
        rng: generator (RANSAC, subsampling); default seeded 0.

    Returns:
        :class:`Localization`.

    Raises:
        DataError: malformed points (wrong shape, fewer than 10 finite points), model or
            point budget.
        NotFound: a model name or file that does not exist.
    """
    t0 = time.perf_counter()
    timing: dict[str, float] = {}
    for name, budget in (("max_points", max_points), ("object_points", object_points)):
        if (budget is not None or name == "max_points") and (
            isinstance(budget, bool) or not isinstance(budget, int | np.integer) or budget < 1
        ):
            none = " or None" if name == "object_points" else ""
            raise DataError(f"localize_cloud: {name} must be an integer >= 1{none}, got {budget!r}")
    rng = np.random.default_rng(0) if rng is None else rng
    if isinstance(model, str | Path) or type(model).__name__ == "Mesh":
        model = load_model(model)
    loc_model = _as_localizable(model, scale)
    try:
        raw = np.asarray(scene_points, dtype=np.float64)
    except (TypeError, ValueError) as exc:
        raise DataError(f"localize_cloud: scene points are not numeric: {exc}") from exc
    if raw.ndim != 2 or raw.shape[1] != 3:
        raise DataError(f"localize_cloud: expected (N, 3) scene points, got shape {raw.shape}")
    # (per column, and a mask's rows by compress: several times faster than axis-1 and [mask])
    finite = np.isfinite(raw[:, 0]) & np.isfinite(raw[:, 1]) & np.isfinite(raw[:, 2])
    dropped = int((~finite).sum())
    if dropped:
        log.warning("localize_cloud: dropped %d NaN/inf scene points of %d", dropped, len(raw))
    # (all finite, the common case: the points as given, no copy of a whole scan)
    pts = np.compress(finite, raw, axis=0) if dropped else raw
    if len(pts) < 10:
        raise DataError(f"localize_cloud: expected at least 10 finite scene points, got {len(pts)}")
    vp = None if viewpoint is None else np.asarray(viewpoint, dtype=np.float64).reshape(3)
    surface = (
        loc_model.surface
        if isinstance(loc_model, PolyhedralModel)
        else ModelSurface.from_arrays(loc_model.surface_points(), loc_model.surface_normals())
    )
    # Extent is linear in scale: the unscaled model's points times `scale` are loc_model's
    # (a model's extent is computed once, on its surface).
    size_warning = check_scale(None, pts, scale, model_extent=surface.extent / scale)

    t = time.perf_counter()
    spacing, noise = _spacing_and_noise(pts, rng)
    voxel_size = 0.0
    raw, raw_noise = pts, noise
    if voxel == "auto":
        # Noise comparable to the spacing defeats PCA normals over one SPG ring: average the
        # cloud on a voxel grid (noise falls with the averaging); what noise is left is
        # handled by two-ring normals in the grouping.
        if noise > 0.2 * spacing:
            voxel_size = max(spacing, 3.0 * noise)
        if len(raw) > max_points:
            # Dense clouds: about max_points points are plenty (and time grows with them).
            voxel_size = max(voxel_size, 1.1 * spacing * np.sqrt(len(raw) / max_points))
        if voxel_size > 0:
            pts = voxel_average(raw, voxel_size, shift=_VOXEL_SHIFT)
            spacing, noise = _spacing_and_noise(pts, rng)
    elif voxel is not None:
        voxel_size = float(voxel)
        pts = voxel_average(raw, voxel_size, shift=_VOXEL_SHIFT)
        spacing, noise = _spacing_and_noise(pts, rng)
    if len(pts) < 10:
        raise DataError(f"localize_cloud: only {len(pts)} points left after voxel averaging")
    timing["graph"] = time.perf_counter() - t

    t = time.perf_counter()
    table_plane: Plane | None
    on_table_band = np.zeros(len(pts), dtype=bool)
    if isinstance(table, Plane):
        table_plane = table
        on_table_band = np.abs(table.distance(pts)) <= 1.5 * max(spacing, 3.0 * noise)
    elif table == "auto":
        table_plane, on_table_band = _find_table(pts, spacing, noise, vp, rng)
    elif table == "none":
        table_plane = None
    else:
        raise DataError(f"localize_cloud: table must be 'auto', 'none' or a Plane, got {table!r}")
    keep = np.flatnonzero(~on_table_band)
    if table_plane is not None:
        keep = keep[table_plane.distance(pts[keep]) > 0]
    obj = pts[keep]
    # The object's own scale: its points, spacing and voxel (the scene's unless averaged again)
    seg_spacing, seg_voxel = spacing, voxel_size
    cell_of: NDArray[np.intp] | None = None
    if (
        object_points is not None and voxel_size > 0 and len(obj) > object_points
        and isinstance(loc_model, PolyhedralModel)
    ):  # fmt: skip
        coarse = min(
            voxel_size * float(np.sqrt(len(obj) / object_points)),
            loc_model.feature_width / FEATURE_CELLS,
        )
        if coarse >= 1.2 * voxel_size:
            obj, cell_of = voxel_average_cells(obj, coarse, shift=_VOXEL_SHIFT)
            # (an averaged surface's spacing scales with its cells)
            seg_spacing, seg_voxel = spacing * coarse / voxel_size, coarse
    timing["table"] = time.perf_counter() - t

    t = time.perf_counter()
    segments: list[SegmentReport] = []
    seg_data: list[tuple[FloatArray, Segmentation | None]] = []
    if len(obj) >= min_segment_points:
        # One SPG of the object points, edges up to 4 spacings: its components, and the SPG
        # of each segment whose points all have their m neighbours within that distance.
        adj = build_graph(obj, m=m, threshold=4.0 * seg_spacing).adjacency
        _, comp = weak_components(adj)
        comp = _merge_components(obj, comp, surface.size)
        sizes = np.bincount(comp)
        for c in np.argsort(-sizes):
            if sizes[c] < min_segment_points:
                break
            members = np.flatnonzero(comp == c)
            seg_pts = obj[members]
            seg_graph = _segment_graph(adj, members, seg_pts, m)
            report, seg = _group_segment(
                seg_pts, m, seg_spacing, vp, table_plane,
                normal_rings=2 if noise > 0.2 * spacing else 1, graph=seg_graph,
                curvature_rings=2 if thorough else None, compiled_fit=not thorough,
            )  # fmt: skip
            at = keep[members] if cell_of is None else keep[np.isin(cell_of, members)]
            segments.append(SegmentReport(at, report[0], report[1], report[2]))
            seg_data.append((seg_pts, seg))
    timing["grouping"] = time.perf_counter() - t

    t_match = 0.0
    t_refine = 0.0
    results: list[tuple[PoseHypothesis, FloatArray, float, int]] = []
    syms = loc_model.symmetries()
    for si, (seg_pts, seg) in enumerate(seg_data):
        rep = segments[si]
        noise = float(np.median([p.plane.rmse for p in rep.planes])) if rep.planes else 0.0
        inlier = max(1.0 * seg_spacing, seg_voxel, 3.0 * noise)
        t = time.perf_counter()
        polyhedral = isinstance(loc_model, PolyhedralModel)
        more = None
        if polyhedral:
            vote = 4 * seg_spacing
            hyps = vertex_hypotheses(
                loc_model, rep.vertexes, seg_pts, vote_distance=vote, rotinv=thorough,
                compiled=not thorough,
            )  # fmt: skip
            if not thorough and len(rep.vertexes) >= 3:  # the rotation-invariant Hough's
                more = functools.partial(
                    vertex_hypotheses, loc_model, rep.vertexes, seg_pts,
                    vote_distance=vote, corners=False,
                )  # fmt: skip
        else:
            hyps = loc_model.hypotheses(seg_pts, None if seg is None else seg.normals)
        t_match += time.perf_counter() - t
        pairs_of = functools.partial(_plane_pairs, rep, seg_pts, table_plane)
        scored, dt_h, dt_v = _segment_verified(
            loc_model if polyhedral else None,
            hyps,
            seg_pts,
            pairs_of,
            inlier=inlier,
            cover_distance=max(inlier, 1.5 * seg_spacing, seg_voxel),
            min_score=min_score,
            max_icp=max_icp,
            verify_options=CLOUD_VERIFY if polyhedral and not thorough else {},
            rng=rng,
            surface=surface,
            symmetries=syms,
            more=more,
            compiled_pairs=not thorough,
        )
        t_match += dt_h
        t_refine += dt_v
        results.extend((h, v.equivalents, v.inlier_fraction, si) for h, v in scored)
    results.sort(key=lambda r: (-r[0].score, r[0].rmse))
    results = results[:max_hypotheses]
    if voxel_size > 0 and results:
        # The voxel-averaged cloud found the pose; polish the best on the full-resolution
        # points near it (averaging blurs edges by about a voxel).
        t = time.perf_counter()
        h0, eq0, frac0, si0 = results[0]
        band = 1.5 * max(spacing, 3.0 * raw_noise, voxel_size)  # the raw points' table band
        polished = _polish_full_resolution(h0, surface, raw, voxel_size, rng, table_plane, band)
        results[0] = (polished, eq0, frac0, si0)
        t_refine += time.perf_counter() - t
    timing["matching"] = t_match
    timing["refinement"] = t_refine
    # the engine's common stage names (``localize --json`` reports the same)
    timing["representation"] = timing["graph"] + timing["table"] + timing["grouping"]
    timing["hypotheses"] = t_match
    timing["verification"] = t_refine
    timing["total"] = time.perf_counter() - t0
    found = bool(results) and results[0][0].score >= min_score
    log.info(
        "localize_cloud(%s): %d segments, %d hypotheses, best score %.3f, %.3f s",
        loc_model.name,
        len(segments),
        len(results),
        results[0][0].score if results else float("nan"),
        timing["total"],
    )
    return Localization(
        found=found,
        hypotheses=tuple(r[0] for r in results),
        equivalents=tuple(r[1] for r in results),
        inlier_fractions=tuple(r[2] for r in results),
        segment_of=tuple(r[3] for r in results),
        segments=tuple(segments),
        table=table_plane,
        spacing=spacing,
        noise=noise,
        voxel=voxel_size,
        object_voxel=seg_voxel if cell_of is not None else 0.0,
        dropped_nan=dropped,
        timing=timing,
        warnings=(size_warning,) if size_warning else (),
    )


def _polish_full_resolution(
    h: PoseHypothesis,
    surface: ModelSurface,
    raw: FloatArray,
    voxel: float,
    rng: np.random.Generator,
    table: Plane | None = None,
    band: float = 0.0,
    max_points: int = 4000,
) -> PoseHypothesis:
    """Point-to-plane ICP of a pose on the raw (not voxel-averaged) points near it, those
    within ``band`` of the ``table`` left out; the pose is kept when ICP fails or moves it by
    more than a voxel.

    The table's raw points within the ICP's gate of the model's lowest faces pulled the pose
    towards the table: with them, the polish made the part's translation worse (tuning
    trials of ``benchmarks/localize.py``, median 0.03 -> 0.10 % of its size; without them,
    rotation errors of the cube halved, 0.08 -> 0.03 deg)."""
    from mks_sim.models.refine import icp_point_to_plane

    T = np.asarray(h.matrix, dtype=np.float64)
    centre = T[:3, :3] @ column_mean(surface.points) + T[:3, 3]
    radius = 0.5 * surface.size + 2.0 * voxel
    near = raw[norm_within(raw, centre, radius)]  # (the norm's rows, compiled)
    if table is not None:
        near = np.compress(table.distance(near) > band, near, axis=0)
    if len(near) < 30:
        return h
    if len(near) > max_points:
        near = near[rng.choice(len(near), max_points, replace=False)]
    try:
        icp = icp_point_to_plane(
            surface, near, T, max_distance=2.0 * voxel, max_iterations=15, stall=ICP_STALL,
            fused=FUSED_ICP,
        )  # fmt: skip
    except MksError:
        return h
    moved = float(np.linalg.norm(icp.matrix[:3, 3] - T[:3, 3]))
    if not np.all(np.isfinite(icp.matrix)) or moved > voxel:
        return h
    ref_model = np.linalg.solve(T[:3, :3], h.reference_point - T[:3, 3])
    ref = icp.matrix[:3, :3] @ ref_model + icp.matrix[:3, 3]
    return replace(h, matrix=icp.matrix, reference_point=ref)


def _diverse_planes(
    planes: Sequence[PlanarRegion], max_planes: int = 5, per_direction: int = 2
) -> list[PlanarRegion]:
    """The largest planes, at most ``per_direction`` per normal direction (20 deg), so that
    a face split by noise does not crowd out the other orientations."""
    chosen: list[PlanarRegion] = []
    for r in planes:
        same = sum(1 for c in chosen if abs(c.normal @ r.normal) > np.cos(np.radians(20)))
        if same < per_direction:
            chosen.append(r)
        if len(chosen) == max_planes:
            break
    return chosen


def _pca_extent(points: FloatArray) -> float:
    """Diagonal of the bounding box in the points' principal axes (rotation invariant)."""
    c = points - column_mean(points)
    _, _, vt = np.linalg.svd(c[:: max(1, len(c) // 2000)], full_matrices=False)
    return float(np.linalg.norm(np.ptp(c @ vt.T, axis=0)))


def _merge_components(
    points: FloatArray, labels: NDArray[np.intp], model_size: float, min_points: int = 10
) -> NDArray[np.intp]:
    """Join SPG components that one object could span: self-occlusion splits an object
    (a hidden step wall leaves a gap). Two components merge when they come within a quarter
    of the model's size of each other and together still fit in 1.1 x its size."""
    sizes = np.bincount(labels)
    ids = [int(c) for c in np.flatnonzero(sizes >= min_points)]
    if len(ids) < 2:
        return labels
    parent = {c: c for c in ids}

    def root(c: int) -> int:
        while parent[c] != c:
            c = parent[c]
        return c

    members = {c: np.flatnonzero(labels == c) for c in ids}
    own = {c: points[members[c]] for c in ids}
    bounds = {c: column_bounds(own[c]) for c in ids}
    lo = {c: bounds[c][0] for c in ids}
    hi = {c: bounds[c][1] for c in ids}
    # whether a pair comes within the reach: the compiled grid when numba imports (no tree
    # to build: 1.5 -> 0.6 ms a call on 48 tuning-seed calls), else a k-d tree, on first use
    near: dict[int, NearPoints] = {}
    reach = 0.25 * model_size
    for a, b in itertools.combinations(ids, 2):
        ra, rb = root(a), root(b)
        if ra == rb:
            continue
        # boxes farther apart than the reach: no point pair can be nearer (no tree query)
        gap = np.maximum(np.maximum(lo[a] - hi[b], lo[b] - hi[a]), 0.0)
        if float(np.sqrt(gap @ gap)) >= reach:
            continue
        if a not in near:
            near[a] = NearPoints(own[a])
        if not near[a].any_nearer(own[b], reach).any():
            continue
        joined = np.concatenate([members[c] for c in ids if root(c) in (ra, rb)])
        if _pca_extent(points[joined]) <= 1.1 * model_size:
            parent[rb] = ra
    out = labels.copy()
    for c in ids:
        out[members[c]] = root(c)
    return out


#: Cut rows x segment points up to which :func:`_segment_graph` answers the cut rows by
#: brute force (~1 ns a pair; beyond, the grid).
_BRUTE_CUT_WORK = 500_000


def _segment_graph(adj: Any, members: NDArray[np.intp], points: FloatArray, m: int) -> Any:
    """The SPG of one component (sorted ``members``, their ``points``) from the thresholded
    SPG ``adj`` of all the object points: a row the threshold did not cut has its ``m``
    nearest neighbours within the threshold, so in the component, and its induced row is
    its row in the component's own SPG (the same neighbours, the columns renumbered
    monotonically); a row it cut (fewer than ``m``: a stray or fringe point) is asked anew
    among the component's points: by brute force in the same compiled pass that renumbers
    the whole rows (:func:`~mks_sim.lowlevel._gridknn.induced_rows`, up to
    :data:`_BRUTE_CUT_WORK` cut rows x points), else by the SPG's own compiled grid for
    those rows alone (:func:`~mks_sim.lowlevel._gridknn.grid_knn`). The same graph as
    building the component's SPG, to the bit (a 2,000-point segment with 2-120 cut rows:
    1.4-3.1 ms to build, 0.4 ms here; the grid's way 1.2 ms, and 10 of the 112 tuning
    segments had a row it could not prove, built anew). (An SPG without the
    threshold gave the components as well, but a noisy scan's stray points then had far
    rows, found by brute force: a 1 mm noise cube's grouping 9 -> 17 ms.) None when the
    compiled grid is unavailable or cannot prove a cut row (the caller builds the SPG)."""
    from mks_sim.lowlevel import _gridknn
    from mks_sim.lowlevel.normals import FixedGraph

    n = len(members)
    lens = np.diff(adj.indptr)[members]
    cut = np.flatnonzero(lens < m)
    if n > m and len(cut) * n <= _BRUTE_CUT_WORK and _gridknn.available():
        # one compiled pass: the whole rows renumbered, the cut ones by brute force (a
        # 2,400-point segment with 2-100 cut rows: 1.2-1.5 -> 0.4 ms)
        ok, indptr_c, indices_c, data_c = _gridknn.induced_rows(adj, members, points, m)
        if ok:
            graph_c = sparse.csr_array((data_c, indices_c, indptr_c), shape=(n, n))
            graph_c.has_sorted_indices = True
            return FixedGraph(graph_c)
    nbr = nd = None
    if len(cut):
        if n <= m or not _gridknn.available():
            return None
        want = np.zeros(n, dtype=bool)
        want[cut] = True
        nbr, nd, got, done = _gridknn.grid_knn(points, m, None, rows=want)
        if not done[cut].all() or not np.all(got[cut] == m):
            return None  # (a row the grid cannot prove: the caller builds the SPG)
        # the rows in the CSR's column order
        by_col = np.argsort(nbr[cut], axis=1, kind="stable")
        nbr = np.take_along_axis(nbr[cut], by_col, axis=1)
        nd = np.take_along_axis(nd[cut], by_col, axis=1)
    # The whole rows: an edge never leaves its component, so a member's row renumbered
    # (monotonically: the columns stay sorted) is its induced row.
    whole = lens >= m
    new_lens = np.where(whole, lens, m)
    indptr = np.zeros(n + 1, dtype=adj.indptr.dtype)
    np.cumsum(new_lens, out=indptr[1:])
    keep_lens = lens[whole]
    src = np.repeat(adj.indptr[members[whole]] - np.cumsum(keep_lens) + keep_lens, keep_lens)
    src += np.arange(len(src))
    dst = np.repeat(indptr[:-1][whole] - np.cumsum(keep_lens) + keep_lens, keep_lens)
    dst += np.arange(len(dst))
    renumber = np.empty(adj.shape[0], dtype=adj.indices.dtype)
    renumber[members] = np.arange(n, dtype=adj.indices.dtype)
    indices = np.empty(indptr[-1], dtype=adj.indices.dtype)
    data = np.empty(indptr[-1], dtype=adj.data.dtype)
    indices[dst] = renumber[adj.indices[src]]
    data[dst] = adj.data[src]
    if nbr is not None and nd is not None:
        at = (indptr[cut][:, None] + np.arange(m)).ravel()
        indices[at] = nbr.ravel()
        data[at] = nd.ravel()
    graph = sparse.csr_array((data, indices, indptr), shape=(n, n))
    graph.has_sorted_indices = True
    return FixedGraph(graph)


def _group_segment(
    seg_pts: FloatArray,
    m: int,
    spacing: float,
    viewpoint: FloatArray | None,
    table_plane: Plane | None,
    normal_rings: int = 1,
    graph: Any = None,
    curvature_rings: int | None = None,
    compiled_fit: bool = False,
) -> tuple[tuple[tuple[PlanarRegion, ...], Vertexes, bool], Segmentation | None]:
    """Planes, vertexes and whether the segment rests on the table; ``graph``: its SPG when
    already known (else built). The regions grow from the flattest points first, flatness
    the surface variation over ``curvature_rings`` SPG rings (None: the normals' own rings,
    no second pass over the neighbourhoods: 1-1.6 ms less on a 2,000-point segment, the
    same 110 of 112 tuning scans found; two rings separate touching parts, as a bin of
    them needs: ``tests/test_bin_instances.py``)."""
    graph = build_graph(seg_pts, m=m) if graph is None else graph
    try:
        # (no curved regions: nothing here asks for them, and their sphere fits cost ~1 ms)
        seg = segment_surfaces(
            seg_pts, graph, viewpoint=viewpoint, seeds="all", normal_rings=normal_rings,
            curved=False,
            curvature_rings=normal_rings if curvature_rings is None else curvature_rings,
            compiled_fit=compiled_fit,
        )  # fmt: skip
    except DataError:
        empty = Vertexes(
            np.zeros((0, 3)), np.zeros((0, 3), np.intp), np.zeros((0, 3, 3)), np.zeros(0)
        )
        return ((), empty, False), None
    on_table = table_plane is not None and bool(
        np.min(table_plane.distance(seg_pts)) <= 4.0 * spacing
    )
    extra = [table_plane.flipped()] if on_table and table_plane is not None else []
    verts = plane_vertexes(
        seg.planes, seg_pts, extra_planes=extra, tolerance=4 * max(spacing, seg.spacing)
    )
    return (seg.planes, verts, on_table), seg


# --------------------------------------------------------------------------- the workstation paths

# An object segment whose points a consistent candidate explains at least this fraction of
# needs no support-face hypotheses.
SUPPORT_EXPLAINED_FRACTION = 0.8
# The best pose leaving more object points near it unexplained than this fraction of those it
# explains gets ICP restarts from copies of it shifted by these fractions of the model's
# size and turned (:func:`_hop`).
HOP_UNEXPLAINED = 0.05
HOP_SHIFTS = (0.12, 0.25)
SPHERE_SENSOR = "Sphere_Detector"
# Spheres of this radius range found by Sphere_Detector are set aside before polyhedral
# matching (the workstation's spheres are 3 cm; larger fits are curved-region artefacts).
MIN_EXPLAINED_SPHERE_M = 0.01
MAX_EXPLAINED_SPHERE_M = 0.05


def _noise_scale(table: Plane | None, spacing: float) -> float:
    """Inlier distance for consistency checks: 3 sigma of the table's RANSAC inliers, >= 3 mm."""
    if table is not None and table.rmse > 0:
        return float(max(0.003, 3.0 * table.rmse))
    return float(max(0.003, 1.5 * spacing))


def _set_aside_spheres(
    rep: Representation, snap: Any, d0: float, extra: dict[str, Any]
) -> NDArray[np.bool_]:
    """(K,) mask over ``rep.objects``: False on the shells of the database's spheres
    (fixed-radius centre Hough + fit + cap check) and of the spheres the Sphere_Detector
    found (3 cm-ish radii) that intersect neither one of those nor the table.

    The database's radii go first: a sphere is a solid, so a detected sphere overlapping one
    already found is the same object, fitted worse. With the stereo pair's noisier points
    the detector fitted scene 2's 30 mm sphere as 41 mm with its centre 14 mm off, and its
    shell took 139 of the 295 stereo points of the cube under it (tuning seed 1026; 1115:
    38 mm, 9 mm off, 162 of 615). Nor can a sphere reach through the table."""
    objects = rep.objects
    keep = np.ones(len(objects), dtype=bool)
    normals = rep.normals.normals
    known: list[tuple[FloatArray, float]] = []
    for radius in _known_sphere_radii():
        sub = np.flatnonzero(keep)
        seeds = sphere_centre_hough(objects[sub], radius, normals[sub])
        found = [h for _, h, chk in score_spheres(objects[sub], seeds, radius, d0) if chk["ok"]]
        for h in found:
            shell = np.abs(np.linalg.norm(objects - h.matrix[:3, 3], axis=1) - radius)
            keep &= shell > d0 + 0.001
            known.append((np.asarray(h.matrix[:3, 3], dtype=np.float64), radius))
    try:
        spheres = np.asarray(snap.get(SPHERE_SENSOR).data, dtype=np.float64).reshape(-1, 4)
    except MksError as exc:
        log.info("%s unavailable: %s", SPHERE_SENSOR, exc)
        spheres = np.zeros((0, 4))
    band = max(rep.table_threshold, 0.003) + 0.001
    n = len(known)
    for s in spheres:
        if not MIN_EXPLAINED_SPHERE_M <= s[3] <= MAX_EXPLAINED_SPHERE_M:
            continue
        if any(np.linalg.norm(s[:3] - c) < s[3] + r - 2.0 * d0 for c, r in known):
            continue  # overlaps a sphere already found: the same solid
        # ... or reaches through the table: the detector reported a 44 mm sphere centred 6 mm
        # above it whose shell ran along a cube's face, 289 of its points (tuning seed 1192)
        if rep.table is not None and float(rep.table.distance(s[None, :3])[0]) < s[3] - 2.0 * d0:
            continue
        keep &= np.abs(np.linalg.norm(objects - s[:3], axis=1) - s[3]) > band
        n += 1
    extra["spheres_set_aside"] = n
    return keep


def localize_polyhedral(
    model: Any,
    entry: Any,
    snap: Any,
    sensor: str,
    rep: Representation,
    rng: np.random.Generator,
    timing: dict[str, float],
    viewpoints: FloatArray | None = None,
) -> tuple[list[PoseHypothesis], dict[str, Any]]:
    """The workstation's polyhedral path over a snapshot's representation (steps 4-6 of
    :func:`mks_sim.localization.workstation.localize_object`): spheres set aside, segments,
    vertex / plane-pair candidates (most promising segment first, stopping once settled),
    consistency over the whole cloud; a settled best (:func:`_settled`) is set to rest on
    the table (polished first when it does not rest) and returned; otherwise the model's
    rotation-invariant Hough on its logical sensor, support faces for what stays
    unexplained, a final polish and restarts; returns (consistent hypotheses best first,
    diagnostics). ``viewpoints``: where the points were seen from (the consistency check's
    facing test; None: any upward-ish face explains)."""
    extra: dict[str, Any] = {}
    points = rep.points
    table = rep.table
    extra["table_z_m"] = None if table is None else float(table.offset / table.normal[2])
    d = _noise_scale(table, rep.spacing)
    # Curved objects explained by the sphere detector (the Surface_Curvature grouping of
    # Table 4-6) are set aside: a sphere resting on the cube would otherwise share its SPG
    # component and crowd the vertex matcher with facets of the sphere.
    t = time.perf_counter()
    keep = _set_aside_spheres(rep, snap, d, extra)
    objects = rep.objects[keep]
    extra["object_points"] = len(objects)
    # the spheres' points are explained, by the sphere: not left unexplained by a pose of this
    # model (scene 2's sphere on the cube made every cube pose look partial and restart ICP)
    sphere_pts = np.zeros(len(points), dtype=bool)
    sphere_pts[rep.object_indices[~keep]] = True
    if len(objects) < 30:
        timing["hypotheses"] = time.perf_counter() - t
        return [], extra
    surface = model.surface
    segments = object_segments(rep, surface.size, keep=keep)
    timing["hypotheses"] = time.perf_counter() - t
    timing["verification"] = 0.0
    surface_pts = np.asarray(model.surface_points(), dtype=np.float64)
    surface_nrm = np.asarray(model.surface_normals(), dtype=np.float64)
    # the coverage tests' questions of the object points, by the compiled grid (no tree)
    objects_tree = NearPoints(objects)
    checked: dict[int, tuple[PoseHypothesis, Consistency]] = {}
    covers: Coverages = {}

    def check(h: PoseHypothesis) -> Consistency:
        """The consistency check of a candidate, computed once per candidate."""
        hit = checked.get(id(h))
        if hit is None or hit[0] is not h:
            c = consistency(
                h.matrix, surface_pts, surface_nrm, points, table, d, None, sphere_pts,
                surface=surface, viewpoints=viewpoints,
            )  # fmt: skip
            hit = (h, _whole(c))
            checked[id(h)] = hit
        return hit[1]

    def settled(found: list[PoseHypothesis]) -> bool:
        top = _contenders([found[i] for i in _top(found, 5)], check)
        checks = [check(h) for h in top]
        return _settled(top, checks, rank(top, checks)[0], model, objects_tree, d, covers)

    candidates, _ = polyhedral_candidates(
        model, rep, segments, rng=rng, timing=timing, settled=settled
    )
    extra["segments"] = [len(s.indices) for s in segments]
    extra["candidates"] = len(candidates)

    # the model's own logical sensor (vertexes / control points): its matcher's input and
    # support of the estimate
    t = time.perf_counter()
    detected: FloatArray | None = None
    try:
        detected = np.asarray(snap.get(sensor).data, dtype=np.float64)[:, :3]
    except MksError as exc:
        log.info("logical sensor %s unavailable: %s", sensor, exc)
    extra["detected_features"] = 0 if detected is None else len(detected)
    timing["hypotheses"] += time.perf_counter() - t
    # 6. scene consistency of the best candidates over the whole cloud; when the best is
    # settled (consistent, whole, showing what one view shows) the later stages could only
    # confirm it: it gets the final polish and is the answer (healthy cube and part, tuning
    # seeds 0-29: 29 and 26 of 30 settle here, every one within 5 mm / 5 deg)
    t = time.perf_counter()
    candidates = [candidates[i] for i in _top(candidates, 5)]
    contenders = _contenders(candidates, check)
    checks = [check(h) for h in contenders]
    order, good = rank(contenders, checks)
    timing["verification"] += time.perf_counter() - t
    extra["inlier_distance_m"] = d
    if _settled(contenders, checks, order, model, objects_tree, d, covers):
        candidates = contenders
        t = time.perf_counter()
        # (the best only, to keep this path short: a tilted near-copy outranking the rested
        # best was seen on the full path, tuning seed 1063). Rested first: its ICP takes all
        # the points near the pose, as the polish does, so a best that rests needs no polish
        # (one ICP and one check less; the same successes and median errors on tuning seeds
        # 1000-1129, the healthy cube's poses identical)
        fine = rep.raw_of(np.flatnonzero(keep))  # the kept objects at the sensor's resolution
        rested = _rest_best(order[:1], candidates, checks, model, fine, table, d, check)
        if not rested:
            _polish(order[0], candidates, checks, model, objects, d, rng, check)
            order, _ = rank(candidates, checks)
            rested = _rest_best(order[:1], candidates, checks, model, fine, table, d, check)
        extra["rested"] = rested
        order, good = rank(candidates, checks)
        timing["verification"] += time.perf_counter() - t
        extra["settled_early"] = True
        extra["checks"] = [checks[i].as_dict() for i in order[:5]]
        _feature_support(good, detected, model, d, extra)
        return good, extra

    t = time.perf_counter()
    checks = [check(h) for h in candidates]  # not settled: all five compete in the later stages
    order, good = rank(candidates, checks)
    timing["verification"] += time.perf_counter() - t
    t = time.perf_counter()
    # 5'. the model's own matcher on its logical sensor: the rotation-invariant Hough of the
    # detected vertexes / control points (section 2.2.1), refined by ICP on the points
    if detected is not None and len(detected) >= 3 and callable(getattr(entry, "detect", None)):
        try:
            coarse = list(entry.detect(detected))[:10]
        except MksError as exc:
            log.info("%s: rotation-invariant Hough gave nothing: %s", sensor, exc)
            coarse = []
        extra["rotinv_maxima"] = len(coarse)
        timing["hypotheses"] += time.perf_counter() - t
        t = time.perf_counter()
        refined = _refine_near(
            _best_coarse(coarse, model, objects_tree, d, 2), model, objects, d, rng
        )
        extra["rotinv_refined"] = len(refined)
        # the five best of all (the checked five and the refined ones), checked once each
        checks += [check(h) for h in refined]
        candidates += refined
        keep5 = _top(candidates, 5)
        candidates = [candidates[i] for i in keep5]
        checks = [checks[i] for i in keep5]
        order, good = rank(candidates, checks)
        timing["verification"] += time.perf_counter() - t
    else:
        timing["hypotheses"] += time.perf_counter() - t
    unexplained: list[Any] = []
    if table is not None and _best_covers_little(
        candidates, checks, order, model, objects_tree, d, covers
    ):
        # support segments as the sensors separate objects: SPG components over 12 mm edges
        # (none that large: an object seen in pieces, e.g. an L-bracket standing on its leg
        # ends, keeps the merged segments), and the object segments over short edges that
        # are none of those: a cube touching a clutter box is one 12 mm component, too large
        # for one cube, and a segment of its own over 4 spacings (stereo pair, tuning seeds
        # 22 and 1019: not found before)
        wide = object_segments(rep, surface.size, keep=keep, gap=rep.gap, merge=False)
        known = {s.indices.tobytes() for s in wide}
        pool = wide + [s for s in segments if s.indices.tobytes() not in known]
        unexplained = _unexplained_segments(pool, candidates, checks, model, d)
    if table is not None and unexplained:
        # The object rests on the table: hypotheses from every support face of the model put
        # on the sensed table plane (yaw from the footprint's principal axes and 8 fixed
        # yaws), pre-scored in a batch, the best refined by ICP and checked like the others.
        t = time.perf_counter()
        support = support_face_hypotheses(
            model, unexplained, table, rep.table_threshold, d, rng, timing
        )
        t2 = time.perf_counter()
        checks2 = [check(h) for h in support]
        candidates += support
        checks += checks2
        order, good = rank(candidates, checks)
        timing["verification"] += time.perf_counter() - t2
        extra["support_fallback"] = {
            "candidates": len(support),
            "ok": int(sum(c.ok for c in checks2)),
            "seconds": time.perf_counter() - t,
        }
    # Polish: the best-ranked candidate (the two best when it failed the check) gets a full
    # ICP on the points near it and is checked again (coarse starts stop short).
    t = time.perf_counter()
    # A consistent polish replaces its start unless it lost support beyond the count noise
    # (:data:`POLISH_KEEP`): start and polish are one pose, and between two near-equal counts
    # the ranking would pick by a few noisy points (stereo cube, tuning seed 6: 1203 vs 1198
    # net support, the start 4.4 deg off, the polish 1.5 deg).
    n_polish = 1 if order and checks[order[0]].ok else 2
    for i in order[:n_polish]:
        _polish(i, candidates, checks, model, objects, d, rng, check)
    order, good = rank(candidates, checks)
    best = checks[order[0]] if order else None
    if best is not None and (not best.ok or best.unexplained > HOP_UNEXPLAINED * best.explained):
        # A pose one wall off (a thin object slid along itself, or turned end for end) is
        # consistent and ICP stays in its basin: when the best is not consistent or leaves
        # object points near it unexplained, ICP restarts from shifted and turned copies of
        # it, which compete.
        hops = _hop(candidates[order[0]], model, objects, d, rng)
        # ... and from the runner-up: with the facing test a pose one wall off loses the
        # points its far face explained and can rank below a pose turned end for end, while
        # its hops find the true pose (generated L-bracket, tuning seed 1011)
        if len(order) > 1:
            hops += _hop(candidates[order[1]], model, objects, d, rng)
        for h in hops:
            candidates.append(h)
            checks.append(check(h))
        extra["hops"] = len(hops)
        order, good = rank(candidates, checks)
    if order:
        fine = rep.raw_of(np.flatnonzero(keep))
        extra["rested"] = _rest_best(order, candidates, checks, model, fine, table, d, check)
        order, good = rank(candidates, checks)
    timing["verification"] += time.perf_counter() - t
    extra["checks"] = [checks[i].as_dict() for i in order[:5]]
    _feature_support(good, detected, model, d, extra)
    return good, extra


def _feature_support(
    good: list[PoseHypothesis],
    detected: FloatArray | None,
    model: Any,
    d: float,
    extra: dict[str, Any],
) -> None:
    """``extra["feature_support"]``: how many of the model's vertexes, posed at the best
    estimate, have a detected feature of its logical sensor within 4 ``d``."""
    model_feats = getattr(model, "vertexes", None)
    if not good or detected is None or not len(detected) or model_feats is None:
        return
    T = np.asarray(good[0].matrix)
    mv = np.asarray(model_feats) @ T[:3, :3].T + T[:3, 3]
    dist = cKDTree(detected).query(mv)[0]
    extra["feature_support"] = int((dist < 4 * d).sum())


#: Score margin of a consistency check: when the best-scored candidate is consistent, the
#: candidates scoring more than this below it are not checked before settling (each check
#: ~3 ms). Tuning seeds 1000-1099 healthy and 1000-1059 stereo (cube, part): at a margin of
#: 0.1-0.3 none of the candidates left out would have outranked the best (consistent with
#: more net support), and the part's three checks of candidates 0.25-0.45 below a 0.99 best
#: went.
CHECK_MARGIN = 0.2


def _contenders(
    candidates: list[PoseHypothesis], check: Callable[[PoseHypothesis], Consistency]
) -> list[PoseHypothesis]:
    """The candidates (best score first) worth checking for a settled answer: all of them
    when the best fails its check; else the best and those within :data:`CHECK_MARGIN` of
    its score. Not settled, the caller checks the rest (the later stages rank all)."""
    if not candidates or not check(candidates[0]).ok:
        return candidates
    floor = float(np.nan_to_num(candidates[0].score)) - CHECK_MARGIN
    return [candidates[0]] + [h for h in candidates[1:] if np.nan_to_num(h.score) >= floor]


def _settled(
    candidates: list[PoseHypothesis],
    checks: list[Consistency],
    order: list[int],
    model: Any,
    objects_tree: cKDTree | NearPoints,
    d: float,
    covers: Coverages | None = None,
) -> bool:
    """The best-ranked candidate is consistent and shows at least what one view does (not
    :func:`_best_covers_little`) and leaves at most :data:`HOP_UNEXPLAINED` of its
    explained count unexplained nearby: no later stage would replace it."""
    if _best_covers_little(candidates, checks, order, model, objects_tree, d, covers):
        return False
    best = checks[order[0]]
    return best.unexplained <= HOP_UNEXPLAINED * best.explained


def _polish(
    i: int,
    candidates: list[PoseHypothesis],
    checks: list[Consistency],
    model: Any,
    objects: FloatArray,
    d: float,
    rng: np.random.Generator,
    check: Callable[[PoseHypothesis], Consistency],
) -> None:
    """A full ICP of candidate ``i`` on the object points near it, checked again: it replaces
    the candidate when still consistent with at least :data:`POLISH_KEEP` of its net
    support, and is appended as a candidate of its own otherwise (lists changed in place)."""
    polished = _refine_near([candidates[i]], model, objects, d, rng)
    if not polished:
        return
    h = polished[0]
    c = check(h)
    if c.ok and checks[i].ok and c.support >= POLISH_KEEP * checks[i].support:
        candidates[i], checks[i] = h, c
    else:
        candidates.append(h)
        checks.append(c)


def _rest(
    i: int,
    candidates: list[PoseHypothesis],
    checks: list[Consistency],
    model: Any,
    objects: FloatArray,
    table: Any,
    d: float,
    check: Callable[[PoseHypothesis], Consistency],
) -> bool:
    """Candidate ``i`` set to rest on the table (:func:`rested_pose`) and refined by ICP that
    turns it only about the normal of the face it rests on (its position free: the table's
    fitted plane is not the object's underside to a tenth of a millimetre); it replaces the
    candidate when consistent with at least :data:`REST_KEEP` of its net support (lists
    changed in place). Returns whether it did.

    An object touching the table with a support face a few degrees from facing it is not at
    rest; noisy points tilt a free ICP that far (stereo cube, tuning seeds 1044 and 1063:
    6.8 and 6.4 deg of tilt, nothing else wrong), and the constrained fit keeps what they
    say of the position and the yaw. A candidate that failed its check only by sinking into
    the table is set to rest too, and replaces itself when that passes (tuning seed 1099: 4 mm
    from the truth, 18 % of its surface under the table; rested, 0.9 mm and the best)."""
    before = checks[i]
    sunk = (
        not before.ok
        and before.penetration > 0
        and before.inside + before.below <= 0.05 * max(before.explained, 1)
    )
    if table is None or not (before.ok or sunk):
        return False
    normals = _support_normals(model)
    got = rested_pose(candidates[i].matrix, model, table, normals, REST_TILT_DEG, REST_GAP_D * d)
    if got is None:
        return False
    T0, face = got
    pts = np.asarray(model.surface_points(), dtype=np.float64)
    surface = _model_surface(model, pts)
    near = _points_near(T0, pts, objects, d)
    if len(near) < 10:
        return False
    icp = icp_point_to_plane(
        surface, near, T0, max_distance=max(4 * d, 0.1 * surface.size), axis=face
    )
    score = score_pose(surface, near, icp.matrix, d, WORKSTATION_COMPILED)[0]
    h = PoseHypothesis(
        icp.matrix,
        icp.matrix[:3, 3].copy(),
        votes=candidates[i].votes,
        rmse=icp.rmse,
        score=score,
    )
    c = check(h)
    if c.ok and (sunk or c.support >= REST_KEEP * before.support):
        candidates[i], checks[i] = h, c
        return True
    return False


def _rest_best(
    order: list[int],
    candidates: list[PoseHypothesis],
    checks: list[Consistency],
    model: Any,
    objects: FloatArray,
    table: Any,
    d: float,
    check: Callable[[PoseHypothesis], Consistency],
) -> int:
    """:func:`_rest` for the :data:`REST_BEST` best-ranked candidates (a rested best would
    otherwise lose the ranking to a tilted near-copy of itself by a few noisy points: stereo
    cube, tuning seed 1063, 0.4 deg rested vs 4.3 deg, 5 points of 680); how many rested."""
    return sum(
        _rest(i, candidates, checks, model, objects, table, d, check) for i in order[:REST_BEST]
    )


_SUPPORT_NORMALS: dict[int, tuple[Any, list[FloatArray]]] = {}


def _support_normals(model: Any) -> list[FloatArray]:
    """:func:`support_normals` of a model, once per model object (the model is kept with
    them, so its id is not reused while cached)."""
    hit = _SUPPORT_NORMALS.get(id(model))
    if hit is None or hit[0] is not model:
        if len(_SUPPORT_NORMALS) > 64:
            _SUPPORT_NORMALS.clear()
        hit = (model, support_normals(model))
        _SUPPORT_NORMALS[id(model)] = hit
    return hit[1]


def _whole(check: Consistency) -> Consistency:
    """The check, inconsistent when the pose leaves more than :data:`MAX_UNEXPLAINED` of its
    explained count unexplained nearby (it covers only part of an object)."""
    if check.ok and check.unexplained > MAX_UNEXPLAINED * check.explained:
        return replace(check, ok=False)
    return check


def _top(candidates: list[PoseHypothesis], n: int) -> list[int]:
    """Indices of the ``n`` best-scored candidates (nan last), in that order."""
    return sorted(range(len(candidates)), key=lambda i: -np.nan_to_num(candidates[i].score))[:n]


def _best_coarse(
    hyps: list[PoseHypothesis], model: Any, objects_tree: cKDTree | NearPoints, d: float, n: int
) -> list[PoseHypothesis]:
    """The ``n`` coarse poses explaining the most object points (one batch query on the
    object points' tree)."""
    from mks_sim.localization.verify import batch_explained

    if len(hyps) <= n or objects_tree.n == 0:
        return hyps
    good = [h for h in hyps if np.asarray(h.matrix).shape == (4, 4)]
    if len(good) <= n:
        return good
    # fraction of the model samples near object points (the scene holds other objects too)
    pts = np.asarray(model.surface_points(), dtype=np.float64)
    pts = pts[:: max(1, len(pts) // 300)]
    score = batch_explained(pts, np.stack([h.matrix for h in good]), objects_tree, 2 * d)
    return [good[i] for i in np.argsort(-score, kind="stable")[:n]]


@functools.lru_cache(maxsize=1)
def _known_sphere_radii() -> tuple[float, ...]:
    """Radii of the database's sphere models (metres)."""
    try:
        db = default_db()
    except MksError:
        return ()
    radii = []
    for name in db.names():
        r = getattr(db.get(name), "radius_m", None)
        if isinstance(r, float) and r > 0:
            radii.append(r)
    return tuple(sorted(set(radii)))


def _best_covers_little(
    candidates: list[PoseHypothesis],
    checks: list[Consistency],
    order: list[int],
    model: Any,
    objects_tree: cKDTree | NearPoints,
    d: float,
    covers: Coverages | None = None,
) -> bool:
    """No consistent candidate, or the best shows less of the model's surface than one view
    does (:data:`VISIBLE_FRACTION` of its samples with an object point within ``d``, from
    ``objects_tree``, the object points' k-d tree; a fraction of the model's fixed sampling,
    independent of the scan density): the object may be another, partly hidden segment.
    ``covers``: the coverages computed so far, by candidate (one localization asks of the
    same best again once its candidates settled)."""
    from mks_sim.localization.verify import surface_coverage

    if not order or not checks[order[0]].ok or objects_tree.n == 0:
        return True
    best = candidates[order[0]]
    hit = None if covers is None else covers.get(id(best))
    if hit is None or hit[0] is not best:
        T = np.asarray(best.matrix, dtype=np.float64)
        hit = (best, float(surface_coverage(model.surface_points(), T[None], objects_tree, d)[0]))
        if covers is not None:
            covers[id(best)] = hit
    return hit[1] < VISIBLE_FRACTION


#: The coverages :func:`_best_covers_little` computed, by ``id`` of the candidate (kept with
#: it: an id is reused only after its object is gone).
Coverages = dict[int, tuple[PoseHypothesis, float]]


def _unexplained_segments(
    segments: list[Any],
    candidates: list[PoseHypothesis],
    checks: list[Consistency],
    model: Any,
    d: float,
) -> list[Any]:
    """The object segments that no consistent candidate explains (less than
    :data:`SUPPORT_EXPLAINED_FRACTION` of their points within ``d`` of one of the posed
    models): they get the support-face hypotheses (an object seen only partly, e.g. under
    the sphere, gives no vertexes). A fraction, not a point count: independent of density."""
    pts = np.asarray(model.surface_points(), dtype=np.float64)
    posed = [
        pts @ np.asarray(h.matrix)[:3, :3].T + np.asarray(h.matrix)[:3, 3]
        for h, c in zip(candidates, checks)
        if c.ok
    ]
    trees = [cKDTree(P) for P in posed]
    out = []
    for seg in segments:
        covered = np.zeros(len(seg.points), dtype=bool)
        for tree in trees:
            covered |= np.isfinite(tree.query(seg.points, distance_upper_bound=d)[0])
        if covered.mean() < SUPPORT_EXPLAINED_FRACTION:
            out.append(seg)
    return out


def _model_surface(model: Any, pts: FloatArray) -> ModelSurface:
    """The model's own :class:`ModelSurface` when it holds ``pts``, else one built from them."""
    surface = getattr(model, "surface", None)
    if not isinstance(surface, ModelSurface) or surface.points is not pts:
        surface = ModelSurface.from_arrays(pts, model.surface_normals())
    return surface


def _hop(
    best: PoseHypothesis, model: Any, objects: FloatArray, d: float, rng: np.random.Generator
) -> list[PoseHypothesis]:
    """ICP from copies of ``best`` shifted along its horizontal axes (by :data:`HOP_SHIFTS`
    of the model's size), turned about the vertical by quarter turns and half round about
    its own axes: the three that explain the most of the object points near it after ICP
    (coarse ICP from every start, full ICP of the three best)."""
    pts = np.asarray(model.surface_points(), dtype=np.float64)
    T0 = np.asarray(best.matrix, dtype=np.float64)
    size = float(model.surface.size)
    centre = T0[:3, :3] @ column_mean(pts) + T0[:3, 3]
    starts = []
    for axis in T0[:3, :3].T:
        horizontal = np.array([axis[0], axis[1], 0.0])
        norm = float(np.linalg.norm(horizontal))
        if norm < 0.5:
            continue  # a near-vertical axis: shifts along it leave the table
        for step in HOP_SHIFTS:
            for sign in (-1.0, 1.0):
                T = T0.copy()
                T[:3, 3] += sign * step * size * horizontal / norm
                starts.append(T)
    turns = [rotation_about(np.array([0.0, 0.0, 1.0]), a * np.pi) for a in (0.5, 1.0, 1.5)]
    turns += [rotation_about(axis, np.pi) for axis in T0[:3, :3].T]
    radius = float(np.max(row_norms(pts - column_mean(pts))))
    near = objects[np.linalg.norm(objects - centre, axis=1) <= radius * (1 + max(HOP_SHIFTS))]
    # Turned about the model's centre and about the centre of the points seen near it (a
    # part seen from one side turns about what is seen), then set back down to the best's
    # lowest point (it rests where it did).
    pivots = [centre] if len(near) == 0 else [centre, near.mean(axis=0)]
    low = float(np.min(pts @ T0[2, :3] + T0[2, 3]))
    for R in turns:
        for pivot in pivots:
            T = T0.copy()
            T[:3, :3] = R @ T0[:3, :3]
            T[:3, 3] = R @ (T0[:3, 3] - pivot) + pivot
            T[2, 3] += low - float(np.min(pts @ T[2, :3] + T[2, 3]))
            starts.append(T)
    # starts that are the best itself under a symmetry of the model (the cube turned about
    # its centre) would only find it again
    same = group_equivalent(
        [T0, *starts], model.symmetries(), rotation_tol_deg=8.0, translation_tol=0.05 * size
    )
    starts = [T for T, label in zip(starts, same[1:], strict=True) if label != 0]
    if not starts:
        return []
    surface = _model_surface(model, pts)
    verified = verify_hypotheses(
        [PoseHypothesis(T, T[:3, 3].copy()) for T in starts],
        surface,
        near,
        inlier_distance=d,
        icp_distance=max(4 * d, 0.1 * surface.size),
        symmetries=model.symmetries(),
        max_icp=len(starts),
        full_refine=3,
        max_scene_points=1000,
        coarse_points=300,
        rng=rng,
        **COMPILED_VERIFY,
    )
    return [v.hypothesis for v in verified[:3]]


def _points_near(T: FloatArray, pts: FloatArray, objects: FloatArray, d: float) -> FloatArray:
    """The object points within the model's bounding sphere (about its samples' centroid,
    ``pts`` in the model frame) + 2 ``d`` of pose ``T``: what ICP of that pose fits."""
    centre = column_mean(pts)
    radius = float(np.max(row_norms(pts - centre)))
    c = T[:3, :3] @ centre + T[:3, 3]
    return objects[norm_within(objects, c, radius + 2 * d)]


def _refine_near(
    hyps: list[PoseHypothesis], model: Any, objects: FloatArray, d: float, rng: np.random.Generator
) -> list[PoseHypothesis]:
    """ICP-refine coarse poses on the object points near each (model -> world)."""
    if not hyps or len(objects) < 10:
        return []
    pts = np.asarray(model.surface_points(), dtype=np.float64)
    surface = _model_surface(model, pts)
    out: list[PoseHypothesis] = []
    for h in hyps:
        T = np.asarray(h.matrix, dtype=np.float64)
        if T.shape != (4, 4) or not np.all(np.isfinite(T)):
            continue
        near = _points_near(T, pts, objects, d)
        if len(near) < 10:
            continue
        verified = verify_hypotheses(
            [h],
            surface,
            near,
            inlier_distance=d,
            icp_distance=max(4 * d, 0.1 * surface.size),
            symmetries=model.symmetries(),
            max_icp=1,
            max_scene_points=1000,
            rng=rng,
            **COMPILED_VERIFY,
        )
        out.extend(v.hypothesis for v in verified)
    return out


def localize_sphere(
    model: Any,
    snap: Any,
    sensor: str,
    rep: Representation,
    rng: np.random.Generator,
    timing: dict[str, float],
) -> tuple[list[PoseHypothesis], dict[str, Any]]:
    """Sphere: Sphere_Detector rows of the model's radius plus a fixed-radius centre Hough
    (votes ``p - r n``), each refined by a fixed-radius robust fit and scored by how much of
    the sphere's upper cap the sensed points cover."""
    del rng
    extra: dict[str, Any] = {}
    t = time.perf_counter()
    try:
        rows = np.asarray(snap.get(sensor).data, dtype=np.float64).reshape(-1, 4)
    except MksError as exc:
        log.info("logical sensor %s unavailable: %s", sensor, exc)
        rows = np.zeros((0, 4))
    extra["detected_features"] = len(rows)
    radius = float(model.radius_m)
    match = model.match(rows) if hasattr(model, "match") else np.arange(len(rows))
    extra["matched"] = len(match)
    objects = rep.objects
    d = _noise_scale(rep.table, rep.spacing)
    seeds = [rows[i, :3] for i in match]
    seeds += sphere_centre_hough(objects, radius, rep.normals.normals)
    timing["hypotheses"] = time.perf_counter() - t
    extra["candidates"] = len(seeds)

    t = time.perf_counter()
    scored = score_spheres(objects, seeds, radius, d)
    scored.sort(key=lambda x: (not x[2]["ok"], -x[0], x[1].rmse))
    extra["inlier_distance_m"] = d
    extra["checks"] = [chk for _, _, chk in scored[:5]]
    good: list[PoseHypothesis] = []
    for _, h, chk in scored:
        if chk["ok"] and all(np.linalg.norm(h.matrix[:3, 3] - g.matrix[:3, 3]) > d for g in good):
            good.append(h)
    timing["verification"] = time.perf_counter() - t
    return good, extra
