"""Multi-instance localization: every instance of one model in a point cloud (bin picking).

The paper localizes one object per model; a bin holds many copies that touch and occlude
each other, so one SPG segment may hold several instances and an instance's score over its
segment is diluted by its neighbours. :func:`localize_all` therefore votes repeatedly with the
explained points removed (issue 13):

1. each pass runs the one-model pipeline (:func:`mks_sim.localize.localize_cloud`: SPG ->
   grouping -> vertex / plane-pair Hough -> ICP) on the points no accepted instance explains;
2. per segment, the best hypotheses are polished by ICP on the unclaimed points near them and
   checked against the WHOLE cloud (:func:`~mks_sim.localization.verify.consistency`: no
   point seen through the posed model, none under it, no table penetration);
3. the first consistent one that is new -- its centre farther than ``same_fraction`` x the
   model size from every accepted instance's or overlapping each nearer one less than
   :data:`SAME_OVERLAP`, and most of its explained points not claimed
   already -- is accepted and its points (within 2 inlier distances of the whole posed
   surface) are claimed;
4. a segment none of whose candidates passes votes again with the object's alternate model
   (its free-form model: point-pair features need no visible corner or face pair, which a
   pile hides), then, if nothing passes still, is split into clusters that vote on their own;
5. passes repeat until one accepts nothing, ``max_instances`` are found or too few points
   are left.

No instance is reported twice (the two tests of step 3). The instance score is the coverage
of what one view of the model shows (explained points over :data:`VISIBLE_FRACTION` of its
area at the cloud's spacing, capped at 1) times the fraction of near points that agree with
the pose: a well-seen, consistent instance scores near 1, a half-buried one lower.

Example:
    >>> from mks_sim.localization.instances import localize_all
    >>> result = localize_all(model, points, table=plane)  # doctest: +SKIP
    >>> [inst.matrix for inst in result.instances]  # doctest: +SKIP
"""

from __future__ import annotations

import logging
import time
from collections.abc import Sequence
from dataclasses import dataclass, field, replace
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray
from scipy.spatial import cKDTree

from mks_sim.errors import DataError
from mks_sim.localization.verify import Consistency, batch_explained, consistency
from mks_sim.lowlevel.regions import Plane
from mks_sim.models.pose import PoseHypothesis

__all__ = ["Instance", "Instances", "localize_all", "pose_stability"]

log = logging.getLogger(__name__)
FloatArray = NDArray[np.float64]

