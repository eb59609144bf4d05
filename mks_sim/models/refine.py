"""Refinement and verification of pose hypotheses: point-to-plane ICP, scoring, symmetry.

A Hough matcher (section 2.2) reports every candidate transformation; "any of the maxima may be
chosen" when the model is symmetric. Here each candidate is refined by point-to-plane ICP of the
model surface (sampled points with normals) to the scene segment, scored by the fraction of
scene points it explains and its residual, ranked, and hypotheses that differ only by a symmetry
of the model (the cube's 24 rotations) are recognised as one and reported once, with the
equivalents listed.

Correspondences run scene -> model (each scene point to its nearest model point), so a partial,
one-sided scan is matched against the whole model without visibility reasoning.
"""

from __future__ import annotations

import functools
import logging
import math
from collections.abc import Sequence
from dataclasses import dataclass, replace

import numpy as np
from numpy.typing import ArrayLike, NDArray
from scipy.spatial import cKDTree

from mks_sim.errors import DataError
from mks_sim.geometry.transforms import invert, rotation_angle_deg
from mks_sim.models.pose import PoseHypothesis

__all__ = [
    "IcpResult",
    "ModelSurface",
    "VerifiedHypothesis",
    "detect_symmetries",
    "group_equivalent",
    "icp_point_to_plane",
    "merge_verified",
    "near_symmetries",
    "principal_half_turns",
    "batch_inlier_fractions",
    "score_pose",
    "verify_hypotheses",
]

log = logging.getLogger(__name__)
FloatArray = NDArray[np.float64]
IntArray = NDArray[np.intp]


