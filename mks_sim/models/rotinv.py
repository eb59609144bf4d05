"""Rotation-invariant 3-D Hough shape model (paper section 2.2.1).

The model is a point set ``P`` (e.g. a polyhedron's vertexes) and a reference point ``P0``
whose distances (radii) to the points of ``P`` are all distinct. A rigid motion keeps those
radii, so the transformed reference point ``P0'`` lies on a sphere of some model radius about
every detected point: the accumulator counts, at the points where spheres about detected points
intersect, how many detected points lie at a model radius. Every maximum is a candidate
``P0'``; pairing each detected point with the model point of equal radius gives the
correspondences, and a least-squares rigid fit (Kabsch, :func:`rigid_fit`) over the pairs and
``P0 -> P0'`` gives the transformation (section 2.2.1, "Matching is done by finding for each
r' in R' its counterpart r in R").

Implementation (beyond the paper's text, which leaves the accumulator to Wu [24]):

* candidates are the 0 or 2 intersection points of three spheres (trilateration) about each
  triple of distinct detected points, for each assignment of three distinct model radii;
  vectorised over all triples and assignments;
* ``prune=True`` (default) keeps only the assignments (i, j, k) whose model points are as far
  apart as the three detected points (a rigid motion keeps distances): the same maxima, far
  fewer spurious intersections; ``prune=False`` is the paper's exhaustive form;
* votes at a candidate: the number of distinct detected points lying at some model radius
  within ``tolerance``; candidates are clustered (cKDTree) and each cluster is one maximum;
* duplicate detected points (within ``tolerance / 4``) are merged and counted, never voted
  twice; mirror-image maxima (reflections of the model, which spheres cannot tell apart) are
  kept in :attr:`RotInvResult.maxima` but fail the rigid fit and are not hypotheses.
"""

from __future__ import annotations

import itertools
import logging
from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike, NDArray
from scipy.optimize import linear_sum_assignment
from scipy.sparse.csgraph import connected_components
from scipy.spatial import cKDTree

from mks_sim.errors import DataError, SpecError
from mks_sim.geometry.points import as_points
from mks_sim.geometry.transforms import rigid_fit_unchecked
from mks_sim.models.pose import PoseHypothesis

__all__ = [
    "Maximum",
    "RotInvResult",
    "RotationInvariantHough",
    "choose_reference",
    "dedupe_points",
    "radius_gaps",
    "trilaterate",
]

log = logging.getLogger(__name__)
FloatArray = NDArray[np.float64]


def dedupe_points(points: ArrayLike, eps: float) -> tuple[FloatArray, NDArray[np.int64]]:
    """Merge points closer than ``eps`` (connected components), keeping first-seen order.

    Args:
        points: (N, 3).
        eps: merge distance (>= 0; 0 merges exact repeats only).

    Returns:
        ``(unique (U, 3) — the mean of each group, counts (U,) int)``.
    """
    P = as_points(points, "dedupe_points: points")
    if len(P) == 0:
        return P, np.zeros(0, dtype=np.int64)
    pairs = cKDTree(P).query_pairs(r=max(eps, 0.0), output_type="ndarray")
    n = len(P)
    if len(pairs) == 0:
        return P.copy(), np.ones(n, dtype=np.int64)
    from scipy.sparse import coo_array

    adj = coo_array((np.ones(len(pairs)), (pairs[:, 0], pairs[:, 1])), shape=(n, n))
    _, labels = connected_components(adj, directed=False)
    _, first, inverse = np.unique(labels, return_index=True, return_inverse=True)
    order = np.argsort(first)  # groups in order of first appearance
    rank = np.empty_like(order)
    rank[order] = np.arange(len(order))
    group = rank[inverse]
    counts = np.bincount(group).astype(np.int64)
    sums = np.zeros((len(counts), 3))
    np.add.at(sums, group, P)
    return sums / counts[:, None], counts