#: Part of a model's surface one view of a well-seen instance shows (score 1): the single-object
#: pipeline's 0.2 saturates for most instances of a pile, and the score orders the picks.
VISIBLE_FRACTION = 0.35
#: Pile consistency (:func:`_pile_ok`): points seen through the posed model at most this
#: fraction of the points it explains (true poses: 0; wrong ones measured 2-15 %).
MAX_INSIDE = 0.01
#: Two poses closer than ``same_fraction`` of the size are one instance when this fraction
#: of one's surface lies on or in the other (:func:`_overlap`); below it they are two parts
#: touching. Tuning bin 11: a part's true pose, its centre 29.8 mm from a neighbour's (under
#: the 30 mm of 0.25 x the size) with 13 % overlap, was taken for the neighbour, and its
#: near-twin, whose centre lies farther, was reported instead (180 deg off). The industrial
#: part against itself: near-twin 0.80, shifted 10 mm 0.90, 20 mm 0.77.
SAME_OVERLAP = 0.5
OVERLAP_SAMPLES = 400
#: Turned-over poses (:func:`_turned_over`) checked when no candidate of a segment passed, or
#: when the accepted one sees points through itself.
FLIPS_CHECKED = 3
#: A turned-over pose is accepted only at this score or more: turned over, a candidate that
#: failed its check finds a consistent but wrong pose at times (tuning bin 13: a part 8 mm
#: off and turned 180 deg, score 0.58-0.62, explaining parts of two others); the right ones
#: of tuning bin 15 scored 0.72-1.0.
MIN_FLIP_SCORE = 0.7
#: The turns that compete with an accepted pose seen through also slide along the model's box
#: axes, every this x the size (:func:`_turned_over`'s ``step``: 79 turns for the part, 5 mm
#: steps). Tuning bin 55: a part 41 % visible was reported turned 180 deg about its height
#: axis and 19.8 mm along its length (616 points, 5 seen through it), which the turns through
#: the box's centre and face centres do not reach. Fresh tuning bins 40-59: instances >= 30 %
#: visible found 92 -> 93 of 103, false positives 2 -> 1; bins 0-19: see docs/bin.md. Slid
#: turns for a segment where nothing passed added wrong instances (bin 53: 6 -> 1 found).
SLIDE_STEP = 0.04
#: Among the moves competing with an accepted pose seen through (its turns and nudges), a
#: point seen through a pose costs it as many explained points: tuning bin 42, a part 30 %
#: visible reported as its near-twin explained 697 points and saw 5 through itself, the
#: truth 694 and none. Weighing every comparison so cost instances (tuning bin 26: a pose
#: with nothing seen through it won early, and no turn was tried).
INSIDE_WEIGHT = 10.0
#: Nudges (:func:`_nudged`) of a pose still seen through after its turns: turns by this
#: many degrees, shifts by :data:`NUDGE_STEP` x the size (4.8 mm for the part).
NUDGE_DEG = 20.0
NUDGE_STEP = 0.04
#: An instance is reported only when its explained points pin its pose down: its
#: :func:`pose_stability` at least this. Tuning bins 0-59 (one run, 350 instances reported):
#: the false positive of bin 18 (a part 21 % visible, 4.1 mm / 5.1 deg off, nothing seen
#: through it, 503 points against the truth's 506) 0.0022; the true instances 0.0052 and up
#: (0.0052, 0.0053, then 0.0089); the two other false positives 0.008 (bin 51) and 0.027 (52,
#: a near-twin). About the geometric middle of 0.0022 and 0.0052.
MIN_STABILITY = 0.0035
#: An instance is reported only when at most this fraction of the points it explains, or
#: one point, is seen through it (``check.inside``; :data:`MAX_INSIDE` lets up to 1 % pass, so
#: that the pile's points are claimed and its turns compete). Tuning bins 0-29 at ``cd2fe37``,
#: range finder failed (one run, 174 instances reported): the 5 false positives saw 4-10
#: points through themselves, 0.38-0.84 % of what they explained (three of them the part
#: turned 180 deg); of the 169 true ones 158 saw none, 10 one (at most 0.18 %) and one 3
#: (0.26 %). Healthy, 171 true instances: none more than one. Between 0.26 and 0.38 %; the
#: one point spares a small instance a stray point (1 of 300 explained is 0.33 %). Bins
#: 30-59, not used to choose it: failed, 2 of the 3 false positives over it (5 and 11
#: points, 0.43 and 0.84 %; the third saw 1), no true instance (at most 4 points, 0.20 %);
#: healthy, no false positive, no true instance over 1 point.
MAX_INSIDE_REPORTED = 0.003
#: A segment with at least this many unclaimed points, none of whose candidates passed,
#: votes with the object's alternate model (its free-form model) before it is split.
ALTERNATE_MIN_POINTS = 60


@dataclass(frozen=True, eq=False)
class Instance:
    """One localized instance.

    Attributes:
        matrix: (4, 4) model -> world (column convention, the points' units).
        score: coverage x agreement in [0, 1] (module docstring).
        explained: points within the inlier distance of the posed model's visible surface.
        check: the scene-consistency check over the whole cloud.
        points: (n,) indices into the input points this instance claimed.
        found_in_pass: the voting pass (0-based) that found it.
        stability: how well its explained points pin the pose down (:func:`pose_stability`).
    """

    matrix: FloatArray
    score: float
    explained: int
    check: Consistency
    points: NDArray[np.intp] = field(repr=False)
    found_in_pass: int
    stability: float = 1.0


@dataclass(frozen=True, eq=False)
class Instances:
    """Result of :func:`localize_all`.

    Attributes:
        instances: best score first.
        passes: voting passes run.
        table: the table plane used (None: none).
        inlier_distance: the match distance (points' units).
        timing: seconds (``passes``, ``verification``, of it ``alternate``: the alternate
            model's votes, ``total``).
        unsure: instances found whose pose their points do not pin down (stability under
            ``min_stability``) or that points are seen through (more than
            ``max_inside_reported`` of what they explain): not reported in ``instances``, their
            points claimed still.
    """

    instances: tuple[Instance, ...]
    passes: int
    table: Plane | None
    inlier_distance: float
    timing: dict[str, float]
    unsure: tuple[Instance, ...] = ()

    @property
    def found(self) -> int:
        """Number of instances found."""
        return len(self.instances)


def _posed(T: FloatArray, pts: FloatArray) -> FloatArray:
    return pts @ T[:3, :3].T + T[:3, 3]


