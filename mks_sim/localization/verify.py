"""Verification: the one table finder, the one scene-consistency check, batch scoring, ranking.

- :func:`find_table` — the supporting plane of a scene (near a nominal height when the sensor
  calibration gives one, else the dominant plane that looks like a support).
- :func:`batch_explained` — how many scene points each of K candidate poses explains, for all
  candidates in one k-d tree query of the stacked transformed model samples (hypotheses are
  scored in arrays; ICP runs only on the best).
- :class:`Consistency` / :func:`consistency` — does a posed model agree with what the sensors
  saw (no point seen through it, none below it, no penetration of the table)?
- :func:`rank` — consistent first, then most points explained, then score.
"""

from __future__ import annotations

import itertools
import weakref
from dataclasses import asdict, dataclass
from typing import TYPE_CHECKING, Any

import numpy as np
from numpy.typing import NDArray
from scipy.spatial import cKDTree

from mks_sim.geometry.transforms import cross3
from mks_sim.lowlevel import _gridknn
from mks_sim.lowlevel._gridknn import column_mean
from mks_sim.lowlevel.regions import Plane, fit_plane_ransac
from mks_sim.models.pose import PoseHypothesis

if TYPE_CHECKING:
    from mks_sim.models.refine import ModelSurface

__all__ = [
    "Consistency",
    "NearPoints",
    "batch_explained",
    "consistency",
    "find_table",
    "rank",
    "surface_coverage",
]

FloatArray = NDArray[np.float64]


#: The table's plane is fit to at most this many of its RANSAC inliers, evenly strided (as
#: many as RANSAC counts its candidates on), by the compiled fit: the 10,000 inliers of a
#: 240 x 180 scan gave the same successes in less time (``localize_cloud``'s tuning trials:
#: 112 scans of ``benchmarks/localize.py``'s rows, 110 found either way; 1.2-1.8 ms less on
#: the cube's 240 x 180 rows; 2,000 lost a noisy part). With ``near_z`` (the workstation's
#: 13,000-18,000 table points): 3.2-3.7 -> 1.1-1.5 ms, the plane within 0.003 deg and 7 um
#: of the fit to all of them.
TABLE_FIT_POINTS = 4000


def find_table(
    points: FloatArray,
    rng: np.random.Generator,
    *,
    spacing: float,
    noise: float,
    near_z: float | None = None,
    viewpoint: FloatArray | None = None,
    min_fraction: float = 0.2,
) -> tuple[Plane | None, float, NDArray[np.bool_]]:
    """The supporting plane, its band half-width and the (N,) mask of points in the band.

    With ``near_z`` (the nominal table height, a sensor calibration parameter): RANSAC on the
    points within 2 cm of it; the plane must be horizontal (normal z >= 0.95) and hold at
    least ``min_fraction`` of the points; band = max(3 mm, 3 x the inliers' RMS). Without:
    the dominant plane if it looks like a support (large, the rest on one side of it and
    inside its footprint, facing the viewpoint); band = 4 robust sigmas of its residuals.
    The plane's normal points towards the objects; None when there is no table.
    """
    none = np.zeros(len(points), dtype=bool)
    if len(points) < 50:
        return None, 0.0, none
    if near_z is not None:
        low_mask = np.abs(points[:, 2] - near_z) < 0.02
        low = np.compress(low_mask, points, axis=0)
        if len(low) < max(50, min_fraction * len(points)):
            return None, 0.0, none
        plane, inl = fit_plane_ransac(
            low, 0.003, rng, iterations=100, fit_points=TABLE_FIT_POINTS, compiled_fit=True
        )
        if plane.normal[2] < 0:
            plane = plane.flipped()
        if plane.normal[2] < 0.95:
            return None, 0.0, none
        resid = plane.distance(np.compress(inl, low, axis=0))
        rmse = float(np.sqrt(np.mean(resid**2)))
        thr = float(max(0.003, 3.0 * rmse))
        table = Plane(plane.normal, plane.offset, rmse)
        return table, thr, np.abs(table.distance(points)) <= thr
    threshold = max(spacing, 3.0 * noise, 1e-12)
    plane, _ = fit_plane_ransac(
        points, threshold, rng, iterations=150, fit_points=TABLE_FIT_POINTS, compiled_fit=True
    )
    support = _support if _gridknn.available() else _support_numpy
    return support(points, plane, threshold, spacing, viewpoint, min_fraction)