def radius_gaps(points: ArrayLike, reference: ArrayLike) -> tuple[float, float]:
    """How distinct the radii from ``reference`` to ``points`` are.

    Returns:
        ``(min_gap, relative_gap)``: the smallest difference between two sorted radii (points'
        units; 0 for fewer than two points is ``inf``) and that gap over the largest radius.
    """
    P = as_points(points, "radius_gaps: points")
    r = np.sort(np.linalg.norm(P - np.asarray(reference, dtype=np.float64), axis=1))
    if len(r) < 2:
        return float("inf"), float("inf")
    gap = float(np.diff(r).min())
    return gap, gap / float(max(r[-1], 1e-300))


def choose_reference(points: ArrayLike, grid: int = 11, refine: int = 3) -> FloatArray:
    """Choose a reference point whose radii to ``points`` are as distinct as possible.

    Deterministic search: maximise the smallest gap between sorted radii over a ``grid^3``
    lattice spanning the bounding box grown by 25 % on each side, then ``refine`` rounds of a
    5^3 lattice around the best point with the step shrunk by 4 each round.

    Args:
        points: (N, 3) model points (distinct).
        grid: lattice size per axis for the first round.
        refine: refinement rounds.

    Returns:
        (3,) reference point.
    """
    P = as_points(points, "choose_reference: points")
    lo, hi = P.min(axis=0), P.max(axis=0)
    span = np.maximum(hi - lo, 1e-9 * max(1.0, float(np.abs(P).max())))
    lo, hi = lo - 0.25 * span, hi + 0.25 * span

    def best_of(cands: FloatArray) -> tuple[FloatArray, float]:
        r = np.sort(np.linalg.norm(cands[:, None, :] - P[None, :, :], axis=2), axis=1)
        gaps = np.diff(r, axis=1).min(axis=1) if P.shape[0] > 1 else r[:, 0]
        k = int(np.argmax(gaps))  # first maximum: deterministic
        return cands[k], float(gaps[k])

    axes = [np.linspace(lo[d], hi[d], grid) for d in range(3)]
    cands = np.stack(np.meshgrid(*axes, indexing="ij"), axis=-1).reshape(-1, 3)
    best, _ = best_of(cands)
    step = (hi - lo) / (grid - 1)
    for _ in range(refine):
        offs = np.linspace(-2, 2, 5)
        grid5 = np.stack(np.meshgrid(offs, offs, offs, indexing="ij"), axis=-1).reshape(-1, 3)
        best, _ = best_of(best + grid5 * step / 2)
        step = step / 4
    return best


def trilaterate(
    a: FloatArray,
    b: FloatArray,
    c: FloatArray,
    ra: FloatArray,
    rb: FloatArray,
    rc: FloatArray,
    slack: float = 0.0,
) -> tuple[FloatArray, NDArray[np.bool_]]:
    """Intersection points of spheres (a, ra), (b, rb), (c, rc), vectorised.

    Args:
        a, b, c: (K, 3) sphere centres.
        ra, rb, rc: (K,) radii.
        slack: spheres that miss by at most this distance (noise) are treated as touching.

    Returns:
        ``(points (K, 2, 3), valid (K,))``: the two intersection points (equal when the spheres
        touch); ``valid`` is False for no intersection or collinear centres.
    """
    ab = b - a
    d = np.linalg.norm(ab, axis=1)
    ok = d > 1e-12
    ex = ab / np.where(ok, d, 1.0)[:, None]
    ac = c - a
    i = np.einsum("kj,kj->k", ex, ac)
    ey_raw = ac - i[:, None] * ex
    j = np.linalg.norm(ey_raw, axis=1)
    ok &= j > 1e-9 * np.maximum(d, 1.0)
    ey = ey_raw / np.where(ok, j, 1.0)[:, None]
    ez = np.cross(ex, ey)
    d_s = np.where(ok, d, 1.0)
    j_s = np.where(ok, j, 1.0)
    x = (ra**2 - rb**2 + d_s**2) / (2 * d_s)
    y = (ra**2 - rc**2 + i**2 + j_s**2) / (2 * j_s) - i * x / j_s
    z2 = ra**2 - x**2 - y**2
    # A miss by `slack` in radius changes z^2 by about 2 * r * slack.
    ok &= z2 >= -2.0 * np.maximum(ra, 1e-12) * slack - 1e-12
    z = np.sqrt(np.clip(z2, 0.0, None))
    base = a + x[:, None] * ex + y[:, None] * ey
    pts = np.stack([base + z[:, None] * ez, base - z[:, None] * ez], axis=1)
    return pts, ok


