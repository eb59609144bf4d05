"""Region growing on the spatial proximity graph: planar and curved regions, plane and sphere fits.

Section 2.2 of the paper: "the points in the graph can be grouped to find the planar regions",
whose intersections give the vertexes of a polyhedron; section 4.1 separates planar from curved
surface points. Planar regions grow over SPG edges from the flattest points while the normal
stays within an angle of the region's plane and the point stays within a distance of it; the
remaining curved points are split into SPG-connected curved regions and fitted with spheres.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike, NDArray
from scipy import sparse

from mks_sim.errors import DataError
from mks_sim.lowlevel import _gridknn
from mks_sim.lowlevel._gridknn import column_mean, masked_components, row_norms
from mks_sim.lowlevel.normals import (
    DEFAULT_CURVATURE_THRESHOLD,
    FixedGraph,
    GraphLike,
    SurfaceNormals,
    as_points,
    curvature_code,
    estimate_normals,
    neighbour_table,
    symmetric_adjacency,
)
from mks_sim.lowlevel.spg import SpatialProximityGraph

__all__ = [
    "CurvedRegion",
    "PlanarRegion",
    "Plane",
    "Segmentation",
    "SphereFit",
    "fit_plane",
    "fit_plane_ransac",
    "fit_sphere",
    "grow_planar_regions",
    "median_spacing",
    "segment_surfaces",
    "warm_up_kernels",
]

log = logging.getLogger(__name__)
FloatArray = NDArray[np.float64]
IntArray = NDArray[np.intp]
#: Points from which region growing uses the compiled kernel (when numba imports): below it
#: the numpy loop is as fast and a fresh process pays no numba import.
_COMPILED_MIN_POINTS = 500


@dataclass(frozen=True, eq=False)
class Plane:
    """The plane ``normal . x = offset``.

    Attributes:
        normal: (3,) unit normal.
        offset: signed distance of the plane from the origin along ``normal``.
        rmse: RMS point-to-plane distance of the fitted points (0 for a given plane).
    """

    normal: FloatArray
    offset: float
    rmse: float = 0.0

    def distance(self, points: ArrayLike) -> FloatArray:
        """(N,) signed distances of (N, 3) points (positive on the normal's side)."""
        return np.asarray(points, dtype=np.float64) @ self.normal - self.offset

    def flipped(self) -> Plane:
        """The same plane with the opposite normal."""
        return Plane(-self.normal, -self.offset, self.rmse)


@dataclass(frozen=True, eq=False)
class PlanarRegion:
    """A planar region of the SPG (a face of a polyhedron).

    Attributes:
        indices: (n,) int indices of the member points.
        plane: robust fit; the normal agrees with the members' (oriented) point normals.
        centroid: (3,) mean of the members.
    """

    indices: IntArray
    plane: Plane
    centroid: FloatArray

    @property
    def normal(self) -> FloatArray:
        return self.plane.normal


@dataclass(frozen=True, eq=False)
class SphereFit:
    """A sphere fitted to points: centre (3,), radius and RMS radial residual (points' units)."""

    center: FloatArray
    radius: float
    rmse: float


@dataclass(frozen=True, eq=False)
class CurvedRegion:
    """An SPG-connected set of curved (+1) points and its sphere fit (None if degenerate)."""

    indices: IntArray
    sphere: SphereFit | None


@dataclass(frozen=True, eq=False)
class Segmentation:
    """Grouping result of one cloud.

    Attributes:
        normals: (N, 3) oriented unit normals.
        curvature: (N,) surface variation.
        codes: (N,) int8 Surface_Curvature code (+1 curved, -1 planar).
        labels: (N,) int, index into ``planes`` or -1.
        planes: planar regions, largest first.
        curved: curved regions, largest first.
        spacing: median SPG edge length (the sampling spacing).
    """

    normals: FloatArray
    curvature: FloatArray
    codes: NDArray[np.int8]
    labels: IntArray
    planes: tuple[PlanarRegion, ...]
    curved: tuple[CurvedRegion, ...]
    spacing: float


def median_spacing(graph: GraphLike) -> float:
    """Median length of the SPG's edges (0 if it has none)."""
    data = sparse.csr_array(graph.adjacency).data
    return _median(data) if data.size else 0.0


def fit_plane(points: ArrayLike, iterations: int = 3, *, compiled: bool = False) -> Plane:
    """Least-squares plane with iterative outlier rejection (residual > 3 robust sigmas).

    Args:
        points: (N >= 3, 3) points.
        iterations: re-fits after rejecting outliers.
        compiled: the same steps in one compiled call when numba imports
            (:func:`mks_sim.lowlevel._regions_kernels.robust_plane`; the sums' order and
            the eigen-solver's rounding may differ: ``localize_cloud``, the workstation's
            representation and its table ask for it).

    Returns:
        :class:`Plane` (normal sign arbitrary) with the RMS residual of the kept points.
    """
    pts = as_points(points, "fit_plane: points", min_points=3)
    if compiled and _gridknn.available():
        from mks_sim.lowlevel._regions_kernels import robust_plane

        normal_c, offset_c, rmse_c = robust_plane(np.ascontiguousarray(pts), int(iterations))
        return Plane(normal_c, float(offset_c), float(rmse_c))
    # (Moments by products over a 0/1 weight on the (3, N) transpose took the 13,000 table
    # points 3.0 -> 1.4 ms, the same planes to rounding; that rounding flipped the suite's
    # replay of a bin push, a knife-edge, so the row gathers stay. The median is exact.)
    keep = np.ones(len(pts), dtype=bool)
    normal, offset = np.array([0.0, 0.0, 1.0]), 0.0
    for _ in range(max(1, iterations)):
        sub = np.compress(keep, pts, axis=0)  # (a mask's row gather, 4x faster than pts[keep])
        c = column_mean(sub)
        d = sub - c
        # the smallest principal axis: eigenvector of the 3x3 scatter (no (N, 3) SVD)
        normal = np.linalg.eigh(d.T @ d)[1][:, 0]
        offset = float(normal @ c)
        r = np.abs(pts @ normal - offset)
        sigma = 1.4826 * _median(r[keep])
        new_keep = r <= max(3.0 * sigma, 1e-12)
        if new_keep.sum() < 3 or np.array_equal(new_keep, keep):
            break
        keep = new_keep
    r = np.compress(keep, pts, axis=0) @ normal - offset
    return Plane(normal, offset, float(np.sqrt(np.mean(r**2))))


def _median(x: FloatArray) -> float:
    """``np.median`` of a 1-D array without NaN (:func:`mks_sim.lowlevel._gridknn.median`:
    np.median's checks and copies cost several times the selection)."""
    return _gridknn.median(np.asarray(x, dtype=np.float64))


def fit_plane_ransac(
    points: ArrayLike,
    threshold: float,
    rng: np.random.Generator,
    iterations: int = 200,
    fit_points: int | None = None,
    compiled_fit: bool = False,
) -> tuple[Plane, NDArray[np.bool_]]:
    """RANSAC plane (3-point samples) refined by :func:`fit_plane` on its inliers.

    Args:
        points: (N >= 3, 3) points.
        threshold: inlier distance (points' units).
        rng: random generator (samples).
        iterations: RANSAC samples.
        fit_points: the refinement fits at most this many of the best candidate's inliers
            (every k-th; None: all of them).
        compiled_fit: ``compiled`` of that :func:`fit_plane`.

    Returns:
        ``(plane, inliers)`` with (N,) bool inlier mask of the refined plane.
    """
    pts = as_points(points, "fit_plane_ransac: points", min_points=3)
    n = len(pts)
    # Candidates are counted on a subset (the count ranks them just as well).
    probe = pts if n <= 4000 else pts[rng.choice(n, 4000, replace=False)]
    samples = rng.integers(0, n, size=(iterations, 3))
    a, b, c = pts[samples[:, 0]], pts[samples[:, 1]], pts[samples[:, 2]]
    nrm = np.cross(b - a, c - a)  # (I, 3)
    length = np.linalg.norm(nrm, axis=1)
    ok = length > 1e-12
    if not ok.any():
        raise DataError("fit_plane_ransac: points are collinear or coincident")
    nrm = nrm[ok] / length[ok, None]
    off = np.einsum("ij,ij->i", nrm, a[ok])
    # Count inliers of every candidate: compiled, or in chunks to bound memory at (chunk, N)
    # (the first of the most-supported either way)
    best, best_count = 0, -1
    if _gridknn.available():
        best = int(np.argmax(_gridknn.plane_counts(nrm, off, probe, threshold)))
    else:
        for start in range(0, len(nrm), 32):
            d = np.abs(nrm[start : start + 32] @ probe.T - off[start : start + 32, None])
            counts = (d <= threshold).sum(axis=1)
            j = int(np.argmax(counts))
            if counts[j] > best_count:
                best, best_count = start + j, int(counts[j])
    inliers = np.abs(pts @ nrm[best] - off[best]) <= threshold
    if fit_points is not None and np.count_nonzero(inliers) > fit_points:
        at = np.flatnonzero(inliers)
        fit = pts[at[:: -(-len(at) // fit_points)]]
    else:
        fit = np.compress(inliers, pts, axis=0)
    plane = (
        fit_plane(fit, compiled=compiled_fit)
        if inliers.sum() >= 3
        else Plane(nrm[best], float(off[best]))
    )
    inliers = np.abs(plane.distance(pts)) <= threshold
    return plane, inliers


#: Points from which :func:`fit_sphere` refines in one compiled call (when numba imports):
#: a 1,000-point cap's fit 0.8 -> 0.35 ms (the algebraic start's SVD and least squares are
#: the rest); the workstation's curved regions, two a scan, 1.3 ms less in all.
SPHERE_COMPILED_MIN_POINTS = 50


def fit_sphere(points: ArrayLike, *, compiled: bool | None = None) -> SphereFit:
    """Sphere by algebraic least squares, refined geometrically (Levenberg-Marquardt).

    The algebraic fit solves ``|x|^2 = 2 c.x + k`` linearly; the refinement minimises the
    radial residuals ``|x - c| - r``.

    Args:
        points: (N >= 4, 3) points.
        compiled: the refinement in one compiled call
            (:func:`mks_sim.lowlevel._regions_kernels.sphere_lm`: the same steps, the normal
            equations summed in their own order) or by numpy (always without numba); None:
            compiled from :data:`SPHERE_COMPILED_MIN_POINTS` points.

    Returns:
        :class:`SphereFit`.
    """
    pts = as_points(points, "fit_sphere: points", min_points=4)
    sv = np.linalg.svd(pts - column_mean(pts), compute_uv=False)
    if sv[2] <= 1e-9 * sv[0]:
        raise DataError("fit_sphere: points are coplanar and do not determine a sphere")
    A = np.column_stack([2.0 * pts, np.ones(len(pts))])
    b = np.einsum("ij,ij->i", pts, pts)
    sol, *_ = np.linalg.lstsq(A, b, rcond=None)
    center0 = sol[:3]
    r2 = sol[3] + center0 @ center0
    if not np.isfinite(r2) or r2 <= 0:
        raise DataError("fit_sphere: points do not determine a sphere (coplanar or too few)")

    # Levenberg-Marquardt on the radial residuals (4 unknowns: a few 4x4 solves, no scipy
    # driver overhead); starts at the algebraic fit, which is already close.
    x = np.append(center0, np.sqrt(r2))
    if compiled is None:
        compiled = len(pts) >= SPHERE_COMPILED_MIN_POINTS
    if compiled and _gridknn.available():
        from mks_sim.lowlevel._regions_kernels import sphere_lm

        xc, rmse_c = sphere_lm(np.ascontiguousarray(pts, dtype=np.float64), x)
        return SphereFit(center=xc[:3].copy(), radius=abs(float(xc[3])), rmse=float(rmse_c))
    d = pts - x[:3]
    length = row_norms(d)  # (np.linalg.norm(d, axis=1) to the bit, 3x faster)
    res = length - x[3]
    cost = float(res @ res)
    damping = 1e-3
    for _ in range(100):
        J = np.column_stack([-d / np.maximum(length, 1e-300)[:, None], -np.ones(len(pts))])
        JtJ, Jtr = J.T @ J, J.T @ res
        improved = False
        while damping < 1e12:
            step = np.linalg.solve(JtJ + damping * np.diag(np.diag(JtJ) + 1e-300), -Jtr)
            x_new = x + step
            d_new = pts - x_new[:3]
            length_new = row_norms(d_new)
            res_new = length_new - x_new[3]
            cost_new = float(res_new @ res_new)
            if cost_new <= cost:
                improved = True
                break
            damping *= 10.0
        if not improved:
            break
        # scipy's lm stops at relative 1e-8 changes; 1e-10 here
        converged = cost - cost_new <= 1e-10 * max(cost, 1e-300) or np.linalg.norm(
            step
        ) <= 1e-10 * (np.linalg.norm(x) + 1e-12)
        x, d, length, res, cost = x_new, d_new, length_new, res_new, cost_new
        damping = max(damping / 10.0, 1e-12)
        if converged:
            break
    center, radius = x[:3], abs(float(x[3]))
    rmse = float(np.sqrt(np.mean(res**2)))  # res: the radial residuals of the final x
    return SphereFit(center=center, radius=radius, rmse=rmse)


def _rows(adj: sparse.csr_array, frontier: IntArray) -> IntArray:
    starts, ends = adj.indptr[frontier], adj.indptr[frontier + 1]
    lengths = ends - starts
    if lengths.sum() == 0:
        return np.zeros(0, dtype=np.intp)
    pos = np.repeat(starts - np.cumsum(lengths) + lengths, lengths) + np.arange(lengths.sum())
    return np.unique(adj.indices[pos])


def warm_up_kernels() -> bool:
    """Import numba and load (or, on a new machine, compile) the grouping's compiled kernels
    now, so that the first representation of a process does not pay it (~0.35 s of CPU on
    the 2-core machine: numba's import and the cached machine code). Call it where a
    long-lived process sets up (model loading); harmless to call again.

    Returns:
        True when the kernels are usable (numba imports), False when the numpy paths run.
    """
    from mks_sim.lowlevel import _gridknn

    if not _gridknn.available():
        return False
    from mks_sim.lowlevel._regions_kernels import grow_regions, ring_moments

    indptr = np.array([0, 1, 2], dtype=np.int64)
    indices = np.array([1, 0], dtype=np.int64)
    pts = np.array([[0.0, 0.0, 0.0], [1.0, 0.0, 0.0]])
    ring_moments(indptr, indices, pts, 2)
    grow_regions(
        indptr,
        indices,
        pts,
        pts,
        np.ones(2, dtype=np.bool_),
        np.arange(2, dtype=np.int64),
        0.9,
        1.0,
    )
    return True


def _grow(
    adj: sparse.csr_array,
    points: FloatArray,
    normals: FloatArray,
    seeds_allowed: NDArray[np.bool_],
    order: IntArray,
    cos_tol: float,
    distance: float,
    *,
    compiled: bool | None = None,
) -> tuple[IntArray, int]:
    """Region labels in seed order and their count.

    A seed's region takes, level by level (breadth first), the unlabelled neighbours whose
    normal is within ``cos_tol`` of the region's plane normal and which lie within
    ``distance`` of the plane; the plane is refitted each time the region doubles.

    ``compiled``: True runs the numba kernel
    (:func:`mks_sim.lowlevel._regions_kernels.grow_regions`), False the numpy loop below
    (the reference the tests compare the kernel with; same regions), None the kernel from
    ``_COMPILED_MIN_POINTS`` points when numba imports.
    """
    from mks_sim.lowlevel import _gridknn

    if compiled is None:
        compiled = len(points) >= _COMPILED_MIN_POINTS and _gridknn.available()
    if compiled:
        from mks_sim.lowlevel._regions_kernels import grow_regions

        grown, count = grow_regions(
            adj.indptr.astype(np.int64),
            adj.indices.astype(np.int64),
            np.ascontiguousarray(points, dtype=np.float64),
            np.ascontiguousarray(normals, dtype=np.float64),
            np.ascontiguousarray(seeds_allowed, dtype=np.bool_),
            np.asarray(order, dtype=np.int64),
            cos_tol,
            distance,
        )
        return np.asarray(grown, dtype=np.intp), int(count)
    labels = np.full(len(points), -1, dtype=np.intp)
    rid = 0
    for seed in order:
        if labels[seed] != -1 or not seeds_allowed[seed]:
            continue
        labels[seed] = rid
        members = [np.array([seed])]
        size, refit_at = 1, 8
        normal, origin = normals[seed], points[seed]
        frontier = np.array([seed])
        while frontier.size:
            cand = _rows(adj, frontier)
            cand = cand[labels[cand] == -1]
            if cand.size == 0:
                break
            ok = (np.abs(normals[cand] @ normal) >= cos_tol) & (
                np.abs((points[cand] - origin) @ normal) <= distance
            )
            frontier = cand[ok]
            labels[frontier] = rid
            members.append(frontier)
            size += frontier.size
            if size >= refit_at:
                allm = np.concatenate(members)
                pl = fit_plane(points[allm], iterations=1)
                normal, origin = pl.normal, points[allm].mean(axis=0)
                refit_at = 2 * size
        rid += 1
    return labels, rid


def grow_planar_regions(
    points: FloatArray,
    normals: FloatArray,
    graph: GraphLike,
    seeds_allowed: NDArray[np.bool_],
    order: IntArray,
    *,
    angle_deg: float,
    distance: float,
    min_points: int,
    compiled_fit: bool = False,
) -> tuple[IntArray, list[PlanarRegion]]:
    """Grow planar regions over the SPG breadth-first from seeds in ``order``.

    A neighbour joins the region when its normal is within ``angle_deg`` of the region's plane
    normal (sign ignored) and it lies within ``distance`` of the plane; the plane is refitted
    each time the region doubles. Regions smaller than ``min_points`` are dissolved. The
    final planes are :func:`fit_plane`'s (``compiled_fit``: its compiled steps).

    Returns:
        ``(labels, regions)``: (N,) region index or -1, and the regions (largest first).
    """
    adj = symmetric_adjacency(graph)
    n = len(points)
    cos_tol = float(np.cos(np.radians(angle_deg)))
    grown, count = _grow(adj, points, normals, seeds_allowed, order, cos_tol, float(distance))
    sizes = np.bincount(grown[grown >= 0], minlength=count)
    by_region = np.argsort(grown, kind="stable")[n - int(sizes.sum()) :]  # drop the -1s
    starts = np.concatenate([[0], np.cumsum(sizes)])
    # regions largest first (ties in seed order), at least min_points
    big = np.argsort(-sizes, kind="stable")
    big = big[sizes[big] >= min_points]
    members_list = [by_region[starts[r] : starts[r + 1]] for r in big]
    final = np.full(n, -1, dtype=np.intp)
    planes = []
    for rid, members in enumerate(members_list):
        final[members] = rid
        pl = fit_plane(points[members], compiled=compiled_fit)
        planes.append(pl.flipped() if pl.normal @ column_mean(normals[members]) < 0 else pl)
    _absorb_boundary(points, graph, final, planes, distance / 2)
    regions = []
    for rid, pl in enumerate(planes):
        kept = np.flatnonzero(final == rid)
        regions.append(PlanarRegion(kept, pl, column_mean(points[kept])))
    return final, regions


def _absorb_boundary(
    points: FloatArray,
    graph: GraphLike,
    labels: IntArray,
    planes: list[Plane],
    distance: float,
    passes: int = 3,
    *,
    compiled: bool | None = None,
) -> None:
    """Give unlabelled points next to a region to the nearest adjacent plane within
    ``distance`` (points near edges, whose blurred normals kept them out), in place.

    ``compiled``: the numba kernel
    (:func:`mks_sim.lowlevel._regions_kernels.absorb_boundary`: the 4,300 object points of
    scene 2 in 0.4 ms against 4.6) or the numpy passes below (the reference the tests
    compare it with); None: the kernel from ``_COMPILED_MIN_POINTS`` points when numba
    imports."""
    from mks_sim.lowlevel import _gridknn

    if not planes:
        return
    normals = np.stack([p.normal for p in planes])
    offsets = np.array([p.offset for p in planes])
    if compiled is None:
        compiled = len(points) >= _COMPILED_MIN_POINTS and _gridknn.available()
    if compiled:
        from mks_sim.lowlevel._regions_kernels import absorb_boundary

        adj = sparse.csr_array(graph.adjacency)
        lab = np.asarray(labels, dtype=np.int64)
        absorb_boundary(
            adj.indptr.astype(np.int64),
            adj.indices.astype(np.int64),
            np.ascontiguousarray(points, dtype=np.float64),
            lab,
            np.ascontiguousarray(normals, dtype=np.float64),
            np.ascontiguousarray(offsets, dtype=np.float64),
            float(distance),
            int(passes),
        )
        labels[:] = lab
        return
    idx, valid = neighbour_table(graph, include_self=False)
    for _ in range(passes):
        free = np.flatnonzero(labels < 0)
        if free.size == 0:
            return
        nb = labels[idx[free]]  # (F, K) neighbour labels
        nb[~valid[free]] = -1
        has = nb >= 0
        lab = np.where(has, nb, 0)
        # distance of each free point to the plane of each labelled neighbour (inf: none);
        # the nearest, the first neighbour on ties (argmin)
        d = np.abs(np.einsum("fd,fkd->fk", points[free], normals[lab]) - offsets[lab])
        d[~has] = np.inf
        k_best = np.argmin(d, axis=1)
        rows = np.arange(free.size)
        best, choice = d[rows, k_best], nb[rows, k_best]
        take = best <= distance
        if not take.any():
            return
        labels[free[take]] = choice[take]


def segment_surfaces(
    points: ArrayLike,
    graph: GraphLike | None = None,
    *,
    m: int = 12,
    viewpoint: ArrayLike | None = None,
    curvature_threshold: float = DEFAULT_CURVATURE_THRESHOLD,
    angle_deg: float = 12.0,
    distance: float | None = None,
    min_points: int = 20,
    seeds: str = "planar",
    normal_rings: int = 1,
    surface_normals: SurfaceNormals | None = None,
    curved: bool = True,
    curvature_rings: int = 2,
    compiled_fit: bool = False,
) -> Segmentation:
    """Group a cloud on its SPG into planar regions and curved regions (sections 2.2, 4.1).

    Args:
        points: (N, 3) surface points of one object (or a scene).
        graph: the SPG of ``points``; built with ``m`` neighbours when None.
        m: SPG neighbours when the graph is built here.
        viewpoint: (3,) sensor position for normal orientation (see :func:`estimate_normals`).
        curvature_threshold: Surface_Curvature threshold (planar seeds are below it).
        angle_deg: max angle between a point normal and its region's plane normal.
        distance: max point-to-plane distance; default 2 x the median SPG edge length.
        min_points: smallest region kept.
        seeds: ``"planar"``: regions start only at points coded planar (-1), so curved
            surfaces stay curved regions; ``"all"``: any point may seed, flattest first (use
            when noise exceeds ~10% of the sampling spacing and the curvature code marks
            planes curved too).
        normal_rings: SPG rings of the normals' neighbourhoods (2 smooths noisy normals at
            the cost of blurring edges wider).
        surface_normals: normals and curvature of ``points`` already estimated on ``graph``
            (a :class:`~mks_sim.localization.representation.Representation` computes them
            once); ``viewpoint`` and ``normal_rings`` are then unused.
        curved: also group the curved points and fit each group's sphere (False: no curved
            regions; the planar ones do not depend on them).
        curvature_rings: SPG rings of the flatness that orders the seeds
            (:func:`estimate_normals`; equal to ``normal_rings``: no second pass).
        compiled_fit: the regions' planes by the compiled fit (:func:`fit_plane`).

    Returns:
        :class:`Segmentation`.
    """
    pts = as_points(points, "segment_surfaces: points", min_points=4)
    if seeds not in ("planar", "all"):
        raise DataError(f"segment_surfaces: seeds must be 'planar' or 'all', got {seeds!r}")
    if graph is None:
        graph = SpatialProximityGraph(pts, m=m)
    graph = FixedGraph.of(graph)  # the SPG builds its adjacency per access
    if surface_normals is not None and len(surface_normals.normals) == len(pts):
        sn = surface_normals
    else:
        sn = estimate_normals(
            pts, graph, viewpoint=viewpoint, normal_rings=normal_rings,
            curvature_rings=curvature_rings,
        )  # fmt: skip
    codes = curvature_code(sn.curvature, curvature_threshold)
    spacing = median_spacing(graph)
    dist = 2.0 * spacing if distance is None else float(distance)
    order = np.argsort(sn.curvature, kind="stable")
    labels, planes = grow_planar_regions(
        pts,
        sn.normals,
        graph,
        codes < 0 if seeds == "planar" else np.ones(len(pts), dtype=bool),
        order,
        angle_deg=angle_deg,
        distance=dist,
        min_points=min_points,
        compiled_fit=compiled_fit,
    )
    regions = _curved_regions(pts, graph, (codes > 0) & (labels < 0), min_points) if curved else []
    log.debug("segment_surfaces: %d planar, %d curved regions", len(planes), len(regions))
    return Segmentation(
        normals=sn.normals,
        curvature=sn.curvature,
        codes=codes,
        labels=labels,
        planes=tuple(planes),
        curved=tuple(regions),
        spacing=spacing,
    )


def _curved_regions(
    points: FloatArray, graph: GraphLike, mask: NDArray[np.bool_], min_points: int
) -> list[CurvedRegion]:
    idx = np.flatnonzero(mask)
    if idx.size < max(min_points, 4):
        return []
    comp = masked_components(graph.adjacency, mask)[1][idx]
    out: list[CurvedRegion] = []
    for c in np.argsort(-np.bincount(comp)):
        members = idx[comp == c]
        if len(members) < max(min_points, 4):
            break
        try:
            sphere: SphereFit | None = fit_sphere(points[members])
        except DataError:
            sphere = None
        out.append(CurvedRegion(members, sphere))
    return out