def _support_numpy(
    points: FloatArray,
    plane: Plane,
    threshold: float,
    spacing: float,
    viewpoint: FloatArray | None,
    min_fraction: float,
) -> tuple[Plane | None, float, NDArray[np.bool_]]:
    """:func:`find_table`'s tests of a dominant plane without ``near_z``, by numpy (the
    reference of :func:`_support`)."""
    none = np.zeros(len(points), dtype=bool)
    d = plane.distance(points)
    near = np.abs(d) <= 3.0 * threshold
    band = max(threshold, 4.0 * 1.4826 * _gridknn.median(np.abs(d[near])))
    inl = np.abs(d) <= band
    off = np.abs(d) > 2.0 * band  # clearly off the plane: objects (and outliers)
    if inl.mean() < min_fraction or off.sum() < 10:
        return None, 0.0, none
    if np.mean(d[off] > 0) < 0.5:
        plane, d = plane.flipped(), -d
    if np.mean(d[off] > 0) < 0.95:
        return None, 0.0, none
    if viewpoint is not None and plane.distance(viewpoint[None])[0] < 0:
        return None, 0.0, none
    # Footprint: the objects, projected into the plane, well inside the inliers' extent.
    u, w = _in_plane_axes(plane)
    uv_in = np.compress(inl, points, axis=0) @ np.column_stack([u, w])
    uv_off = np.compress(off, points, axis=0) @ np.column_stack([u, w])
    lo, hi = _gridknn.column_bounds(uv_in)
    margin = 0.05 * (hi - lo) + 2 * spacing
    inside = np.all((uv_off > lo + margin) & (uv_off < hi - margin), axis=1)
    if inside.mean() < 0.9:
        return None, 0.0, none
    return plane, float(band), inl


def _in_plane_axes(plane: Plane) -> tuple[FloatArray, FloatArray]:
    """Two orthonormal directions in a plane (the footprint test's axes)."""
    n = plane.normal
    u = cross3(n, [1.0, 0.0, 0.0] if abs(n[0]) < 0.9 else [0.0, 1.0, 0.0])
    u /= np.linalg.norm(u)
    return u, cross3(n, u)


def _support(
    points: FloatArray,
    plane: Plane,
    threshold: float,
    spacing: float,
    viewpoint: FloatArray | None,
    min_fraction: float,
) -> tuple[Plane | None, float, NDArray[np.bool_]]:
    """:func:`find_table`'s tests of a dominant plane without ``near_z``, in two compiled
    passes (:func:`~mks_sim.lowlevel._gridknn.plane_band`, ``footprint_inside``): the same
    tests; the distances' rounding may differ from numpy's products."""
    from mks_sim.lowlevel._gridknn import _load

    kern = _load()
    none = np.zeros(len(points), dtype=bool)
    pts = np.ascontiguousarray(points, dtype=np.float64)
    _, band, inl, off, positive = kern["plane_band"](
        pts, np.ascontiguousarray(plane.normal, dtype=np.float64), float(plane.offset),
        float(threshold),
    )  # fmt: skip
    n_off = int(np.count_nonzero(off))
    if np.count_nonzero(inl) < min_fraction * len(pts) or n_off < 10:
        return None, 0.0, none
    if positive < 0.5 * n_off:
        plane, positive = plane.flipped(), n_off - positive
    if positive < 0.95 * n_off:
        return None, 0.0, none
    if viewpoint is not None and plane.distance(viewpoint[None])[0] < 0:
        return None, 0.0, none
    u, w = _in_plane_axes(plane)
    if kern["footprint_inside"](pts, inl, off, u, w, float(spacing)) < 0.9:
        return None, 0.0, none
    return plane, float(band), inl