@dataclass(frozen=True, eq=False)
class _Fit:
    """A maximum's rigid fit: (4, 4) model -> detected, its rmse, its (n, 2) int64 pairs
    (detected index, model index) in detected order."""

    matrix: FloatArray
    rmse: float
    correspondences: NDArray[np.int64]

    def hypothesis(self, reference: FloatArray) -> PoseHypothesis:
        """The fit as a hypothesis: the model's ``reference`` moved (apply's arithmetic) is
        its reference point, its pairs are its votes."""
        T = self.matrix
        return PoseHypothesis(
            matrix=T,
            reference_point=(reference[None, :] @ T[:3, :3].T + T[:3, 3])[0],
            votes=len(self.correspondences),
            correspondences=self.correspondences,
            rmse=self.rmse,
        )


@dataclass(frozen=True, eq=False)
class Maximum:
    """One accumulator maximum (a cluster of sphere intersections).

    Attributes:
        position: (3,) candidate P0' (mean of the cluster's best-voted candidates).
        votes: detected points lying at a model radius from ``position``.
        hits: intersections that fell into the cluster.
        proper: True when the pairs fit a rigid motion (rmse <= ``max_rmse``), False for a
            mirror image (the sphere construction cannot tell a reflection apart).
        rmse: rigid-fit residual of the pairs.
    """

    position: FloatArray
    votes: int
    hits: int
    proper: bool
    rmse: float


@dataclass(frozen=True, eq=False)
class RotInvResult:
    """Everything one detection found.

    Attributes:
        hypotheses: rigid hypotheses, best first (votes desc, rmse asc); indices of
            ``correspondences`` refer to the caller's (not deduplicated) detected points and to
            the model points.
        maxima: every accumulator maximum with >= ``min_votes`` votes, proper and mirror,
            best first.
        unique_points: (U, 3) detected points after merging repeats.
        counts: (U,) how many input points each unique point merged.
        first_index: (U,) the first input index of each unique point.
        candidates: number of sphere intersections computed.
        top_votes: the largest vote count.
    """

    hypotheses: list[PoseHypothesis]
    maxima: list[Maximum]
    unique_points: FloatArray
    counts: NDArray[np.int64]
    first_index: NDArray[np.int64]
    candidates: int
    top_votes: int

    @property
    def top_maxima(self) -> list[Maximum]:
        """The maxima with the largest vote count (the paper's "possible locations")."""
        return [m for m in self.maxima if m.votes == self.top_votes]