def localize_all(
    model: Any,
    points: ArrayLike,
    *,
    table: Plane | None = None,
    inlier_distance: float | None = None,
    max_instances: int = 12,
    max_passes: int = 8,
    same_fraction: float = 0.25,
    min_new_fraction: float = 0.5,
    min_score: float = 0.3,
    per_segment: int = 4,
    max_split: int = 6,
    rng: np.random.Generator | None = None,
    prior: Sequence[ArrayLike] = (),
    alternate: Any = None,
    min_stability: float = MIN_STABILITY,
    max_inside_reported: float = MAX_INSIDE_REPORTED,
) -> Instances:
    """Every instance of ``model`` in ``points`` (module docstring).

    Args:
        model: a localizable polyhedral model (``mks_sim.localize.PolyhedralModel``: its
            surface samples, normals and size).
        points: (N, 3) the sensed points (world frame), table included or not; NaN rows
            are ignored.
        table: the supporting plane (normal up), e.g. from
            :func:`~mks_sim.localization.verify.find_table`; None: the pipeline looks for one.
        inlier_distance: match distance; default 3 sigma of the table's fit, at least 3 mm.
        max_instances: stop after this many.
        max_passes: voting passes at most.
        same_fraction: two poses whose model centres are closer than this x the model's size
            are one instance when they overlap (:data:`SAME_OVERLAP`).
        min_new_fraction: a candidate must explain at least this fraction of points no
            accepted instance claimed.
        min_score: instances scoring less are not reported (fragments, wrong poses).
        per_segment: candidates checked per segment and pass.
        max_split: a segment no candidate explains is split into at most this many clusters.
        rng: generator (RANSAC, ICP subsets); default seeded 0.
        prior: (4, 4) poses found before in part of these points (an earlier view, best
            first): each is polished and checked like a voted candidate, before any voting,
            and kept when it passes. Re-voting a fused cloud from scratch lost instances the
            first view had found (another view changes the segments); a prior that the new
            points show to be wrong (points seen through it) fails the check and is dropped.
        alternate: a second model of the same object in the same frame with a
            ``hypotheses(points)`` method (the object's free-form model,
            :func:`instance_alternate`): a segment none of whose candidates passes votes
            with it on its unclaimed points before it is split (:data:`ALTERNATE_MIN_POINTS`).
        min_stability: instances whose :func:`pose_stability` is lower are found (their
            points claimed) but not reported: ``Instances.unsure``.
        max_inside_reported: so are instances through which more than this fraction of the
            points they explain, and more than one point, is seen (:data:`MAX_INSIDE_REPORTED`).

    Returns:
        :class:`Instances`.

    Raises:
        DataError: malformed points.
    """
    from mks_sim.localize import localize_cloud
    from mks_sim.models.refine import ModelSurface, near_symmetries, verify_hypotheses

    t0 = time.perf_counter()
    rng = np.random.default_rng(0) if rng is None else rng
    cloud = np.asarray(points, dtype=np.float64)
    if cloud.ndim != 2 or cloud.shape[1] != 3:
        raise DataError(f"localize_all: expected (N, 3) points, got shape {cloud.shape}")
    finite = np.flatnonzero(np.all(np.isfinite(cloud), axis=1))
    cloud = cloud[finite]
    if len(cloud) < 30:
        raise DataError(f"localize_all: expected at least 30 finite points, got {len(cloud)}")
    tree = cKDTree(cloud)
    surf_pts = np.asarray(model.surface_points(), dtype=np.float64)
    surf_nrm = np.asarray(model.surface_normals(), dtype=np.float64)
    surface = ModelSurface.from_arrays(surf_pts, surf_nrm)
    size = float(surface.size)
    centre = surf_pts.mean(axis=0)
    radius = float(np.max(np.linalg.norm(surf_pts - centre, axis=1)))
    twins = near_symmetries(surf_pts, model.symmetries())
    flips = _turned_over(surf_pts)
    slides = _turned_over(surf_pts, step=SLIDE_STEP * size)
    flip_samples = surf_pts[:: max(1, len(surf_pts) // 300)]
    nudges = _nudged(surf_pts, NUDGE_DEG, NUDGE_STEP * size)
    d = inlier_distance
    if d is None:
        d = 0.003 if table is None or table.rmse <= 0 else max(0.003, 3.0 * table.rmse)
    d = float(d)
    # object points: above the table band (the table is no instance)
    above = np.ones(len(cloud), dtype=bool)
    if table is not None:
        above = table.distance(cloud) > max(d, 0.003)
    claimed = ~above
    spacing = float(np.median(tree.query(cloud[above][:5000], k=2)[0][:, 1])) if above.any() else d
    model_area = len(surf_pts) * (surface.spacing / 0.47) ** 2
    expected = VISIBLE_FRACTION * model_area / max(spacing, 1e-12) ** 2
    timing = {"passes": 0.0, "verification": 0.0, "alternate": 0.0}
    found: list[Instance] = []
    passes = 0
    t = time.perf_counter()

    def as_instance(
        h: PoseHypothesis, free: NDArray[np.intp], use_table: Plane | None, pass_index: int
    ) -> Instance | None:
        """``h`` polished and checked as a new instance (:func:`_check`) when it passes and
        scores at least ``min_score``, else None."""
        inst = _check(
            h, cloud, tree, free, claimed, found, surface, surf_pts, surf_nrm, use_table, d,
            centre, radius, size, same_fraction, min_new_fraction, expected, pass_index, rng,
            verify_hypotheses,
        )  # fmt: skip
        return inst if inst is not None and inst.score >= min_score else None

    for T in prior:
        T = np.asarray(T, dtype=np.float64)
        if T.shape != (4, 4) or not np.all(np.isfinite(T)) or len(found) >= max_instances:
            continue
        free = np.flatnonzero(~claimed)
        inst = as_instance(PoseHypothesis(T, T[:3, :3] @ centre + T[:3, 3]), free, table, 0)
        if inst is not None:
            if inst.check.inside > 0:
                # seen through: its near-twins compete, as for a voted pose seen through
                # (INSIDE_WEIGHT). The earlier view may have been too sparse to tell them
                # apart (range finder failed, tuning bins 14, 50, 52, 58: a part reported
                # turned 180 deg explained 951-1903 points and saw 1-16 through itself, its
                # twin -- the truth -- 1086-1943 and none)
                for W in twins:
                    Tw = inst.matrix @ W
                    twin = as_instance(
                        PoseHypothesis(Tw, Tw[:3, :3] @ centre + Tw[:3, 3]), free, table, 0
                    )
                    if twin is not None and _merit(twin, INSIDE_WEIGHT) > _merit(
                        inst, INSIDE_WEIGHT
                    ):
                        inst = twin
            found.append(inst)
            claimed[inst.points] = True
    timing["verification"] += time.perf_counter() - t
    for passes in range(1, max_passes + 1):  # noqa: B007 - reported
        free = np.flatnonzero(~claimed)
        if len(free) < 60 or len(found) >= max_instances:
            passes -= 1
            break
        t = time.perf_counter()
        # (thorough: the verification bin picking was measured with, issue 13)
        loc = localize_cloud(
            model, cloud[free], table=table if table is not None else "auto", voxel=None,
            thorough=True, rng=rng,
        )  # fmt: skip
        timing["passes"] += time.perf_counter() - t
        t = time.perf_counter()
        accepted = 0
        by_segment: dict[int, list[PoseHypothesis]] = {}
        for h, si in zip(loc.hypotheses, loc.segment_of, strict=True):
            by_segment.setdefault(si, []).append(h)
        use_table = table if table is not None else loc.table

        free_tree: list[cKDTree] = []  # of the pass's free points, built when first asked

        def accept(
            hyps: list[PoseHypothesis],
            free: NDArray[np.intp] = free,
            use_table: Plane | None = use_table,
            pass_index: int = passes - 1,
            free_tree: list[cKDTree] = free_tree,
        ) -> bool:
            def better(
                h: PoseHypothesis, best: Instance | None, weigh: float = 0.0
            ) -> Instance | None:
                """``h`` checked as an instance when it passes and explains more points than
                ``best`` (a part and its near-twin flipped pose both fit; the right one
                explains more), else ``best``."""
                inst = as_instance(h, free, use_table, pass_index)
                if inst is None:
                    return best
                return inst if best is None or _merit(inst, weigh) > _merit(best, weigh) else best

            def better_of(poses: Any, best: Instance | None, weigh: float = 0.0) -> Instance | None:
                """:func:`better` over (4, 4) poses in turn."""
                for T in poses:
                    best = better(PoseHypothesis(T, T[:3, :3] @ centre + T[:3, 3]), best, weigh)
                return best

            def turned_over(pose: FloatArray, turns: FloatArray = flips) -> FloatArray:
                """The :data:`FLIPS_CHECKED` ``turns`` of ``pose`` (:func:`_turned_over`)
                that land the most model samples on free points (one batch query)."""
                if not free_tree:
                    free_tree.append(cKDTree(cloud[free]))
                turned = pose @ turns
                n_near = batch_explained(flip_samples, turned, free_tree[0], 2 * d)
                return turned[np.argsort(-n_near, kind="stable")[:FLIPS_CHECKED]]

            best: Instance | None = None
            for h in hyps[:per_segment]:
                best = better(h, best)
            # the near-twin poses of the best (of the first candidate when none passed):
            # the part turned about its height axis fits the same points but for features
            # the pile may hide (tuning bin 9: a part 40 % visible was found turned 180 deg,
            # score 0.99), or shows them and fails where its twin passes
            if best is not None:
                base = best.matrix
            elif hyps:
                base = np.asarray(hyps[0].matrix, dtype=np.float64)
            else:
                return False
            polished = best is not None
            best = better_of(base @ twins, best)
            if not polished and best is not None:
                # the twin of an unpolished candidate passed (the candidate itself, a few mm
                # off, did not): the candidate's turn again, now about the polished pose
                # (tuning bins 29 and 32: the twin won with 868 and 571 points, its own twin
                # explains 1047 and 589 and sees nothing through itself)
                best = better_of(best.matrix @ twins, best)
            if best is not None and best.check.inside > 0:
                # an accepted pose through which points are seen may be the part turned
                # over (tuning bin 26: 0.8 mm and 179.5 deg off about the model's y axis
                # explained 1135 points and saw 8 through itself, the turned-over truth
                # 1492 and none): its best turns compete. Turning every accepted pose
                # cost instances (tuning bins 20-39: 98 -> 95 of 103 found: a turn
                # explaining a neighbour's points as well took them). The turns slide too
                # (:data:`SLIDE_STEP`)
                best = better_of(turned_over(best.matrix, slides), best, INSIDE_WEIGHT)
            if best is None:
                # nothing passed: the first candidate turned over (a part lying upside down
                # shows its flat bottom, which the upright pose puts its own bottom on:
                # tuning bin 15, candidates 0.5 mm and 178 deg off a part explained 270 of
                # its 1150 points)
                best = better_of(turned_over(base), best)
                if best is not None and best.score < MIN_FLIP_SCORE:
                    best = None
            if best is not None and best.check.inside > 0:
                # still seen through: small moves of it compete, ICP-polished from there
                # (tuning bin 22: a part 4.1 mm and 18.7 deg off, 1181 points and 6 seen
                # through it, where the truth explains 1254 and sees none; bin 12: 5.4 mm
                # along its length, 933 points and 3 through, the truth 935 and none)
                best = better_of(best.matrix @ nudges, best, INSIDE_WEIGHT)
            if best is None:
                return False
            found.append(best)
            claimed[best.points] = True
            return True

        for si, seg in enumerate(loc.segments):
            if len(found) >= max_instances:
                break
            if accept(by_segment.get(si, [])):
                accepted += 1
                continue
            members = free[np.asarray(seg.indices, dtype=np.intp)]
            members = members[~claimed[members]]
            if alternate is not None and len(members) >= ALTERNATE_MIN_POINTS:
                # the other model kind votes on the segment: point-pair features need no
                # corner or face pair, which a pile hides (tuning bin 40: three parts
                # 34-52 % visible whose polyhedral candidates all landed 17-22 mm off)
                t_alt = time.perf_counter()
                alt = list(alternate.hypotheses(cloud[members]))
                timing["alternate"] += time.perf_counter() - t_alt
                if accept(alt):
                    accepted += 1
                    continue
            # Touching instances share one segment and its candidates fit none of them
            # (ICP is pulled by the neighbours): split it into about as many spatial clusters
            # as instances it could hold (one view shows ~2 x VISIBLE_FRACTION of a part)
            # and vote in each.
            k = int(np.clip(round(len(members) / (2.0 * expected)), 2, max_split))
            if len(members) < 2 * 60:
                continue
            labels = _split(cloud[members], k, rng)
            for c in range(k):
                part = members[labels == c]
                if len(part) < 60 or len(found) >= max_instances:
                    continue
                sub = localize_cloud(
                    model, cloud[part], table=use_table if use_table is not None else "none",
                    voxel=None, thorough=True, rng=rng,
                )  # fmt: skip
                if accept(list(sub.hypotheses)):
                    accepted += 1
        timing["verification"] += time.perf_counter() - t
        if table is None:
            table = loc.table
        if not accepted:
            break
    found.sort(key=lambda i: -i.score)
    sure = [_reportable(i, min_stability, max_inside_reported) for i in found]
    unsure = [i for i, ok in zip(found, sure, strict=True) if not ok]
    found = [i for i, ok in zip(found, sure, strict=True) if ok]
    timing["total"] = time.perf_counter() - t0
    log.info(
        "localize_all(%s): %d instances in %d passes, %.2f s",
        getattr(model, "name", "?"),
        len(found),
        passes,
        timing["total"],
    )
    # indices into the caller's array (NaN rows were dropped)
    found = [replace(i, points=finite[i.points]) for i in found]
    unsure = [replace(i, points=finite[i.points]) for i in unsure]
    return Instances(tuple(found), passes, table, d, timing, tuple(unsure))


def _overlap(A: FloatArray, B: FloatArray, surface: Any, d: float) -> float:
    """Fraction of the model's surface at pose ``A`` that lies on or inside the model at pose
    ``B`` (within ``2 d`` of its surface or behind its nearest sample's normal): about 1 for
    two estimates of one instance (a pose and its near-twin included), at most the share of
    a touching face for two solids that only touch."""
    pts = surface.points[:: max(1, len(surface.points) // OVERLAP_SAMPLES)]
    rel = np.linalg.solve(B, A)  # A's model frame -> B's
    q = pts @ rel[:3, :3].T + rel[:3, 3]
    dist, j = surface.tree.query(q)
    behind = np.einsum("ij,ij->i", q - surface.points[j], surface.normals[j]) < 0
    return float(np.mean((dist <= 2 * d) | behind))


def _turned_over(surf_pts: FloatArray, step: float | None = None) -> FloatArray:
    """(K, 4, 4) half turns of a model (model frame) about each axis of its samples'
    bounding box, through the box's centre and through the centres of the four faces
    parallel to the axis (K = 15): the poses of an object turned over onto another face, the
    face it was seen by kept in place. ``step``: also through the points every ``step``
    (about) between the centre and those face centres: the turned poses slid along the
    box's axes by twice that (an elongated part turned 180 degrees fits most of its own
    surface 20 mm along its length)."""
    lo, hi = surf_pts.min(axis=0), surf_pts.max(axis=0)
    mid, half = 0.5 * (lo + hi), 0.5 * (hi - lo)
    out = []
    for k in range(3):
        R = -np.eye(3)
        R[k, k] = 1.0
        pivots = [mid]
        for j in range(3):
            if j != k:
                n = max(1, int(round(half[j] / step))) if step else 1
                for off in np.linspace(-half[j], half[j], 2 * n + 1):
                    if off != 0.0:
                        p = mid.copy()
                        p[j] += off
                        pivots.append(p)
        for p in pivots:
            S = np.eye(4)
            S[:3, :3] = R
            S[:3, 3] = p - R @ p
            out.append(S)
    return np.stack(out)


def _nudged(surf_pts: FloatArray, degrees: float, step: float) -> FloatArray:
    """(12, 4, 4) small moves of a model (model frame): turns by +- ``degrees`` about each
    axis of its samples' bounding box through the box's centre, and shifts by +- ``step``
    along each axis (:data:`NUDGE_DEG`, :data:`NUDGE_STEP`)."""
    from scipy.spatial.transform import Rotation

    lo, hi = surf_pts.min(axis=0), surf_pts.max(axis=0)
    mid = 0.5 * (lo + hi)
    out = []
    for k in range(3):
        for sign in (1.0, -1.0):
            S = np.eye(4)
            S[:3, :3] = Rotation.from_rotvec(np.radians(sign * degrees) * np.eye(3)[k]).as_matrix()
            S[:3, 3] = mid - S[:3, :3] @ mid
            out.append(S)
    for k in range(3):
        for sign in (1.0, -1.0):
            S = np.eye(4)
            S[:3, 3] = sign * step * np.eye(3)[k]
            out.append(S)
    return np.stack(out)


def pose_stability(
    T: FloatArray, surface: Any, points: FloatArray, centre: FloatArray, radius: float
) -> float:
    """How well ``points`` (N, 3), explained by the model ``surface`` at pose ``T``, pin the
    pose down: the smallest eigenvalue of the point-to-plane fit's normal matrix per point,
    rotations as the displacement they cause at ``radius`` from the model's ``centre``
    (model frame). Each point contributes the row ``[(q - centre) x n / radius, n]`` (``q``
    the point in the model frame, ``n`` its nearest sample's normal). A motion along the
    smallest eigenvector moves the points off the surface least: about 0 for a pose free to
    slide or turn (one face, a cylinder's axis), at most 1/3 (normals evenly spread). The
    "geometric stability" of Gelfand et al., 3DIM 2003."""
    P = np.asarray(points, dtype=np.float64).reshape(-1, 3)
    if len(P) < 6:
        return 0.0
    q = (P - T[:3, 3]) @ T[:3, :3]
    _, j = surface.tree.query(q)
    n = surface.normals[j]
    J = np.hstack([np.cross(q - centre, n) / max(radius, 1e-12), n])
    return float(np.linalg.eigvalsh(J.T @ J / len(P))[0])


def _reportable(inst: Instance, min_stability: float, max_inside: float) -> bool:
    """``inst``'s explained points pin its pose down (:func:`pose_stability`) and at most
    ``max_inside`` of them, or one point, is seen through it (:data:`MAX_INSIDE_REPORTED`)."""
    return (
        inst.stability >= min_stability
        and inst.check.inside <= max(1.0, max_inside * inst.explained)
    )


def _merit(inst: Instance, weigh: float) -> float:
    """What :func:`localize_all`'s ``better`` compares: the points ``inst`` explains, less
    ``weigh`` per point seen through it."""
    return inst.explained - weigh * inst.check.inside


def _split(points: FloatArray, k: int, rng: np.random.Generator) -> NDArray[np.intp]:
    """(n,) cluster labels of ``points`` by k-means (k-means++ starts from ``rng``)."""
    from scipy.cluster.vq import kmeans2

    _, labels = kmeans2(points, k, seed=rng, minit="++")
    return np.asarray(labels, dtype=np.intp)


def _pile_ok(check: Consistency) -> bool:
    """The consistency test for a pile: nothing seen through the model (``inside`` at most
    :data:`MAX_INSIDE` of the explained points), no table penetration.

    The single-object test's ``below`` (points under the model in their vertical column)
    assumes the sensors look from above; in a pile the oblique range finder sees under the
    overhang of a part leaning on another and through the part's holes: measured on a
    6-part bin, every true pose had 20-75 % of its explained points "below", the wrong poses
    that ``below`` rejected all had points inside as well.
    """
    n = max(check.explained, 1)
    return bool(
        check.explained >= 30 and check.inside <= MAX_INSIDE * n and check.penetration <= 0.02
    )


def _check(
    h: PoseHypothesis,
    cloud: FloatArray,
    tree: cKDTree,
    free: NDArray[np.intp],
    claimed: NDArray[np.bool_],
    found: list[Instance],
    surface: Any,
    surf_pts: FloatArray,
    surf_nrm: FloatArray,
    table: Plane | None,
    d: float,
    centre: FloatArray,
    radius: float,
    size: float,
    same_fraction: float,
    min_new_fraction: float,
    expected: float,
    pass_index: int,
    rng: np.random.Generator,
    verify_hypotheses: Any,
) -> Instance | None:
    """Polish ``h`` on the unclaimed points near it, check it, and return it as a new
    instance (or None: inconsistent, a duplicate, or mostly explaining claimed points)."""
    T = np.asarray(h.matrix, dtype=np.float64)
    c = T[:3, :3] @ centre + T[:3, 3]
    near = free[np.linalg.norm(cloud[free] - c, axis=1) <= radius + 2 * d]
    if len(near) >= 30:
        polished = verify_hypotheses(
            [h],
            surface,
            cloud[near],
            inlier_distance=d,
            icp_distance=max(3 * d, 0.05 * size),
            max_icp=1,
            rng=rng,
        )
        if polished:
            T = np.asarray(polished[0].hypothesis.matrix, dtype=np.float64)
            c = T[:3, :3] @ centre + T[:3, 3]
    for inst in found:
        other = inst.matrix[:3, :3] @ centre + inst.matrix[:3, 3]
        if np.linalg.norm(c - other) < same_fraction * size and (
            _overlap(T, inst.matrix, surface, d) >= SAME_OVERLAP
        ):
            return None
    check = consistency(T, surf_pts, surf_nrm, cloud, table, d, tree)
    if not _pile_ok(check):
        log.debug("candidate at %s: inconsistent %s", np.round(c, 3), check)
        return None
    P = _posed(T, surf_pts)
    N = surf_nrm @ T[:3, :3].T
    seen = N[:, 2] > -0.3
    # the points this pose explains (visible surface) and the ones it claims (whole surface)
    near_all = np.asarray(tree.query_ball_point(c, r=radius + 2 * d), dtype=np.intp)
    if len(near_all) == 0:
        return None
    dist_seen = cKDTree(P[seen]).query(cloud[near_all])[0]
    explained = near_all[dist_seen <= d]
    new = explained[~claimed[explained]]
    if len(explained) < 30 or len(new) < min_new_fraction * len(explained):
        log.debug("candidate at %s: %d explained, %d new", np.round(c, 3), len(explained), len(new))
        return None
    dist_all = cKDTree(P).query(cloud[near_all])[0]
    claim = near_all[dist_all <= 2 * d]
    agreement = 1.0 - check.inside / max(check.explained, 1)
    score = float(min(1.0, len(explained) / max(expected, 1.0)) * agreement)
    stability = pose_stability(T, surface, cloud[explained], centre, radius)
    return Instance(T, score, len(explained), check, claim, pass_index, stability)


# --------------------------------------------------------------------------- from the sensors


@dataclass(frozen=True, eq=False)
class SensedInstances:
    """Result of :func:`localize_instances`: the instances and what they were found in.

    Attributes:
        instances: the :class:`Instances`.
        points: (N, 3) the sensed points (world frame) the instances were found in (cropped
            to the region of interest).
        scene_points: (M, 3) every sensed point (not cropped): obstacles for a grasp
            planner (walls and neighbours included).
        provenance: logical sensor -> the way that served it.
        timing: seconds (``sensing``, ``localization``, ``total``).
        views: the views the points came from, in order (``range_finder#0``,
            ``wrist_camera#1``: the fused sensor's stream sources), or the one sensor's way.
    """

    instances: Instances
    points: FloatArray = field(repr=False)
    scene_points: FloatArray = field(repr=False)
    provenance: dict[str, str]
    timing: dict[str, float]
    views: tuple[str, ...] = ()


_MODELS: dict[tuple[str, tuple[str, ...]], Any] = {}
_ALTERNATES: dict[tuple[str, tuple[str, ...]], Any] = {}


def instance_model(object_name: str, models: tuple[str, ...] = ()) -> Any:
    """The polyhedral surface model of a database object's mesh (built once per object)."""
    from mks_sim.localize import PolyhedralModel
    from mks_sim.models.objects import load_object

    key = (object_name, models)
    if key not in _MODELS:
        obj = load_object(object_name, models=models)
        _MODELS[key] = PolyhedralModel.from_mesh(obj.mesh, obj.name)
    return _MODELS[key]


def instance_alternate(object_name: str, models: tuple[str, ...] = ()) -> Any:
    """The object's free-form model when it lists the ``freeform`` kind (the database entry
    it names, else one built from its mesh; once per object), else None: the alternate
    candidates of :func:`localize_all`."""
    from mks_sim.localization.model import db_for, default_db
    from mks_sim.localization.workstation import freeform_model
    from mks_sim.models.objects import load_object

    key = (object_name, models)
    if key not in _ALTERNATES:
        spec = load_object(object_name, models=models)
        alt = None
        if "freeform" in spec.kinds:
            db = default_db() if not models else db_for(tuple(str(m) for m in models))
            alt = freeform_model(spec, db)[1]
        _ALTERNATES[key] = alt
    return _ALTERNATES[key]


def localize_instances(
    devices: Any,
    object_name: str,
    *,
    roi: tuple[ArrayLike, ArrayLike] | None = None,
    exclude: Sequence[tuple[ArrayLike, ArrayLike]] = (),
    graph: Any = None,
    rng: np.random.Generator | None = None,
    models: tuple[str, ...] = (),
    max_instances: int = 12,
    sensor: str | None = None,
    prior: Sequence[ArrayLike] = (),
) -> SensedInstances:
    """Sense the scene once and localize every instance of a database object.

    Args:
        devices: device name -> device (``mks_sim.devices.make_devices``); a failed range
            finder is replaced by the points sensor's alternate (stereo). With
            ``sensor="Fused_Points"``, views held by
            :class:`~mks_sim.sensing.programs.views.HeldViews` (active sensing).
        object_name: a database object (its mesh is the model).
        roi: (lo, hi) world-frame corners of the region of interest (e.g. a bin's inside:
            a workcell calibration, like the table height); points outside are ignored.
        exclude: (lo, hi) world xy corners ((2,) each) of regions left out of ``roi``,
            from the table up (e.g. a bin and a box, when the table around them is
            searched): points above them are ignored.
        graph: the logical sensors (default ``SensorGraph.from_dir()``).
        rng: generator (default seeded 0).
        models: extra model folders.
        max_instances: stop after this many.
        sensor: the logical sensor of 3-D points (default the workstation's
            ``Range_Points``).
        prior: poses found in an earlier view, checked first (:func:`localize_all`).

    Raises:
        NotFound: unknown object.
        SensorFailure: the points sensor and all its alternates failed, or too few points.
    """
    from mks_sim.errors import SensorFailure
    from mks_sim.localization.verify import find_table
    from mks_sim.workstation import POINTS_SENSOR, table_z_m

    t0 = time.perf_counter()
    rng = np.random.default_rng(0) if rng is None else rng
    model = instance_model(object_name, models)
    if graph is None:
        from mks_sim.workstation import _default_graph

        graph = _default_graph()
    sensor = POINTS_SENSOR if sensor is None else sensor
    snap = graph.snapshot(devices)
    stream = snap.get(sensor)
    pts = np.asarray(stream.data, dtype=np.float64)[:, :3]
    if stream.source is not None:
        views = tuple(dict.fromkeys(str(v) for v in stream.source))
    else:
        views = (f"{sensor}:{stream.served_by}",)
    pts = pts[np.all(np.isfinite(pts), axis=1)]
    scene = pts
    if roi is not None:
        lo, hi = (np.asarray(v, dtype=np.float64).reshape(3) for v in roi)
        pts = pts[np.all((pts >= lo) & (pts <= hi), axis=1)]
    for lo_xy, hi_xy in exclude:
        lo2, hi2 = (np.asarray(v, dtype=np.float64).reshape(2) for v in (lo_xy, hi_xy))
        pts = pts[~np.all((pts[:, :2] >= lo2) & (pts[:, :2] <= hi2), axis=1)]
    t_sense = time.perf_counter() - t0
    if len(pts) < 50:
        raise SensorFailure(sensor, f"expected >= 50 points in the region, got {len(pts)}")
    table, _, _ = find_table(pts, rng, spacing=0.0, noise=0.0, near_z=table_z_m(graph))
    result = localize_all(
        model,
        pts,
        table=table,
        rng=rng,
        max_instances=max_instances,
        prior=prior,
        alternate=instance_alternate(object_name, models),
    )
    total = time.perf_counter() - t0
    return SensedInstances(
        result,
        pts,
        scene,
        dict(snap.provenance),
        {"sensing": t_sense, "localization": total - t_sense, "total": total},
        views,
    )