class NearPoints:
    """A point set asked which queries have one of its points strictly within a distance
    (the coverage tests' question: a finite distance from ``cKDTree.query`` with
    ``distance_upper_bound``), answered by the compiled grid
    (:func:`~mks_sim.lowlevel._gridknn.space_any`: no tree to build) when numba imports,
    else by a k-d tree built on first use; the same answers either way."""

    def __init__(self, points: FloatArray) -> None:
        self.points = np.ascontiguousarray(points, dtype=np.float64)
        self.n = len(self.points)
        self.compiled = _gridknn.available()
        self._tree: cKDTree | None = None

    def any_nearer(self, queries: FloatArray, r: float) -> NDArray[np.bool_]:
        """(Q,) some point lies strictly within ``r`` of the query."""
        if self.compiled:
            return _gridknn.space_any(self.points, queries, r)
        if self._tree is None:
            self._tree = cKDTree(self.points)
        return np.isfinite(self._tree.query(queries, distance_upper_bound=r)[0])


def batch_explained(
    model_points: FloatArray,
    matrices: FloatArray,
    scene_tree: cKDTree | NearPoints,
    distance: float,
) -> NDArray[np.intp]:
    """(K,) for each of K poses, how many of the model samples land within ``distance`` of a
    scene point (one k-d tree query of all K x M transformed samples).

    Args:
        model_points: (M, 3) model samples (model frame), e.g. a few hundred.
        matrices: (K, 4, 4) model -> scene poses.
        scene_tree: k-d tree of the scene points (or :class:`NearPoints` of them).
        distance: match distance.
    """
    T = np.asarray(matrices, dtype=np.float64).reshape(-1, 4, 4)
    if len(T) == 0:
        return np.zeros(0, dtype=np.intp)
    # (K, M, 3): p R^T + t by matmul (einsum: several times slower at these shapes)
    moved = np.matmul(model_points[None], np.transpose(T[:, :3, :3], (0, 2, 1))) + T[:, None, :3, 3]
    if isinstance(scene_tree, NearPoints):
        hit = scene_tree.any_nearer(moved.reshape(-1, 3), distance)
    else:
        hit = np.isfinite(scene_tree.query(moved.reshape(-1, 3), distance_upper_bound=distance)[0])
    return np.asarray(hit.reshape(len(T), -1).sum(axis=1), dtype=np.intp)