class RotationInvariantHough:
    """The rotation-invariant 3-D Hough shape model of paper section 2.2.1.

    Args:
        points: (n, 3) model points (n >= 3), e.g. vertexes; repeats are merged.
        reference: (3,) model reference point P0; ``None`` chooses one with
            :func:`choose_reference`.
        tolerance: distance within which a detected point "lies on" a model sphere (and two
            radii are "equal"), in the points' units. Default: 2 % of the model's diameter.
            Set it to about 3x the noise of the detected points.
        symmetries: optional (K, 3, 3) rotations of the model (for evaluation, e.g.
            :func:`~mks_sim.geometry.transforms.cube_rotations`); kept, not used in detection.
        name: model name.
        prune: keep only radius assignments consistent with the detected triple's distances.
        max_rmse: rigid-fit residual above which a maximum is a mirror image / not rigid.
            Default ``2 * tolerance``.
        min_votes: maxima with fewer votes are not reported. Default
            ``max(min(4, m), ceil(top / 2))`` for m distinct detected points and ``top`` the
            largest vote count (every triple's own intersection already has 3 votes).
    """

    def __init__(
        self,
        points: ArrayLike,
        reference: ArrayLike | None = None,
        tolerance: float | None = None,
        symmetries: ArrayLike | None = None,
        name: str = "",
        prune: bool = True,
        max_rmse: float | None = None,
        min_votes: int | None = None,
    ) -> None:
        P = as_points(points, "RotationInvariantHough: model points", min_points=3)
        uniq, counts = dedupe_points(P, 0.0)
        if len(uniq) < len(P):
            log.warning("model %r: %d repeated model points merged", name, len(P) - len(uniq))
        if len(uniq) < 3:
            raise DataError(
                f"RotationInvariantHough: expected >= 3 distinct model points, got {len(uniq)}"
            )
        self.points: FloatArray = uniq
        self.name = name
        self.description = ""
        self.unit = ""
        diameter = float(np.linalg.norm(uniq.max(axis=0) - uniq.min(axis=0)))
        if reference is None:
            ref = choose_reference(uniq)
        else:
            ref = np.asarray(reference, dtype=np.float64).reshape(-1)
            if ref.shape != (3,) or not np.all(np.isfinite(ref)):
                raise DataError(
                    f"RotationInvariantHough: reference: expected 3 finite numbers, got {reference!r}"
                )
        self.reference: FloatArray = ref
        self.radii: FloatArray = np.linalg.norm(uniq - ref, axis=1)
        self.min_gap, self.relative_gap = radius_gaps(uniq, ref)
        if tolerance is None:
            tolerance = 0.02 * diameter
        if not np.isfinite(tolerance) or tolerance <= 0:
            raise SpecError(
                f"RotationInvariantHough: tolerance: expected a number > 0, got {tolerance!r}"
            )
        self.tolerance = float(tolerance)
        if self.min_gap <= 1e-12 * max(diameter, 1.0):
            raise SpecError(
                f"RotationInvariantHough {name!r}: the radii from the reference point "
                f"{ref.tolist()} are not distinct (smallest gap {self.min_gap:.3g}); "
                "choose another reference point or pass reference=None"
            )
        if self.min_gap < 2 * self.tolerance:
            log.info(
                "model %r: smallest radius gap %.4g < 2 * tolerance %.4g: radii may be "
                "confused; correspondences are re-paired geometrically",
                name,
                self.min_gap,
                self.tolerance,
            )
        self.symmetries = None if symmetries is None else np.asarray(symmetries, dtype=float)
        self.prune = prune
        self.max_rmse = 2.0 * self.tolerance if max_rmse is None else float(max_rmse)
        self.min_votes = min_votes
        self._model_dist = np.linalg.norm(uniq[:, None] - uniq[None], axis=2)  # (n, n)

    # ------------------------------------------------------------------ public

    def detect(self, points: ArrayLike) -> list[PoseHypothesis]:
        """Candidate poses (model -> detected), best first; see :meth:`analyze`."""
        return self.analyze(points).hypotheses

    def analyze(self, points: ArrayLike) -> RotInvResult:
        """Run the Hough on detected points.

        Args:
            points: (m, 3) detected points (m >= 3 distinct), same units as the model.

        Returns:
            :class:`RotInvResult` (hypotheses, every maximum, deduplication report).

        Raises:
            DataError: wrong shape, NaN, or fewer than 3 distinct detected points.
        """
        D_in = as_points(points, "RotationInvariantHough.detect: detected points")
        uniq, counts = dedupe_points(D_in, self.tolerance / 4)
        first = self._first_index(D_in, uniq)
        if np.any(counts > 1):
            log.info(
                "%d repeated detected point(s) merged (counts %s)",
                int((counts > 1).sum()),
                counts[counts > 1].tolist(),
            )
        if len(uniq) < 3:
            raise DataError(
                f"RotationInvariantHough.detect: expected >= 3 distinct detected points, "
                f"got {len(uniq)} (of {len(D_in)})"
            )
        cands = self._candidates(uniq)
        if len(cands) == 0:
            return RotInvResult([], [], uniq, counts, first, 0, 0)
        votes = self._votes(cands, uniq)
        maxima_raw = self._cluster(cands, votes)
        maxima: list[Maximum] = []
        hyps: list[PoseHypothesis] = []
        pos_votes = np.zeros(0, dtype=np.int64)
        if maxima_raw:
            positions = np.array([m[0] for m in maxima_raw])
            pos_votes = self._votes(positions, uniq)
        min_votes = self.min_votes
        if min_votes is None:
            top_raw = int(pos_votes.max()) if len(pos_votes) else 0
            min_votes = max(min(4, len(uniq)), (top_raw + 1) // 2)
        # Noise spreads one maximum over several clusters; clusters that pair the same
        # detected points with the same model points are one maximum.
        # (a maximum's hypothesis is built only when it is kept: the first of its key, proper)
        merged: dict[tuple[bool, bytes], tuple[Maximum, _Fit | None]] = {}
        for k in np.argsort(-pos_votes, kind="stable"):
            pos, hits, _ = maxima_raw[k]
            v = int(pos_votes[k])
            if v < min_votes:
                break
            h = self._match(pos, uniq, first)
            proper = h is not None and h.rmse <= self.max_rmse
            rmse = float("inf") if h is None else h.rmse
            key = (proper, b"" if h is None else h.correspondences.tobytes())
            if h is None:
                key = (False, pos.tobytes())
            prev = merged.get(key)
            if prev is None:
                merged[key] = (Maximum(pos, v, hits, proper, rmse), h)
            else:
                m0, h0 = prev
                merged[key] = (Maximum(m0.position, m0.votes, m0.hits + hits, proper, m0.rmse), h0)
        for m, h in merged.values():
            maxima.append(m)
            if m.proper and h is not None:
                hyps.append(h.hypothesis(self.reference))
        maxima.sort(key=lambda m: (-m.votes, not m.proper, m.rmse))
        hyps.sort(key=lambda h: (-h.votes, h.rmse))
        top = maxima[0].votes if maxima else 0
        return RotInvResult(hyps, maxima, uniq, counts, first, len(cands), top)

    # ------------------------------------------------------------------ steps

    @staticmethod
    def _first_index(D: FloatArray, uniq: FloatArray) -> NDArray[np.int64]:
        _, idx = cKDTree(D).query(uniq)
        return np.asarray(idx, dtype=np.int64)

    def _assignments(self, tri: NDArray[np.intp], D: FloatArray) -> NDArray[np.intp]:
        """(T, 3) triples of detected indices -> (A, 4) rows (triple row, i, j, k)."""
        n = len(self.points)
        if not self.prune:
            perms = np.array(list(itertools.permutations(range(n), 3)), dtype=np.intp)
            t_idx = np.repeat(np.arange(len(tri)), len(perms))
            return np.column_stack([t_idx, np.tile(perms, (len(tri), 1))])
        tol = 2.0 * self.tolerance
        M = self._model_dist
        out = []
        chunk = max(1, 2_000_000 // max(n**3, 1))
        for s in range(0, len(tri), chunk):
            t = tri[s : s + chunk]
            dab = np.linalg.norm(D[t[:, 0]] - D[t[:, 1]], axis=1)
            dac = np.linalg.norm(D[t[:, 0]] - D[t[:, 2]], axis=1)
            dbc = np.linalg.norm(D[t[:, 1]] - D[t[:, 2]], axis=1)
            mab = np.abs(M[None] - dab[:, None, None]) <= tol  # (T, n, n): (i, j)
            mac = np.abs(M[None] - dac[:, None, None]) <= tol  # (i, k)
            mbc = np.abs(M[None] - dbc[:, None, None]) <= tol  # (j, k)
            ok = mab[:, :, :, None] & mac[:, :, None, :] & mbc[:, None, :, :]  # (T, i, j, k)
            tt, i, j, k = np.nonzero(ok)
            keep = (i != j) & (i != k) & (j != k)
            out.append(np.column_stack([tt[keep] + s, i[keep], j[keep], k[keep]]))
        return np.concatenate(out) if out else np.zeros((0, 4), dtype=np.intp)

    def _candidates(self, D: FloatArray) -> FloatArray:
        tri = np.array(list(itertools.combinations(range(len(D)), 3)), dtype=np.intp)
        asg = self._assignments(tri, D)
        if len(asg) == 0:
            return np.zeros((0, 3))
        t = tri[asg[:, 0]]
        r = self.radii
        pts, ok = trilaterate(
            D[t[:, 0]],
            D[t[:, 1]],
            D[t[:, 2]],
            r[asg[:, 1]],
            r[asg[:, 2]],
            r[asg[:, 3]],
            slack=self.tolerance,
        )
        return pts[ok].reshape(-1, 3)

    def _votes(self, cands: FloatArray, D: FloatArray) -> NDArray[np.int64]:
        """Per candidate: detected points at some model radius (within tolerance)."""
        r_sorted = np.sort(self.radii)
        votes = np.zeros(len(cands), dtype=np.int64)
        chunk = 200_000
        for s in range(0, len(cands), chunk):
            dist = np.linalg.norm(cands[s : s + chunk, None, :] - D[None], axis=2)  # (c, m)
            pos = np.clip(np.searchsorted(r_sorted, dist), 1, len(r_sorted) - 1)
            near = np.minimum(np.abs(dist - r_sorted[pos - 1]), np.abs(dist - r_sorted[pos]))
            votes[s : s + chunk] = (near <= self.tolerance).sum(axis=1)
        return votes

    def _cluster(
        self, cands: FloatArray, votes: NDArray[np.int64]
    ) -> list[tuple[FloatArray, int, int]]:
        """Cluster candidates with >= 3 votes; one maximum per cluster."""
        keep = votes >= 3
        C, V = cands[keep], votes[keep]
        if len(C) == 0:
            return []
        pairs = cKDTree(C).query_pairs(r=2.0 * self.tolerance, output_type="ndarray")
        from scipy.sparse import coo_array

        adj = coo_array((np.ones(len(pairs)), (pairs[:, 0], pairs[:, 1])), shape=(len(C), len(C)))
        n_lab, labels = connected_components(adj, directed=False)
        best = np.full(n_lab, -1)
        np.maximum.at(best, labels, V)
        hits = np.bincount(labels, minlength=n_lab)
        top = V == best[labels]
        sums = np.zeros((n_lab, 3))
        np.add.at(sums, labels[top], C[top])
        n_top = np.bincount(labels[top], minlength=n_lab)
        pos = sums / n_top[:, None]
        return [(pos[k], int(hits[k]), int(best[k])) for k in range(n_lab)]

    def _match(self, pos: FloatArray, D: FloatArray, first: NDArray[np.int64]) -> _Fit | None:
        """Pair detected points with model points of equal radius; fit the rigid motion."""
        dist = np.linalg.norm(D - pos, axis=1)
        cost = np.abs(dist[:, None] - self.radii[None, :])  # (m, n)
        # Pairs beyond the tolerance all cost the same, so that an outlier cannot take the
        # radius of an inlier to lower the total.
        rows, cols = linear_sum_assignment(np.where(cost <= self.tolerance, cost, 1e6))
        ok = cost[rows, cols] <= self.tolerance
        det_idx, mod_idx = rows[ok], cols[ok]
        if len(det_idx) < 3:
            return None
        T, rmse = self._fit(det_idx, mod_idx, D, pos)
        # Radii closer than the tolerance can be confused: re-pair by position once.
        moved = self.points @ T[:3, :3].T + T[:3, 3]  # (apply's arithmetic, unchecked)
        cost2 = np.linalg.norm(D[:, None] - moved[None], axis=2)
        r2, c2 = linear_sum_assignment(np.where(cost2 <= 2.0 * self.tolerance, cost2, 1e6))
        ok2 = cost2[r2, c2] <= 2.0 * self.tolerance
        n2 = int(ok2.sum())
        if n2 >= 3 and n2 >= len(det_idx):
            T2, rmse2 = self._fit(r2[ok2], c2[ok2], D, pos)
            if n2 > len(det_idx) or rmse2 <= rmse:
                T, rmse, det_idx, mod_idx = T2, rmse2, r2[ok2], c2[ok2]
        order = np.argsort(det_idx)
        corr = np.column_stack([first[det_idx[order]], mod_idx[order]])
        return _Fit(T, rmse, corr)

    def _fit(
        self, det_idx: NDArray[np.intp], mod_idx: NDArray[np.intp], D: FloatArray, pos: FloatArray
    ) -> tuple[FloatArray, float]:
        # The reference point is one more pair (P0 -> P0'), as in the paper's matching step.
        src = np.vstack([self.points[mod_idx], self.reference])
        dst = np.vstack([D[det_idx], pos])
        return rigid_fit_unchecked(src, dst)  # (finite model and detected points)