@dataclass(frozen=True, eq=False)
class ModelSurface:
    """A model surface for ICP: points, outward normals and their k-d tree (model frame).

    Build with :meth:`from_arrays`.
    """

    points: FloatArray
    normals: FloatArray
    tree: cKDTree
    spacing: float  # median nearest-neighbour distance of the points (sampling spacing)

    @classmethod
    def from_arrays(cls, points: ArrayLike, normals: ArrayLike) -> ModelSurface:
        """Validate (M, 3) points and (M, 3) normals and build the tree."""
        p = np.asarray(points, dtype=np.float64)
        n = np.asarray(normals, dtype=np.float64)
        if p.ndim != 2 or p.shape[1] != 3 or p.shape != n.shape or len(p) < 3:
            raise DataError(
                f"ModelSurface: expected (M >= 3, 3) points and normals of the same shape, "
                f"got {p.shape} and {n.shape}"
            )
        if not (np.all(np.isfinite(p)) and np.all(np.isfinite(n))):
            raise DataError("ModelSurface: points or normals contain NaN/inf")
        n = n / np.clip(np.linalg.norm(n, axis=1, keepdims=True), 1e-12, None)
        tree = cKDTree(p)
        d, _ = tree.query(p[:: max(1, len(p) // 500)], k=2)
        return cls(p, n, tree, float(np.median(d[:, 1])))

    @functools.cached_property
    def size(self) -> float:
        """Diagonal of the bounding box (the object's size, points' units)."""
        return float(np.linalg.norm(np.ptp(self.points, axis=0)))

    @functools.cached_property
    def extent(self) -> float:
        """:func:`mks_sim.io.units.extent` of the samples (the unit check's model size),
        computed once."""
        from mks_sim.io.units import extent

        return extent(self.points)

    @property
    def lookup(self) -> NearestLookup | None:
        """The nearest-sample grid (:meth:`with_lookup`), None until it is built."""
        out: NearestLookup | None = self.__dict__.get("_lookup")
        return out

    def with_lookup(self) -> ModelSurface:
        """Build (once) the grid that answers :meth:`nearest` without the k-d tree, and
        return this surface.

        A long-lived model (the workstation's, built once per mesh) pays the build once
        (0.3-0.5 s for the 4,000-sample cube and part) and its ICP, scoring and batch
        inlier counts then look their correspondences up in an array instead of a tree
        query: 800 scene points in 0.09 ms against 0.7. The answers are the sample nearest
        each query's grid cell centre (cells of one sampling spacing): the exact nearest
        sample in about 3 of 4 queries, at most 0.8 mm farther on the cube.
        """
        if self.lookup is None:
            self.__dict__["_lookup"] = NearestLookup.build(self.points, self.tree, self.spacing)
        return self

    def nearest(self, points: FloatArray, max_distance: float) -> tuple[FloatArray, IntArray]:
        """``(distance, index)`` of each point's nearest sample, as ``tree.query(points,
        distance_upper_bound=max_distance)`` answers (misses: inf and ``len(points)``); by
        the grid once :meth:`with_lookup` built it, else by the k-d tree."""
        lookup = self.lookup
        if lookup is None:
            d, j = self.tree.query(points, distance_upper_bound=max_distance)
            return d, j
        return lookup.query(points, max_distance, self.points, self.tree)

    @functools.cached_property
    def offsets(self) -> FloatArray:
        """(M,) ``points . normals``: the tangent-plane offset of each sample (ICP residuals
        ``p . n - offset`` without gathering the points)."""
        return np.asarray(np.einsum("ij,ij->i", self.points, self.normals), dtype=np.float64)


#: Cells of a :class:`NearestLookup` at most (the cell grows past the sampling spacing for a
#: large or finely sampled model).
LOOKUP_MAX_CELLS = 3_000_000
#: The lookup's grid reaches this fraction of the model's size beyond its bounding box
#: (ICP's gates: 4 inlier distances, at most a tenth of the size; farther queries go to
#: the tree, and an ICP whose gate reaches past the grid runs its steps in Python). 0.2:
#: the workstation's 4.1 mm voxels give the cube a gate of ~16 mm, inside the 17 mm its
#: grid reaches (0.15: 13 mm, and the cube's verification took 8.2 ms instead of 4.9).
LOOKUP_MARGIN = 0.2


@dataclass(frozen=True, eq=False)
class NearestLookup:
    """A regular grid around a model surface whose cells hold the index of the sample
    nearest each cell centre (computed once by the k-d tree): nearest-sample queries
    become array lookups.

    Attributes:
        origin: (3,) centre of cell (0, 0, 0), model frame.
        cell: cell edge.
        shape: cells per axis.
        index: (prod(shape),) int32 sample index per cell, C order.
        margin: how far the grid reaches beyond the samples' bounding box (a query outside
            the grid is at least this far from every sample).
    """

    origin: FloatArray
    cell: float
    shape: tuple[int, int, int]
    index: NDArray[np.int32]
    margin: float

    @classmethod
    def build(cls, points: FloatArray, tree: cKDTree, spacing: float) -> NearestLookup:
        """The grid over the bounding box plus :data:`LOOKUP_MARGIN` of the size, cells of
        ``spacing`` (larger when that would exceed :data:`LOOKUP_MAX_CELLS`)."""
        lo, hi = points.min(axis=0), points.max(axis=0)
        margin = LOOKUP_MARGIN * float(np.linalg.norm(hi - lo))
        lo, hi = lo - margin, hi + margin
        cell = max(float(spacing), 1e-12)
        extent = hi - lo
        cell = max(cell, float(np.cbrt(np.prod(extent) / LOOKUP_MAX_CELLS)))
        n = np.ceil(extent / cell).astype(np.intp) + 1
        shape = (int(n[0]), int(n[1]), int(n[2]))
        axes = [lo[d] + cell * np.arange(shape[d]) for d in range(3)]
        centres = np.stack(np.meshgrid(*axes, indexing="ij"), axis=-1).reshape(-1, 3)
        _, j = tree.query(centres, workers=-1)
        return cls(lo, cell, shape, np.asarray(j, dtype=np.int32), margin)

    def query(
        self,
        p: FloatArray,
        max_distance: float,
        points: FloatArray,
        tree: cKDTree,
        compiled: bool | None = None,
    ) -> tuple[FloatArray, IntArray]:
        """``(distance, index)`` as ``tree.query(p, distance_upper_bound=max_distance)``:
        the distance is exact to the sample returned; queries outside the grid go to the
        tree when ``max_distance`` reaches past the grid's margin, else miss.
        ``compiled``: one numba pass (:func:`mks_sim.models._refine_kernels.lookup_nearest`)
        or numpy; None: compiled when numba imports."""
        if compiled is None:
            compiled = _compiled_available()
        if compiled:
            from mks_sim.models._refine_kernels import lookup_nearest

            d, j, off = lookup_nearest(
                np.ascontiguousarray(p, dtype=np.float64),
                self.origin,
                self.cell,
                np.asarray(self.shape, dtype=np.int64),
                self.index,
                points,
                float(max_distance),
            )
            if max_distance > self.margin and off.any():
                out = np.flatnonzero(off)
                d[out], j[out] = tree.query(p[out], distance_upper_bound=max_distance)
            return d, j.astype(np.intp, copy=False)
        c = np.rint((p - self.origin) / self.cell).astype(np.intp)
        nx, ny, nz = self.shape
        inside = (
            (c[:, 0] >= 0) & (c[:, 0] < nx) & (c[:, 1] >= 0) & (c[:, 1] < ny)
            & (c[:, 2] >= 0) & (c[:, 2] < nz)
        )  # fmt: skip
        miss = len(points)
        j = np.full(len(p), miss, dtype=np.intp)
        d = np.full(len(p), np.inf)
        ci = c[inside]
        ji = self.index[(ci[:, 0] * ny + ci[:, 1]) * nz + ci[:, 2]].astype(np.intp)
        di = np.sqrt(np.sum((p[inside] - points[ji]) ** 2, axis=1))
        ok = di < max_distance
        idx = np.flatnonzero(inside)
        j[idx[ok]] = ji[ok]
        d[idx[ok]] = di[ok]
        if not inside.all():
            if max_distance > self.margin:  # else no sample is near enough to a query outside
                out = np.flatnonzero(~inside)
                d[out], j[out] = tree.query(p[out], distance_upper_bound=max_distance)
        return d, j


@dataclass(frozen=True, eq=False)
class IcpResult:
    """Result of :func:`icp_point_to_plane`.

    Attributes:
        matrix: (4, 4) refined model -> scene transform (column convention).
        rmse: RMS point-to-plane residual of the kept correspondences.
        iterations: iterations run.
        converged: the last update was below the tolerance.
    """

    matrix: FloatArray
    rmse: float
    iterations: int
    converged: bool


@dataclass(frozen=True, eq=False)
class VerifiedHypothesis:
    """A refined, scored hypothesis and its symmetric equivalents.

    Attributes:
        hypothesis: the refined hypothesis (``matrix``, ``rmse``, ``score`` filled).
        inlier_fraction: fraction of scene points within the inlier distance of the model.
        equivalents: (E, 4, 4) other refined poses that are the same placement up to a
            symmetry of the model (empty if none were proposed).
    """

    hypothesis: PoseHypothesis
    inlier_fraction: float
    equivalents: FloatArray


_DIAG6 = np.diag_indices(6)
#: :func:`group_equivalent` compares every pair at once up to this many poses (the (H, S, H)
#: cosines: 256 poses and the cube's 24 symmetries, 1.6 million numbers); a pose at a time
#: beyond.
_GROUP_BATCH = 256
#: From this many poses :func:`group_equivalent` picks the representatives in one compiled
#: pass (the same rule; a hundred poses: ~0.3 ms of Python loop).
_GROUP_COMPILED_MIN = 16
#: Scene points from which ICP iterations use the compiled normal equations (numba).
ICP_COMPILED_MIN_POINTS = 64
#: ``stall``: ICP stops once its RMS residual fell by less than this fraction over the last
#: ``stall`` iterations.
STALL_GAIN = 1e-3


def _compiled_available() -> bool:
    """The compiled kernels of the models and the localization can run (numba imports and
    can cache here: :func:`mks_sim.lowlevel._gridknn.available`)."""
    from mks_sim.lowlevel import _gridknn

    return _gridknn.available()


# ICP stops in a two-cycle: an update as large as the last (0.7-1.4x), below CYCLE_MAX_STEP
# (rotation radians + translation / model size: 0.06 deg), pointing back along it within
# this cosine.
CYCLE_COSINE = 0.9
CYCLE_MAX_STEP = 1e-3


def _vnorm(v: FloatArray) -> float:
    """``np.linalg.norm`` of a 1-D float64 vector to the bit (numpy's is ``sqrt(v.dot(v))``),
    without its dispatch (1 us against 4: the ICP takes five per iteration)."""
    return math.sqrt(float(v.dot(v)))


def _rodrigues(omega: FloatArray) -> FloatArray:
    theta = _vnorm(omega)
    if theta < 1e-12:
        return np.eye(3)
    k = omega / theta
    K = np.array([[0.0, -k[2], k[1]], [k[2], 0.0, -k[0]], [-k[1], k[0], 0.0]])
    return np.eye(3) + np.sin(theta) * K + (1.0 - np.cos(theta)) * (K @ K)


def icp_point_to_plane(
    surface: ModelSurface,
    scene_points: ArrayLike,
    initial: ArrayLike,
    *,
    max_distance: float,
    trim: float = 0.9,
    max_iterations: int = 30,
    tolerance: float = 1e-5,
    axis: ArrayLike | None = None,
    compiled: bool | None = None,
    stall: int | None = None,
    fused: bool = False,
) -> IcpResult:
    """Point-to-plane ICP of a model surface to scene points (scene -> model correspondences).

    Each iteration matches every scene point (in the model frame) to its nearest model point,
    drops pairs farther than ``max_distance`` and the worst ``1 - trim`` of the rest, and
    solves the linearised point-to-plane problem for a small rotation and translation.

    Args:
        surface: the model surface.
        scene_points: (N, 3) scene points (one segment).
        initial: (4, 4) initial model -> scene transform.
        max_distance: correspondence gate (points' units).
        trim: fraction of gated pairs kept (the closest).
        max_iterations: iteration cap.
        tolerance: stop when the update (rotation radians + translation / model size) is below.
        axis: (3,) a direction in the model frame: the pose turns only about it (4 degrees
            of freedom, the translation free: an object resting on a face with this outward
            normal turns on its support plane and never tilts).
        compiled: the normal equations of each iteration in one numba pass
            (:mod:`mks_sim.models._refine_kernels`; the same sums in another order) or by
            numpy; None: compiled from :data:`ICP_COMPILED_MIN_POINTS` scene points when numba
            imports.
        stall: stop (not converged) once the RMS residual fell by less than
            :data:`STALL_GAIN` (0.1 %) over this many iterations: the pose slides along a fit
            that no longer improves (a wrong start in the healthy cube's scans ran all 26
            iterations); None runs to ``tolerance`` or ``max_iterations``.
        fused: every iteration in one compiled call
            (:func:`mks_sim.models._refine_kernels.icp_lookup_loop`: the same steps, the
            rounding of the transforms and the solve may differ) when the surface has its
            lookup grid (:meth:`ModelSurface.with_lookup`), ``max_distance`` is within the
            grid's margin, ``axis`` is None and numba imports; else as without it.

    Returns:
        :class:`IcpResult`.
    """
    scene = np.asarray(scene_points, dtype=np.float64)
    basis: FloatArray | None = None
    if axis is not None:
        f = np.asarray(axis, dtype=np.float64).ravel()
        if f.shape != (3,) or not np.all(np.isfinite(f)) or np.linalg.norm(f) < 1e-12:
            raise DataError(f"icp_point_to_plane: expected a (3,) non-zero axis, got {axis!r}")
        f = f / np.linalg.norm(f)
        basis = np.zeros((6, 4))  # columns: turn about f, translations
        basis[:3, 0] = f
        basis[3:, 1:] = np.eye(3)
    if scene.ndim != 2 or scene.shape[1] != 3 or len(scene) < 6:
        raise DataError(f"icp_point_to_plane: expected (N >= 6, 3) scene points, got {scene.shape}")
    T = np.asarray(initial, dtype=np.float64)
    if T.shape != (4, 4):
        raise DataError(f"icp_point_to_plane: expected (4, 4) initial transform, got {T.shape}")
    if stall is not None and (isinstance(stall, bool) or not isinstance(stall, int) or stall < 1):
        raise DataError(
            f"icp_point_to_plane: expected stall >= 1 iterations or None, got {stall!r}"
        )
    scene_to_model = invert(T)
    size = max(surface.size, 1e-12)
    normals, offsets = surface.normals, surface.offsets
    lookup = surface.lookup
    if (
        fused and basis is None and lookup is not None and max_distance <= lookup.margin
        and _compiled_available()
    ):  # fmt: skip
        from mks_sim.models._refine_kernels import icp_lookup_loop

        S, rmse_f, it_f, conv_f = icp_lookup_loop(
            np.ascontiguousarray(scene), np.ascontiguousarray(scene_to_model), lookup.origin,
            lookup.cell, np.asarray(lookup.shape, dtype=np.int64), lookup.index,
            surface.points, normals, offsets, float(max_distance), float(trim),
            int(max_iterations), float(tolerance), float(size), 0 if stall is None else stall,
            STALL_GAIN, CYCLE_MAX_STEP, CYCLE_COSINE,
        )  # fmt: skip
        return IcpResult(invert(S), float(rmse_f), int(it_f), bool(conv_f))
    if compiled is None:
        compiled = len(scene) >= ICP_COMPILED_MIN_POINTS and _compiled_available()
    if compiled:
        from mks_sim.models._refine_kernels import point_to_plane_system
    A = np.empty((0 if compiled else len(scene), 6))
    rmse, converged, it = np.inf, False, 0
    step = np.zeros(6)  # the last update, translation scaled by the size
    history: list[float] = []
    for it in range(1, max_iterations + 1):  # noqa: B007 - reported
        p = scene @ scene_to_model[:3, :3].T + scene_to_model[:3, 3]  # (N, 3) model frame
        dist, j = surface.nearest(p, max_distance)
        if compiled:
            H, g, ss, used = point_to_plane_system(p, dist, j, normals, offsets, trim)
            if used < 6:
                break
            rmse = float(np.sqrt(ss / used))
        else:
            ok = dist < np.inf
            n_ok = int(np.count_nonzero(ok))
            if n_ok < 6:
                break
            if trim < 1.0 and n_ok > 10:
                kth = int(trim * (n_ok - 1))
                ok &= dist <= np.partition(dist[ok], kth)[kth]
            p, jj = p[ok], j[ok]
            n = normals[jj]
            r = np.einsum("ij,ij->i", p, n) - offsets[jj]  # (K,) point-to-plane residuals
            a = A[: len(p)]  # (K, 6): [p x n, n]
            a[:, 0] = p[:, 1] * n[:, 2] - p[:, 2] * n[:, 1]
            a[:, 1] = p[:, 2] * n[:, 0] - p[:, 0] * n[:, 2]
            a[:, 2] = p[:, 0] * n[:, 1] - p[:, 1] * n[:, 0]
            a[:, 3:] = n
            H, g = a.T @ a, a.T @ r
            rmse = float(np.sqrt(np.mean(r**2)))
        if basis is None:
            H[_DIAG6] += 1e-9
            x = np.linalg.solve(H, -g)
        else:
            Hb = basis.T @ H @ basis
            Hb[_DIAG6[0][:4], _DIAG6[1][:4]] += 1e-9
            x = basis @ np.linalg.solve(Hb, -(basis.T @ g))
        scaled = np.concatenate([x[:3], x[3:] / size])
        # A two-cycle: the trimmed pairs flip between two sets and each update undoes the
        # last (measured: 1e-4 rad back and forth for 25 iterations on a scanned cube).
        # Half the step lands between the two states; further iterations change nothing.
        norm, last = _vnorm(scaled), _vnorm(step)
        cycle = (
            norm < CYCLE_MAX_STEP
            and 0.7 * last < norm < 1.4 * last
            and float(scaled @ step) < -CYCLE_COSINE * norm * last
        )
        if cycle:
            x = 0.5 * x
        step = scaled
        dT = np.eye(4)
        dT[:3, :3] = _rodrigues(x[:3])
        dT[:3, 3] = x[3:]
        scene_to_model = dT @ scene_to_model
        if cycle or _vnorm(x[:3]) + _vnorm(x[3:]) / size < tolerance:
            converged = True
            break
        history.append(rmse)
        if stall is not None and len(history) > stall:
            if rmse > (1.0 - STALL_GAIN) * history[-1 - stall]:
                break  # the fit no longer improves: further steps slide along it
    return IcpResult(invert(scene_to_model), rmse, it, converged)


def score_pose(
    surface: ModelSurface,
    scene_points: ArrayLike,
    matrix: ArrayLike,
    inlier_distance: float,
    compiled: bool = False,
) -> tuple[float, float, float]:
    """Score a pose by how well the model explains the scene points.

    Args:
        surface: the model surface.
        scene_points: (N, 3) scene segment.
        matrix: (4, 4) model -> scene.
        inlier_distance: a scene point is explained when its point-to-plane distance to its
            nearest model point is within this and that point is within this plus the
            model's sampling spacing (points' units).
        compiled: with the surface's lookup grid and numba, one compiled pass
            (:func:`mks_sim.models._refine_kernels.lookup_score`; 1,500 points: ~0.5 ->
            0.05 ms) whose moved points and sums round as its loop does: the score's last
            bits may differ from numpy's.

    Returns:
        ``(score, inlier_fraction, rmse)``: ``score = inlier_fraction * exp(-(rmse / d)^2 / 2)``
        with ``d`` the inlier distance and ``rmse`` the RMS point-to-plane residual of the
        inliers (so among equally explaining poses the tighter one wins).
    """
    scene = np.asarray(scene_points, dtype=np.float64)
    S = invert(matrix)
    lookup = surface.lookup
    reach = inlier_distance + surface.spacing
    if compiled and lookup is not None and reach <= lookup.margin and _compiled_available():
        from mks_sim.models._refine_kernels import lookup_score

        count, ssq = lookup_score(
            np.ascontiguousarray(scene), S, lookup.origin, lookup.cell,
            np.asarray(lookup.shape, dtype=np.int64), lookup.index, surface.points,
            surface.normals, float(reach), float(inlier_distance),
        )  # fmt: skip
        if count == 0:
            return 0.0, 0.0, float("inf")
        frac = count / len(scene)
        rmse = float(np.sqrt(ssq / count))
        return frac * float(np.exp(-0.5 * (rmse / inlier_distance) ** 2)), frac, rmse
    p = scene @ S[:3, :3].T + S[:3, 3]
    dist, j = surface.nearest(p, reach)
    ok = np.isfinite(dist)
    r_all = np.zeros(len(p))
    r_all[ok] = np.einsum("ij,ij->i", p[ok] - surface.points[j[ok]], surface.normals[j[ok]])
    ok &= np.abs(r_all) <= inlier_distance
    frac = float(ok.mean()) if len(ok) else 0.0
    if not ok.any():
        return 0.0, 0.0, float("inf")
    r = r_all[ok]
    rmse = float(np.sqrt(np.mean(r**2)))
    return frac * float(np.exp(-0.5 * (rmse / inlier_distance) ** 2)), frac, rmse


def batch_inlier_fractions(
    surface: ModelSurface,
    scene_points: ArrayLike,
    matrices: ArrayLike,
    inlier_distance: float,
    compiled: bool | None = None,
) -> FloatArray:
    """(K,) inlier fraction of :func:`score_pose` for K poses at once: the scene points are
    moved into each model frame and all K x N of them go through one nearest-sample query.

    Args:
        surface: the model surface.
        scene_points: (N, 3) scene points (a few hundred suffice for ranking).
        matrices: (K, 4, 4) model -> scene poses.
        inlier_distance: as :func:`score_pose`.
        compiled: with the surface's lookup grid (:meth:`ModelSurface.with_lookup`), one
            numba pass (:func:`mks_sim.models._refine_kernels.lookup_inlier_counts`) or
            numpy; None: compiled when numba imports.
    """
    scene = np.asarray(scene_points, dtype=np.float64)
    T = np.asarray(matrices, dtype=np.float64).reshape(-1, 4, 4)
    if len(T) == 0 or len(scene) == 0:
        return np.zeros(len(T))
    lookup = surface.lookup
    reach = inlier_distance + surface.spacing
    if compiled is None:
        compiled = _compiled_available()
    if compiled and lookup is not None and reach <= lookup.margin:
        # one compiled pass: no (K, N, 3) arrays (a hundred vertex hypotheses on 100 scene
        # points: ~1 ms -> 0.1); the same counts up to the rounding of the moved points
        from mks_sim.models._refine_kernels import lookup_inlier_counts

        counts = lookup_inlier_counts(
            np.ascontiguousarray(scene), np.ascontiguousarray(T), lookup.origin, lookup.cell,
            np.asarray(lookup.shape, dtype=np.int64), lookup.index, surface.points,
            surface.normals, float(reach), float(inlier_distance),
        )  # fmt: skip
        return np.asarray(counts / len(scene), dtype=np.float64)
    R = T[:, :3, :3]
    # model frame: R^T (p - t)
    p = np.matmul(scene[None, :, :] - T[:, None, :3, 3], R)  # (K, N, 3): (p - t) R = R^T (p - t)
    flat = p.reshape(-1, 3)
    dist, j = surface.nearest(flat, inlier_distance + surface.spacing)
    ok = np.isfinite(dist)
    r = np.full(len(flat), np.inf)
    jj = j[ok]
    r[ok] = np.abs(np.einsum("ij,ij->i", flat[ok] - surface.points[jj], surface.normals[jj]))
    inl = (r <= inlier_distance).reshape(len(T), -1)
    return np.asarray(inl.mean(axis=1), dtype=np.float64)


def _angles_deg(R: FloatArray, rotations: FloatArray) -> FloatArray:
    """(S,) angles (degrees) between R (3, 3) and each of (S, 3, 3) rotations."""
    cos = (np.einsum("sij,ij->s", rotations, R) - 1.0) / 2.0
    return np.degrees(np.arccos(np.clip(cos, -1.0, 1.0)))


def _with_identity(symmetries: ArrayLike | None) -> FloatArray:
    syms = np.eye(3)[None]
    if symmetries is not None:
        s = np.asarray(symmetries, dtype=np.float64)
        if s.ndim != 3 or s.shape[1:] != (3, 3):
            raise DataError(f"expected (S, 3, 3) symmetries, got {s.shape}")
        syms = np.concatenate([syms, s])
    return syms


def _matching_symmetry(A: FloatArray, B: FloatArray, syms: FloatArray) -> FloatArray:
    """The symmetry S with R_A ~ R_B S."""
    rel = B[:3, :3].T @ A[:3, :3]
    return syms[int(np.argmin(_angles_deg(rel, syms)))]


def _matching_symmetries(As: Sequence[FloatArray], B: FloatArray, syms: FloatArray) -> FloatArray:
    """(K, 3, 3) :func:`_matching_symmetry` of each of K poses ``As`` to ``B``, at once."""
    if len(As) == 0:
        return np.zeros((0, 3, 3))
    rel = np.matmul(B[:3, :3].T, np.asarray(As, dtype=np.float64)[:, :3, :3])  # (K, 3, 3)
    cos = (np.matmul(rel.reshape(len(rel), 9), syms.reshape(len(syms), 9).T) - 1.0) / 2.0
    angles = np.degrees(np.arccos(np.clip(cos, -1.0, 1.0)))  # (K, S), as _angles_deg
    return syms[np.argmin(angles, axis=1)]


def _symmetric_images(T: FloatArray, related: list[FloatArray]) -> FloatArray:
    """Distinct poses T @ S for the non-identity S in ``related`` (the equivalents)."""
    out = np.zeros((0, 3, 3))
    if related:
        R = np.asarray(related, dtype=np.float64).reshape(-1, 3, 3)
        # The symmetries are exact copies of the model's: rounding identifies equal ones.
        # The first of each in order, by a dict of the rounded rows' bytes (+ 0.0 makes
        # -0.0 the 0.0 it equals): np.unique(axis=0)'s groups, ~10x faster on 24 rows.
        keys = np.round(R.reshape(len(R), 9), 6) + 0.0
        seen: dict[bytes, int] = {}
        for k, row in enumerate(keys):
            seen.setdefault(row.tobytes(), k)
        first = np.fromiter(seen.values(), dtype=np.intp, count=len(seen))
        trace = R[first, 0, 0] + R[first, 1, 1] + R[first, 2, 2]  # (np.trace's order)
        out = R[first[trace < 3.0 - 1e-9]]  # not the identity
    images = np.repeat(T[None], len(out), axis=0)
    if len(out):
        images[:, :3, :3] = T[:3, :3] @ out
    return images.reshape(-1, 4, 4)


def group_equivalent(
    matrices: Sequence[ArrayLike],
    symmetries: ArrayLike | None = None,
    *,
    rotation_tol_deg: float = 5.0,
    translation_tol: float,
    compiled: bool = True,
) -> NDArray[np.intp]:
    """Label poses that are the same placement up to a model symmetry.

    Args:
        matrices: H (4, 4) model -> scene poses, best first.
        symmetries: (S, 3, 3) rotations about the model origin mapping the model onto itself
            (identity implied).
        rotation_tol_deg: angular tolerance.
        translation_tol: distance tolerance of the model origin (points' units).
        compiled: label in one compiled pass when numba imports (only the representatives'
            pairs; the cosines' sums in a fixed order, so a pair within ~1e-16 of the
            tolerance could fall on the other side of it than numpy's batched products
            put it); False: numpy's products.

    Returns:
        (H,) int label = index of the first (best) pose of its group.
    """
    syms = _with_identity(symmetries)
    mats = np.asarray([np.asarray(m, dtype=np.float64) for m in matrices]).reshape(-1, 4, 4)
    labels = np.arange(len(mats))
    reps: list[int] = []
    cos_tol = np.cos(np.radians(rotation_tol_deg))
    if compiled and len(mats) > 1 and _compiled_available():
        # only the representatives' pairs, in one compiled pass (100 poses under the cube's
        # 24 symmetries: 4.8 ms of batched products -> 0.16 ms); the products' labels below
        from mks_sim.models._refine_kernels import equivalent_labels

        return np.asarray(
            equivalent_labels(
                np.ascontiguousarray(mats), np.ascontiguousarray(syms, dtype=np.float64),
                float(translation_tol), float(cos_tol),
            ),
            dtype=labels.dtype,
        )  # fmt: skip
    if 1 < len(mats) <= _GROUP_BATCH:
        # every pair at once: R_b = R_a S <=> trace((R_a S)^T R_b) = 1 + 2 cos(angle), one
        # (H S, 9) x (9, H) product; then the same first-representative rule as below
        h = len(mats)
        R = mats[:, :3, :3]
        RS = np.matmul(R[:, None], syms[None]).reshape(h, len(syms), 9)  # (H, S, 9)
        cos = (np.matmul(RS, R.reshape(h, 9).T) - 1.0) / 2.0  # (H, S, H): [a, s, b]
        t = mats[:, :3, 3]
        near = np.linalg.norm(t[:, None, :] - t[None, :, :], axis=2) <= translation_tol
        same = near & (cos.max(axis=1) >= cos_tol)  # [rep a, pose b]
        if h >= _GROUP_COMPILED_MIN and _compiled_available():
            from mks_sim.models._refine_kernels import first_representatives

            return np.asarray(first_representatives(same), dtype=labels.dtype)
        is_rep = np.zeros(h, dtype=bool)
        for i in range(h):
            hit = np.flatnonzero(same[:i, i] & is_rep[:i])
            if hit.size:
                labels[i] = hit[0]
            else:
                is_rep[i] = True
        return labels
    for i, M in enumerate(mats):
        if reps:
            R_reps = mats[reps, :3, :3]  # (r, 3, 3)
            near = np.linalg.norm(mats[reps, :3, 3] - M[:3, 3], axis=1) <= translation_tol
            if near.any():
                # R_M = R_rep S  <=>  trace(S^T R_rep^T R_M) = 1 + 2 cos(angle)
                rel = np.einsum("rji,jk->rik", R_reps[near], M[:3, :3])  # (r', 3, 3)
                cos = (np.einsum("sij,rij->rs", syms, rel) - 1.0) / 2.0  # (r', S)
                hit = np.flatnonzero(cos.max(axis=1) >= cos_tol)
                if hit.size:
                    labels[i] = np.asarray(reps)[near][hit[0]]
                    continue
        reps.append(i)
    return labels


def merge_verified(
    verified: Sequence[VerifiedHypothesis],
    symmetries: ArrayLike | None,
    translation_tol: float,
) -> list[VerifiedHypothesis]:
    """Verified hypotheses of several verification runs as one list: best score first (then
    lowest residual), one per placement up to a symmetry (3 deg, ``translation_tol``)."""
    merged = sorted(verified, key=lambda v: (-v.hypothesis.score, v.hypothesis.rmse))
    keep = group_equivalent(
        [v.hypothesis.matrix for v in merged],
        symmetries,
        rotation_tol_deg=3.0,
        translation_tol=translation_tol,
    )
    return [v for i, v in enumerate(merged) if keep[i] == i]


def principal_half_turns(points: ArrayLike) -> FloatArray:
    """Half turns about a point set's three principal axes through its centroid.

    A rounded shape seen from one side fits its own half-turned copy almost as well (the
    visible cap of an egg fits either end): these are the poses to try against a found one.

    Args:
        points: (M, 3) model surface samples (model frame).

    Returns:
        (3, 4, 4) transforms ``p -> c + R (p - c)``, ``R`` a half turn about a principal axis.
    """
    p = np.asarray(points, dtype=np.float64)
    c = p.mean(axis=0)
    _, vecs = np.linalg.eigh(np.cov((p - c).T))
    out = np.repeat(np.eye(4)[None], 3, axis=0)
    for k in range(3):
        a = vecs[:, k]
        R = 2.0 * np.outer(a, a) - np.eye(3)  # rotation by pi about a
        out[k, :3, :3] = R
        out[k, :3, 3] = c - R @ c
    return out


def near_symmetries(
    points: ArrayLike,
    symmetries: ArrayLike | None = None,
    *,
    tolerance: float = 2.0,
) -> FloatArray:
    """Half turns that map a model's surface almost onto itself: its near-twin poses.

    Candidates are the half turns about the axes of the samples' bounding box through its
    centre and about their principal axes through their centroid; one is kept when the
    median distance of the turned samples to the nearest sample is within ``tolerance``
    sampling spacings (most of the surface lands on itself; the features that differ may
    be hidden in a view) and it is no exact symmetry of the model (within 5 deg of one of
    ``symmetries``, or of another kept turn). The industrial part turned about its height
    axis: median 1.6 mm at 1.3 mm spacing, 10 % of the surface over 12 mm off.

    Args:
        points: (M, 3) model surface samples (model frame).
        symmetries: (S, 3, 3) the model's exact symmetries (None: none).
        tolerance: median distance allowed, in sampling spacings.

    Returns:
        (K, 4, 4) transforms ``p -> c + R (p - c)`` (K may be 0).
    """
    p = np.asarray(points, dtype=np.float64)
    if p.ndim != 2 or p.shape[1] != 3 or len(p) < 10:
        raise DataError(f"near_symmetries: expected (M >= 10, 3) points, got {p.shape}")
    tree = cKDTree(p)
    spacing = float(np.median(tree.query(p[:: max(1, len(p) // 500)], k=2)[0][:, 1]))
    lo, hi = p.min(axis=0), p.max(axis=0)
    box = np.repeat(np.eye(4)[None], 3, axis=0)
    for k in range(3):
        a = np.eye(3)[k]
        R = 2.0 * np.outer(a, a) - np.eye(3)
        box[k, :3, :3] = R
        box[k, :3, 3] = 0.5 * (lo + hi) - R @ (0.5 * (lo + hi))
    known = [np.eye(3)] + ([] if symmetries is None else list(np.asarray(symmetries)))
    out: list[FloatArray] = []
    for T in np.concatenate([box, principal_half_turns(p)]):
        if min(rotation_angle_deg(T[:3, :3], S) for S in known) < 5.0:
            continue
        if np.median(tree.query(p @ T[:3, :3].T + T[:3, 3])[0]) <= tolerance * spacing:
            out.append(T)
            known.append(T[:3, :3])
    return np.asarray(out, dtype=np.float64).reshape(-1, 4, 4)


def detect_symmetries(
    points: ArrayLike,
    candidates: ArrayLike,
    tolerance: float,
) -> FloatArray:
    """The candidate rotations (about the origin) that map a point set onto itself.

    Args:
        points: (V, 3) characteristic points of a model (e.g. its vertexes).
        candidates: (C, 3, 3) rotations to test (e.g. ``cube_rotations()``).
        tolerance: every rotated point must lie within this distance of a point.

    Returns:
        (S, 3, 3) the candidates that are symmetries, the identity excluded.
    """
    pts = np.asarray(points, dtype=np.float64)
    cands = np.asarray(candidates, dtype=np.float64)
    tree = cKDTree(pts)
    out = [
        R
        for R in cands
        if rotation_angle_deg(R, np.eye(3)) > 1e-6
        and float(tree.query(pts @ R.T)[0].max()) <= tolerance
    ]
    return np.array(out).reshape(-1, 3, 3)


def verify_hypotheses(
    hypotheses: Sequence[PoseHypothesis],
    surface: ModelSurface,
    scene_points: ArrayLike,
    *,
    inlier_distance: float,
    icp_distance: float | None = None,
    symmetries: ArrayLike | None = None,
    max_icp: int = 20,
    icp_iterations: int = 20,
    full_refine: int = 3,
    max_scene_points: int = 1500,
    prescreen: int | None = None,
    coarse_points: int = 500,
    rng: np.random.Generator | None = None,
    icp_stall: int | None = None,
    icp_fused: bool = False,
    compiled_score: bool = False,
) -> list[VerifiedHypothesis]:
    """Refine (ICP), score and rank hypotheses; report symmetric equivalents once.

    Args:
        hypotheses: candidates from a matcher, any order.
        surface: the model surface.
        scene_points: (N, 3) the scene segment the hypotheses refer to.
        inlier_distance: scoring inlier distance (e.g. 2-3 x the sampling spacing).
        icp_distance: ICP correspondence gate; default 4 x ``inlier_distance``.
        symmetries: (S, 3, 3) model symmetries for grouping.
        max_icp: refine at most this many initial poses (the most voted, after merging
            initial poses that are already equivalent).
        icp_iterations: ICP iteration cap of the full refinement.
        full_refine: fully refine this many starts (best after 6 coarse ICP iterations on
            500 scene points); the others keep their coarse pose and score.
        max_scene_points: ICP and scoring use a random subset of at most this many points.
        prescreen: when set, all distinct starts are first scored together in one batch
            (:func:`batch_inlier_fractions` on 300 scene points) and only this many of the
            best get the coarse ICP; None runs the coarse ICP on every start (up to
            ``max_icp``).
        coarse_points: scene points of the coarse ICP stage.
        rng: generator for that subset (default seeded 0).
        icp_stall: ``stall`` of the full refinement's ICP (:func:`icp_point_to_plane`).
        icp_fused: ``fused`` of every ICP (:func:`icp_point_to_plane`).
        compiled_score: ``compiled`` of every :func:`score_pose`.

    Returns:
        One :class:`VerifiedHypothesis` per distinct placement, best score first.
    """
    scene = np.asarray(scene_points, dtype=np.float64)
    if scene.ndim != 2 or scene.shape[1] != 3:
        raise DataError(f"verify_hypotheses: expected (N, 3) scene points, got {scene.shape}")
    if not hypotheses or len(scene) < 6:
        return []
    rng = np.random.default_rng(0) if rng is None else rng
    if len(scene) > max_scene_points:
        scene = scene[rng.choice(len(scene), max_scene_points, replace=False)]
    gate = 4.0 * inlier_distance if icp_distance is None else icp_distance
    size = surface.size
    syms = _with_identity(symmetries)
    # Merge initial poses that are the same placement up to a symmetry, keeping the most
    # voted; remember which symmetry relates each merged pose to its representative.
    ordered = sorted(hypotheses, key=lambda h: -h.votes)
    init_labels = group_equivalent(
        [h.matrix for h in ordered], symmetries, rotation_tol_deg=8.0, translation_tol=0.05 * size
    )
    start_ids = [i for i in range(len(ordered)) if init_labels[i] == i]
    if prescreen is not None and len(start_ids) > prescreen:
        probe = scene[rng.permutation(len(scene))[:300]]
        fr = batch_inlier_fractions(
            surface, probe, np.stack([ordered[i].matrix for i in start_ids]), gate / 2
        )
        best = np.argsort(-fr, kind="stable")[:prescreen]
        start_ids = [start_ids[k] for k in sorted(best)]
    start_ids = start_ids[:max_icp]
    # Two stages: a few coarse ICP iterations on a subset for every start, then full
    # refinement of the most promising ones only.
    coarse: list[tuple[float, int, FloatArray]] = []
    extra_iterations = 0
    if len(start_ids) <= full_refine:
        # every start is fully refined: the coarse stage would only order them
        coarse = [(0.0, i, ordered[i].matrix) for i in start_ids]
        extra_iterations = 6
    else:
        coarse_scene = scene[rng.permutation(len(scene))[:coarse_points]]
        for i in start_ids:
            icp = icp_point_to_plane(
                surface, coarse_scene, ordered[i].matrix, max_distance=gate, max_iterations=6,
                fused=icp_fused,
            )  # fmt: skip
            coarse.append(
                (
                    score_pose(
                        surface, coarse_scene, icp.matrix, inlier_distance, compiled_score
                    )[0],
                    i,
                    icp.matrix,
                )
            )
        coarse.sort(key=lambda c: -c[0])
    refined: list[tuple[PoseHypothesis, float, list[FloatArray]]] = []
    for rank, (_, i, T_coarse) in enumerate(coarse):
        h = ordered[i]
        if rank < full_refine:
            icp = icp_point_to_plane(
                surface,
                scene,
                T_coarse,
                max_distance=gate,
                max_iterations=icp_iterations + extra_iterations,
                stall=icp_stall,
                fused=icp_fused,
            )
            T_new = icp.matrix
        else:
            T_new = T_coarse
        score, frac, rmse = score_pose(surface, scene, T_new, inlier_distance, compiled_score)
        members = [k for k in range(len(ordered)) if init_labels[k] == i and k != i]
        related = list(_matching_symmetries([ordered[k].matrix for k in members], h.matrix, syms))
        # The reference point moves with the model: p_ref_model = T_init^-1 p_ref.
        inv = invert(h.matrix)
        ref_model = inv[:3, :3] @ h.reference_point + inv[:3, 3]
        ref = T_new[:3, :3] @ ref_model + T_new[:3, 3]
        moved = replace(h, matrix=T_new, reference_point=ref, rmse=rmse, score=score)
        refined.append((moved, frac, related))
    refined.sort(key=lambda hf: (-hf[0].score, hf[0].rmse))
    labels = group_equivalent(
        [h.matrix for h, _, _ in refined],
        symmetries,
        rotation_tol_deg=3.0,
        translation_tol=max(inlier_distance, 0.01 * size),
    )
    out: list[VerifiedHypothesis] = []
    for i, (h, frac, related) in enumerate(refined):
        if labels[i] != i:
            continue
        for k in range(len(refined)):
            if labels[k] == i and k != i:
                related = related + [_matching_symmetry(refined[k][0].matrix, h.matrix, syms)]
                related = related + refined[k][2]
        eq = _symmetric_images(h.matrix, related)
        out.append(VerifiedHypothesis(h, frac, eq))
    log.debug(
        "verify_hypotheses: %d in, %d refined, %d distinct", len(hypotheses), len(refined), len(out)
    )
    return out