def surface_coverage(
    model_points: FloatArray,
    matrices: FloatArray,
    scene_tree: cKDTree | NearPoints,
    distance: float,
    max_samples: int = 1000,
) -> FloatArray:
    """(K,) fraction of the model's surface samples that have a scene point within
    ``distance`` at each of K poses: how much of the model the scan shows, at the model's own
    fixed sampling, so the same for 10 k and 2 M scene points (as long as the scan's spacing
    is below ``distance``)."""
    pts = np.asarray(model_points, dtype=np.float64)
    pts = pts[:: max(1, len(pts) // max_samples)]
    T = np.asarray(matrices, dtype=np.float64).reshape(-1, 4, 4)
    return batch_explained(pts, T, scene_tree, distance) / max(len(pts), 1)


#: How much an unexplained object point near a pose counts against it in the ranking
#: (:attr:`Consistency.support`). A cube pose around the lower part of a taller clutter box
#: explains about as many points as the true cube partly hidden under the sphere and leaves
#: the box's upper part unexplained: with weight 1 it won by a few points (stereo pair,
#: tuning seed 21: 1291 - 280 against 1019 - 24); with 2 the true pose wins. Stereo cube,
#: tuning seeds 0-29 and 1000-1039: 66/70 -> 68/70 (seeds 21 and 1031, the latter's pose
#: 5.6 deg off before); healthy cube and part unchanged (30/30 each). Points seen through the
#: posed solid or under it (``inside``, ``below``) count against it the same (tuning seed
#: 1097: a pose 8 mm into the clutter beside the cube won 870 - 2 x 21 against 828 - 2 x 7
#: while 9 points were seen through or under it).
UNEXPLAINED_WEIGHT = 2
#: A model sample explains a sensed point only if its normal is within ~100 degrees of the
#: line of sight to one of the sensors (cosine above this): a little past grazing, for a
#: pose a few degrees off; a face turned away (cosine near -1) never explains.
VIEW_FACING_COS = -0.2


@dataclass(frozen=True)
class Consistency:
    """The scene-consistency check of one posed model.

    Attributes:
        explained: sensed points within ``d`` of the model's visible surface.
        inside: points inside the model solid by more than ``d`` (seen through it).
        below: points under the model in their vertical column (could not have been seen).
        penetration: fraction of the model surface below the table by more than ``d``.
        ok: explained >= 30, inside + below <= 5 % of explained, penetration <= 2 %.
        unexplained: points off the table (by more than ``d``) within the model's bounding
            sphere that the posed model does not explain: an object the pose covers only
            part of (a cube pose inside a taller box) leaves its upper part here.
    """

    explained: int
    inside: int
    below: int
    penetration: float
    ok: bool
    unexplained: int = 0

    @property
    def support(self) -> int:
        """Net support of the pose: points explained minus :data:`UNEXPLAINED_WEIGHT` x the
        points that contradict it (nearby object points left unexplained, points seen
        through or under it): the ranking key among consistent poses."""
        return self.explained - UNEXPLAINED_WEIGHT * (self.unexplained + self.inside + self.below)

    @classmethod
    def of(
        cls, explained: int, inside: int, below: int, penetration: float, unexplained: int
    ) -> Consistency:
        """The check of these counts, with its verdict (``ok``, see the attributes)."""
        bad = inside + below
        ok = bool(explained >= 30 and bad <= 0.05 * max(explained, 1) and penetration <= 0.02)
        return cls(int(explained), int(inside), int(below), float(penetration), ok, int(unexplained))

    def __getitem__(self, key: str) -> Any:
        """Dictionary-style access (``check["ok"]``) for reports."""
        return getattr(self, key)

    def as_dict(self) -> dict[str, Any]:
        """The fields as a JSON-ready dict."""
        return asdict(self)


_MODEL_TREES: dict[int, tuple[Any, cKDTree]] = {}
_SPACINGS: dict[tuple[str, int], tuple[Any, float]] = {}
#: Eight horizontal unit directions (the openings around a point under an overhang).
_DIRS8 = np.stack([np.cos(np.arange(8) * np.pi / 4), np.sin(np.arange(8) * np.pi / 4)], axis=1)


def _model_tree(surface_pts: FloatArray) -> cKDTree:
    """The k-d tree of a model's surface samples (model frame), built once per sample array
    (keyed by the array's identity, dropped when the array is freed)."""
    key = id(surface_pts)
    hit = _MODEL_TREES.get(key)
    if hit is not None and hit[0]() is surface_pts:
        return hit[1]
    tree = cKDTree(surface_pts)

    trees = _MODEL_TREES  # bound here: at interpreter exit the module global may be None

    def _drop(ref: Any) -> None:
        hit = trees.get(key)
        if hit is not None and hit[0] is ref:  # not a newer array that reused the id
            del trees[key]

    try:
        ref = weakref.ref(surface_pts, _drop)
    except TypeError:  # not weak-referenceable (a view of a temporary): no cache
        return tree
    _MODEL_TREES[key] = (ref, tree)
    return tree


def _model_spacing(surface_pts: FloatArray) -> float:
    """Median nearest-neighbour distance of a model's surface samples (cached with its tree)."""
    key = ("spacing", id(surface_pts))
    hit = _SPACINGS.get(key)
    if hit is not None and hit[0]() is surface_pts:
        return hit[1]
    tree = _model_tree(surface_pts)
    sub = surface_pts[:: max(1, len(surface_pts) // 500)]
    spacing = float(np.median(tree.query(sub, k=2)[0][:, 1])) if len(surface_pts) > 1 else 0.0
    try:
        spacings = _SPACINGS  # bound here: at interpreter exit the module global may be None
        _SPACINGS[key] = (weakref.ref(surface_pts, lambda _r: spacings.pop(key, None)), spacing)
    except TypeError:
        pass
    return spacing


def _flatten(lists: Any) -> tuple[NDArray[np.intp], NDArray[np.intp]]:
    """(lengths, concatenated indices) of the index lists a ball query returns."""
    lens = np.fromiter(map(len, lists), dtype=np.intp, count=len(lists))
    flat = np.fromiter(itertools.chain.from_iterable(lists), dtype=np.intp, count=int(lens.sum()))
    return lens, flat


def _pairs_within(
    tree: cKDTree, queries: FloatArray, r: float
) -> tuple[NDArray[np.intp], NDArray[np.intp]]:
    """(lengths, concatenated indices) of the tree's points within ``r`` of each query,
    grouped by query in query order, as :func:`_flatten` of ``tree.query_ball_point`` gives
    them (the order within a group may differ): one dual-tree search into an array, about
    twice as fast as a ball query's Python lists for a thousand queries."""
    if len(queries) == 0:
        return np.zeros(0, dtype=np.intp), np.zeros(0, dtype=np.intp)
    pairs = cKDTree(queries, balanced_tree=False).sparse_distance_matrix(
        tree, r, output_type="ndarray"
    )
    lens = np.bincount(pairs["i"], minlength=len(queries)).astype(np.intp)
    return lens, pairs["j"][np.argsort(pairs["i"], kind="stable")].astype(np.intp)


class _Footprint:
    """A posed model's samples in (x, y), for the consistency check's test of points under
    the model: the samples within a distance of each query, and whether one lies nearer.
    By the compiled grid (:func:`~mks_sim.lowlevel._gridknn.plane_pairs`) when numba
    imports, else by a k-d tree built once; the same sets either way (the tree's distance
    rule). The grid is built per call, in about the time the tree's build takes numpy's
    min and max over its points, and answers the workstation's checks several times faster
    than the tree's dual search."""

    def __init__(self, xy: FloatArray) -> None:
        self.xy = np.ascontiguousarray(xy, dtype=np.float64)
        self.compiled = _gridknn.available()
        self._tree: cKDTree | None = None

    def _kd(self) -> cKDTree:
        if self._tree is None:
            self._tree = cKDTree(self.xy, balanced_tree=False)
        return self._tree

    def pairs_within(
        self, queries: FloatArray, r: float
    ) -> tuple[NDArray[np.intp], NDArray[np.intp]]:
        """(lengths, concatenated indices) of the samples within ``r`` of each query,
        grouped by query in query order (as :func:`_pairs_within`)."""
        if self.compiled:
            return _gridknn.plane_pairs(self.xy, queries, r)
        return _pairs_within(self._kd(), queries, r)

    def any_nearer(self, queries: FloatArray, r: float) -> NDArray[np.bool_]:
        """(Q,) some sample is strictly nearer than ``r`` (a finite distance from
        ``cKDTree.query`` with ``distance_upper_bound=r``)."""
        if self.compiled:
            lens, _ = _gridknn.plane_pairs(self.xy, queries, r, strict=True, first_only=True)
            return lens > 0
        return np.isfinite(self._kd().query(queries, distance_upper_bound=r)[0])


def consistency(
    T: FloatArray,
    surface_pts: FloatArray,
    surface_nrm: FloatArray,
    cloud: FloatArray,
    table: Plane | None,
    d: float,
    cloud_tree: cKDTree | None = None,
    elsewhere: NDArray[np.bool_] | None = None,
    surface: ModelSurface | None = None,
    viewpoints: FloatArray | None = None,
    compiled: bool | None = None,
) -> Consistency:
    """Does the posed model (``T`` model -> world) agree with what the sensors saw?

    Counts, over the sensed points near the posed model: ``explained`` (within ``d`` of its
    surface facing the sensors), ``inside`` (inside the model solid by more than ``d``) and
    ``below`` (under the model in their vertical column: the overhead and oblique sensors
    could not have seen them); ``penetration``: fraction of the model surface below the
    table plane by more than ``d``. ``elsewhere``: (N,) mask over ``cloud``, points another
    object explains (a sphere set aside): never counted unexplained (a point inside the
    model still counts as inside).

    ``cloud_tree``: a k-d tree of ``cloud`` to find the points near the posed model; None:
    one compiled pass over ``cloud`` finds the same points (no tree to build).

    ``surface``: the model's :class:`~mks_sim.models.refine.ModelSurface` over the same
    samples (``surface.points is surface_pts``); when it has its nearest-sample grid, the
    points' nearest samples are looked up there (3,000 points in 0.2 ms against 5 by the
    tree; a sample at most a cell diagonal farther than the nearest, 0.8 mm on the cube).

    ``viewpoints``: (K, 3) positions the cloud was seen from (the sensors' optical centres,
    :meth:`~mks_sim.sensing.snapshot.Snapshot.origins`); only surface facing one of them
    (within :data:`VIEW_FACING_COS`) explains a point. Without it a pose one wall thickness
    nearer the sensors explains the wall's seen face with its far face (the generated
    L-bracket, tuning seed 1032: 9.7 mm off, chosen at every other look).

    ``compiled``: the check in two compiled passes around the lookup grid's nearest samples
    (:mod:`mks_sim.localization._verify_kernels`: the same steps and rules, products summed
    in their own order; the workstation's checks 2.5-2.8 -> 0.5-1.1 ms) or by numpy; it
    needs numba and ``surface`` with its lookup grid (else numpy's, whatever is asked).
    None: compiled when those are there and no ``cloud_tree`` is given (a caller's tree
    keeps numpy's, as bin picking's does).
    """
    lookup = surface is not None and surface.points is surface_pts and surface.lookup is not None
    if compiled is None:
        compiled = cloud_tree is None
    if compiled and lookup and surface is not None and _gridknn.available():
        return _consistency_compiled(
            T, surface_pts, surface_nrm, cloud, table, d, elsewhere, viewpoints, surface
        )
    R, t = T[:3, :3], T[:3, 3]
    P = surface_pts @ R.T + t
    N = surface_nrm @ R.T
    # Only surface the sensors (all above the table) can see explains a point: a downward
    # face resting on the table would otherwise "explain" the table under a wrong pose.
    seen = N[:, 2] > -0.3
    if viewpoints is not None and len(viewpoints):
        facing = np.full(len(P), -np.inf)
        for v in np.asarray(viewpoints, dtype=np.float64).reshape(-1, 3):
            ray = v - P
            cos = np.einsum("ij,ij->i", N, ray) / np.maximum(_gridknn.row_norms(ray), 1e-12)
            np.maximum(facing, cos, out=facing)
        seen &= facing > VIEW_FACING_COS
    centre = column_mean(P)
    radius = float(np.sqrt(np.max(np.einsum("ij,ij->i", P - centre, P - centre))))
    if cloud_tree is not None:
        near_idx = np.asarray(cloud_tree.query_ball_point(centre, r=radius + 2 * d), dtype=np.intp)
    else:  # the same points, by the tree's rule, in one pass (no tree to build)
        near_idx = _gridknn.ball_rows(cloud, centre, radius + 2 * d)
    near = cloud[near_idx]
    explained_n = inside_n = below_n = unexplained_n = 0
    penetration = 0.0
    if table is not None:
        penetration = float(np.mean(table.distance(P) < -d))
    if len(near):
        # nearest model sample in the model frame: the model's tree is built once per model
        model_tree = _model_tree(surface_pts)
        q = (near - t) @ R
        if surface is not None and surface.lookup is not None and surface.points is surface_pts:
            dist, idx = surface.nearest(q, np.inf)
        else:
            dist, idx = model_tree.query(q)
        close = dist <= d
        explained = close & seen[idx]
        # a point whose nearest sample faces away may still have a seen one within d
        amb = np.flatnonzero(close & ~seen[idx])
        if len(amb):
            lens_a, flat_a = _flatten(model_tree.query_ball_point(q[amb], r=d))
            hit = np.repeat(np.arange(len(amb)), lens_a)[seen[flat_a]]
            explained[amb[hit]] = True
        sd = np.einsum("ij,ij->i", q - surface_pts[idx], surface_nrm[idx])
        sd[close] = 0.0  # on the surface (a visible or a resting face): not inside
        inside = (~explained) & (sd < -d)
        # a point on the surface (a face turned from the sensors) is not seen through it
        rest = np.flatnonzero(~explained & ~inside & ~close)
        below = np.zeros(len(near), dtype=bool)
        if len(rest):
            # under the model in its vertical column: at least two model samples within d/2
            # in (x, y) lie more than 2d above the point (radius d/2 and two samples: sensor
            # noise along the silhouette edges does not count, a point well inside the
            # footprint does); samples below every such height cannot count
            zq = near[rest, 2]
            high = np.flatnonzero(P[:, 2] > zq.min() - d)
            if len(high) >= 2:
                foot = _Footprint(P[high, :2])
                lens, flat = foot.pairs_within(near[rest, :2], 0.5 * d)
                if lens.sum():
                    grp = np.repeat(np.arange(len(rest)), lens)
                    z = P[high[flat], 2]
                    above = z > zq[grp] + 2 * d
                    under = np.bincount(grp[above], minlength=len(rest)) >= 2
                    # ... unless an oblique sensor sees it under an overhang of a model
                    # resting on the table: the model's
                    # lowest surface over it (not below it by more than d) is ``gap`` higher,
                    # and within ``gap`` of it (a 45 deg line of sight) the footprint of the
                    # model above it leaves an opening
                    over = z > zq[grp] - d
                    low = np.full(len(rest), np.inf)
                    np.minimum.at(low, grp[over], z[over])
                    idx_u = np.flatnonzero(under)
                    # (only a model resting on the table: a pose floating over it would
                    # otherwise hide the table under itself)
                    resting = table is not None and float(np.min(table.distance(P))) <= d
                    if not resting:
                        below[rest[idx_u]] = True
                    elif len(idx_u):
                        gap = np.maximum(low[idx_u] - zq[idx_u], 0.0)
                        probe = near[rest[idx_u], None, :2] + gap[:, None, None] * _DIRS8[None]
                        reach = max(0.5 * d, _model_spacing(surface_pts))
                        # a direction is blocked where the model reaches down to the line of
                        # sight (height ``gap`` over the point at ``gap`` away, with 20 % +
                        # d/10 for a flat underside posed a little tilted): a surface curving
                        # up (a cylinder on its side) leaves it open though its footprint
                        # covers the probe
                        ray_z = np.repeat(zq[idx_u] + 1.2 * gap + 0.1 * d, 8)
                        # (over twice the reach: a random sampling of the underside alone
                        # leaves holes wider than the reach of the whole footprint)
                        lens_h, flat_h = foot.pairs_within(probe.reshape(-1, 2), 2.0 * reach)
                        z_min = np.full(len(ray_z), np.inf)  # lowest model sample near each
                        some = lens_h > 0
                        if some.any():
                            starts = (np.cumsum(lens_h) - lens_h)[some]
                            z_min[some] = np.minimum.reduceat(P[high[flat_h], 2], starts)
                        blocked = z_min <= ray_z
                        blocked &= foot.any_nearer(probe.reshape(-1, 2), reach)
                        covered = blocked.reshape(len(idx_u), 8).all(axis=1)
                        below[rest[idx_u[covered]]] = True
        explained_n, inside_n, below_n = int(explained.sum()), int(inside.sum()), int(below.sum())
        loose = ~explained & ~inside & ~below
        if table is not None:
            loose &= table.distance(near) > d
        if elsewhere is not None:
            loose &= ~elsewhere[near_idx]
        unexplained_n = int(loose.sum())
    return Consistency.of(explained_n, inside_n, below_n, penetration, unexplained_n)


def _consistency_compiled(
    T: FloatArray,
    surface_pts: FloatArray,
    surface_nrm: FloatArray,
    cloud: FloatArray,
    table: Plane | None,
    d: float,
    elsewhere: NDArray[np.bool_] | None,
    viewpoints: FloatArray | None,
    surface: ModelSurface,
) -> Consistency:
    """:func:`consistency` in two compiled passes around the model's nearest-sample lookup
    (the same nearest samples: the lookup grid's, the tree's off it)."""
    from mks_sim.localization._verify_kernels import consistency_counts, posed_samples

    f64 = np.float64
    T = np.asarray(T, dtype=f64)
    R = np.ascontiguousarray(T[:3, :3])
    t = np.ascontiguousarray(T[:3, 3])
    S = np.ascontiguousarray(surface_pts, dtype=f64)
    Nm = np.ascontiguousarray(surface_nrm, dtype=f64)
    vps = np.zeros((0, 3)) if viewpoints is None else np.asarray(viewpoints, f64).reshape(-1, 3)
    tn = np.zeros(3) if table is None else np.asarray(table.normal, dtype=f64)
    toff = 0.0 if table is None else float(table.offset)
    P, seen, centre, radius, penetration, lowest = posed_samples(
        R, t, S, Nm, np.ascontiguousarray(vps), float(VIEW_FACING_COS), table is not None, tn,
        toff, float(d),
    )  # fmt: skip
    cloud = np.ascontiguousarray(cloud, dtype=f64)
    near = _gridknn.ball_rows(cloud, centre, radius + 2 * d)
    q = (cloud[near] - t) @ R
    dist, idx = surface.nearest(q, np.inf)
    # a point whose nearest sample faces away may still have a seen one within d (the
    # tree's rule: strictly within the next float up)
    seen_near = np.zeros(len(near), dtype=bool)
    amb = np.flatnonzero((dist <= d) & ~seen[idx])
    if len(amb) and seen.any():
        seen_near[amb] = _gridknn.space_any(S[seen], q[amb], float(np.nextafter(d, np.inf)))
    explained_n, inside_n, below_n, unexplained_n = consistency_counts(
        P, seen, S, Nm, cloud, near.astype(np.int64), np.ascontiguousarray(q),
        np.ascontiguousarray(dist), idx.astype(np.int64), seen_near, table is not None, tn,
        toff, bool(table is not None and lowest <= d), float(d),
        np.zeros(0, dtype=bool) if elsewhere is None else np.ascontiguousarray(elsewhere, bool),
        float(max(0.5 * d, _model_spacing(surface_pts))), _DIRS8,
    )  # fmt: skip
    return Consistency.of(explained_n, inside_n, below_n, penetration, unexplained_n)


def rank(
    candidates: list[PoseHypothesis], checks: list[Consistency]
) -> tuple[list[int], list[PoseHypothesis]]:
    """Candidate order (consistent first, then the most net support: points explained
    minus nearby object points left unexplained, then score) and the consistent candidates
    in that order.

    Net support, not the explained count alone: with the stereo pair's noisier points a
    cube pose wrapped around the lower part of a taller clutter box explained more points
    than the true pose under the sphere (tuning seed 1008: 1183 vs 1149) while leaving the
    box's upper part unexplained (309 vs 167 points)."""
    order = sorted(
        range(len(checks)),
        key=lambda i: (not checks[i].ok, -checks[i].support, -candidates[i].score),
    )
    return order, [candidates[i] for i in order if checks[i].ok]
