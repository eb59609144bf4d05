"""The low-level representation of one point set, built once and shared (paper section 4).

"The low-level representation is built once per snapshot and every logical sensor and model
queries it": a :class:`Representation` holds, for the points of one stream, the k-d tree, the
spacing and noise estimate, the supporting table plane (the one table finder,
:func:`mks_sim.localization.verify.find_table`), the object points above it, their spatial
proximity graph (SPG) and its components, normals and curvature, and the planar / curved
segmentation. Every piece is computed lazily, at most once.

:func:`representation_of` returns the one representation of a stream's points (keyed on the
stream's read-only data array and the :class:`RepresentationConfig`); the sensing
:class:`~mks_sim.sensing.snapshot.Snapshot` keeps it alive for the snapshot's lifetime
(``snap.representation("Range_Points")``), and the description programs
(``Vertex_Detector``, ``Control_Point_Detector``, ``Sphere_Detector``,
``Surface_Curvature``) and the localization pipeline all take it from there.
"""

from __future__ import annotations

import logging
import weakref
from collections.abc import Sequence
from dataclasses import dataclass
from functools import cached_property
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray
from scipy.spatial import cKDTree

from mks_sim.errors import DataError
from mks_sim.geometry.keypoints import unique_cells
from mks_sim.lowlevel.normals import smallest_eigenvalue

__all__ = [
    "Representation",
    "RepresentationConfig",
    "representation_of",
    "spacing_and_noise",
    "voxel_average",
]

log = logging.getLogger(__name__)
FloatArray = NDArray[np.float64]
IntArray = NDArray[np.intp]

#: Object points from which the SPG is built by the compiled grid kernel (when numba
#: imports), as the normals' and the region growing's kernels (500 points).
_GRID_MIN_POINTS = 500
#: Most point distances (rows x points) the statistics' probes that the column grid left
#: not done are answered with by brute force (:func:`~mks_sim.lowlevel._gridknn.brute_knn`)
#: rather than by a k-d tree of all the points.
_BRUTE_WORK = 5_000_000


@dataclass(frozen=True)
class RepresentationConfig:
    """How a point set is turned into its low-level representation.

    Attributes:
        table_z_m: nominal table height (a sensor calibration parameter): the table plane is
            searched near it; None searches the dominant plane anywhere.
        table_margin_m: object points lie more than this above the table (0: above its
            fitted band, 3 sigma of the table's residuals).
        gap_m: SPG edges longer than this do not join objects (None: 4 x the spacing).
        m: SPG neighbours.
        min_region_points: smallest planar region of the segmentation (a few-millimetre cap
            of a sphere is flat within the region growing's tolerances; 40 points keep it out).
        voxel: ``"auto"`` averages noisy or very dense clouds on a voxel grid (see
            :meth:`Representation.voxel`), a number forces that edge, None never averages.
        max_points: point budget of ``voxel="auto"``.
        max_voxel_spacings: the budget averages only on a voxel edge of at most this many
            spacings (None: any): it thins an evenly sampled scan a little and leaves alone a
            cloud it would thin several-fold.
        viewpoint: (x, y, z) sensor position (orients normals); None: away from each object
            component's centroid.
        compiled: the segmentation's planes by the compiled fit when numba imports
            (``fit_plane(compiled=True)``: the same steps, the sums' and the eigen-solver's
            rounding its own); False: numpy's.
    """

    table_z_m: float | None = None
    table_margin_m: float = 0.0
    gap_m: float | None = None
    m: int = 12
    min_region_points: int = 40
    voxel: float | str | None = "auto"
    max_points: int = 100000
    max_voxel_spacings: float | None = None
    viewpoint: tuple[float, float, float] | None = None
    compiled: bool = True


def _tree(points: FloatArray) -> cKDTree:
    """k-d tree of a point set: sliding-midpoint splits (``balanced_tree=False``), unpacked
    nodes and leaves of 32 build fast and answer the few queries asked of it as fast (the
    workstation's 17,300 voxel points in 1.3 ms against 2.2 with scipy's leaves of 16 and
    packed nodes, 4.0 with median splits; the raw 640 x 480 scan's statistics 42 -> 27 ms)."""
    return cKDTree(points, balanced_tree=False, compact_nodes=False, leafsize=32)


def voxel_average(points: FloatArray, voxel: float, shift: float = 0.0) -> FloatArray:
    """(M, 3) centroids of the points in each occupied cube of edge ``voxel`` (the one voxel
    filter of the package): cells ``floor(p / voxel + shift)``, so ``shift=0.5`` centres
    them on the frame's origin (a plane through it then lies inside one layer of cells,
    not on the border of two)."""
    if len(points) and points.ndim == 2 and points.shape[1] == 3:
        from mks_sim.lowlevel import _gridknn

        if _gridknn.available():  # the same centroids, in one compiled pass
            means = _gridknn.voxel_means(points, voxel, shift)
            if means is not None:
                return means
    return voxel_average_cells(points, voxel, shift)[0]


def voxel_average_cells(
    points: FloatArray, voxel: float, shift: float = 0.0
) -> tuple[FloatArray, NDArray[np.intp]]:
    """:func:`voxel_average` by numpy, with the (N,) row of each point's centroid."""
    cells = np.floor(points / voxel + shift)  # (+ 0.0 leaves every quotient as it is)
    _, inverse, counts = unique_cells(cells.astype(np.int64), first=False)
    out = np.zeros((len(counts), 3))
    for d in range(3):
        out[:, d] = np.bincount(inverse, weights=points[:, d]) / counts
    return out, inverse


def _grid_answers(points: FloatArray) -> bool:
    """The statistics' neighbours of these points come from the compiled column grid
    (:func:`spacing_and_noise` without a tree): 3-D, enough of them, numba importable."""
    if len(points) < _GRID_MIN_POINTS or points.shape[1] != 3:
        return False
    from mks_sim.lowlevel import _gridknn

    return _gridknn.available()


def spacing_and_noise(
    points: FloatArray,
    rng: np.random.Generator,
    tree: cKDTree | None = None,
    probes: int = 1500,
) -> tuple[float, float]:
    """Median nearest-neighbour distance and a noise estimate (median RMS distance of 12
    nearest neighbours from their fitted plane; the planar majority of a scene dominates),
    from ``probes`` random points.

    Without a ``tree``, the probes' neighbours come from the compiled column grid
    (:func:`mks_sim.lowlevel._gridknn.probe_knn`, the same neighbours as a tree's query:
    the workstation's 23,700-point scan in 1.2 ms against 3.5 for a tree's build and query)
    when numba imports; the few rows it leaves (a probe far from the rest) are answered by
    a pass over all the points each (:func:`mks_sim.lowlevel._gridknn.brute_knn`), many by
    a tree; without numba a tree answers them all.
    """
    n = len(points)
    sel = None if n <= probes else rng.choice(n, probes, replace=False)
    probe = points if sel is None else points[sel]
    k = min(12, n)
    compiled = _grid_answers(points)
    if tree is None and compiled:
        from mks_sim.lowlevel import _gridknn

        rows = np.arange(n) if sel is None else sel
        d, idx, done = _gridknn.probe_knn(points, rows, k)
        if not done.all():
            left = np.flatnonzero(~done)
            if len(left) * n <= _BRUTE_WORK:
                # a few far probes: one pass over the points each, not a tree of them all
                # (4 of the 112 localizations of benchmarks/localize.py left one probe:
                # the tree cost them 5-37 ms, the pass well under 1)
                d[left], idx[left] = _gridknn.brute_knn(points, rows[left], k)
            else:
                d[left], idx[left] = _tree(points).query(probe[left], k=k)
    else:
        d, idx = (tree if tree is not None else _tree(points)).query(probe, k=k)
    spacing = float(np.median(d[:, 1])) if k > 1 else 0.0
    # the covariances' upper triangles, and their smallest eigenvalues in closed form
    # (numpy's batched einsum and eigvalsh: 2.7 ms per 800 probes)
    if compiled:
        from mks_sim.lowlevel import _gridknn

        scatter = _gridknn.neighbour_scatter(points, idx)  # (the same sums, compiled)
    else:
        nb = points[idx]  # (P, k, 3)
        c = nb - nb.mean(axis=1, keepdims=True)
        cx, cy, cz = c[..., 0], c[..., 1], c[..., 2]
        upper = [cx * cx, cx * cy, cx * cz, cy * cy, cy * cz, cz * cz]
        scatter = np.stack([u.sum(axis=1) for u in upper], axis=1)
    lam0 = smallest_eigenvalue(scatter / k)[0]
    return spacing, float(np.median(np.sqrt(np.clip(lam0, 0.0, None))))


class Representation:
    """The low-level representation of one point set; every piece lazy and computed once.

    Args:
        points: (N, 3) float points (world frame for the workstation); NaN rows dropped.
        config: how to build it.
        rng: generator for subsampling and RANSAC (default seeded 0: the representation of
            one stream is the same whoever asks first).

    Attributes (lazy):
        raw: the finite input points.
        points: the points the representation is built on (``raw`` voxel-averaged when
            :attr:`voxel` > 0).
        tree, spacing, noise, voxel, table, table_threshold, object_indices, objects,
        objects_tree, graph, spg_adjacency, labels, normals, segmentation; at the sensor's
        own resolution: raw_rows, raw_objects, raw_curvature (and ``raw_of``).
    """

    def __init__(
        self,
        points: ArrayLike,
        config: RepresentationConfig | None = None,
        *,
        rng: np.random.Generator | None = None,
    ) -> None:
        raw = np.asarray(points, dtype=np.float64)
        if raw.ndim != 2 or raw.shape[1] < 3:
            raise DataError(f"Representation: expected (N, 3) points, got shape {raw.shape}")
        raw = raw[:, :3]
        # (per column: an (N, 3) all over axis 1 is several times slower)
        finite = np.isfinite(raw[:, 0]) & np.isfinite(raw[:, 1]) & np.isfinite(raw[:, 2])
        self.raw: FloatArray = np.compress(finite, raw, axis=0)
        if len(self.raw) < 10:
            raise DataError(
                f"Representation: expected at least 10 finite points, got {len(self.raw)}"
            )
        self.config = config if config is not None else RepresentationConfig()
        self._rng = np.random.default_rng(0) if rng is None else rng
        self._cache: dict[Any, Any] = {}

    # ------------------------------------------------------------------ sampling

    @cached_property
    def _raw_tree(self) -> cKDTree:
        # the tree of the points when they are not averaged
        return _tree(self.raw)

    @cached_property
    def _raw_stats(self) -> tuple[float, float]:
        # the statistics that set the voxel: without a tree when the compiled grid answers
        # the probes, else on the raw points' tree (then also :attr:`tree` when not averaged)
        tree = None if _grid_answers(self.raw) else self._raw_tree
        return spacing_and_noise(self.raw, self._rng, tree, probes=800)

    @cached_property
    def voxel(self) -> float:
        """Voxel edge the points were averaged on (0: not averaged).

        ``"auto"``: noise above 0.2 x the spacing defeats PCA normals over one SPG ring, so
        the cloud is averaged at max(spacing, 3 sigma); a cloud over ``max_points`` is
        averaged on an edge of 1.1 x spacing x sqrt(N / max_points), unless that edge is
        over ``max_voxel_spacings`` spacings (the workstation's 8000 and 2.5: the range
        finder's 23.7k-point scan is averaged at 1.9 spacings, a 4.1 mm grid; the stereo
        pair's 58k points, already thinned on a 2 mm grid, would be at 3.0 and are left as
        they are: averaged at 2.1 spacings, the stereo cube was found in 166 of 170 tuning
        seeds against 169).
        """
        v = self.config.voxel
        if v is None:
            return 0.0
        if not isinstance(v, str):
            return float(v)
        spacing, noise = self._raw_stats
        size = 0.0
        if noise > 0.2 * spacing:
            size = max(spacing, 3.0 * noise)
        if len(self.raw) > self.config.max_points:
            budget = 1.1 * spacing * np.sqrt(len(self.raw) / self.config.max_points)
            cap = self.config.max_voxel_spacings
            if cap is None or budget <= cap * spacing:
                size = max(size, budget)
        return float(size)

    @cached_property
    def points(self) -> FloatArray:
        """(M, 3) the points the representation is built on."""
        if self.voxel > 0:
            return voxel_average(self.raw, self.voxel)
        return self.raw

    @cached_property
    def raw_rows(self) -> IntArray:
        """(N_raw,) the row of :attr:`points` each raw point was averaged into (the
        identity when not averaged): :func:`voxel_average_cells`' cells are
        :func:`voxel_average`'s, in the same lexicographic order."""
        if self.voxel == 0:
            return np.arange(len(self.raw))
        return voxel_average_cells(self.raw, self.voxel)[1]

    def raw_of(self, indices: IntArray) -> FloatArray:
        """The raw points averaged into the object points ``indices`` (into :attr:`objects`):
        a region at the sensor's own resolution, whatever the budget averaged it to."""
        if self.voxel == 0:
            return self.objects[indices]
        rows = np.zeros(len(self.points), dtype=bool)
        rows[self.object_indices[indices]] = True
        return self.raw[rows[self.raw_rows]]

    @cached_property
    def raw_objects(self) -> FloatArray:
        """(K_raw, 3) the raw points averaged into :attr:`objects` (all of them when not
        averaged)."""
        return self.raw_of(np.arange(len(self.objects)))

    @cached_property
    def raw_curvature(self) -> FloatArray:
        """(K_raw,) surface variation of :attr:`raw_objects` over two rings of their own SPG
        (edges up to :attr:`gap` and never between objects, as :attr:`normals`' graph): the
        curvature at the sensor's resolution, which a coarse averaging budget would blur
        (two rings of coarse cells reach a face's edges from far inside it)."""
        from scipy import sparse

        from mks_sim.lowlevel import _gridknn
        from mks_sim.lowlevel._gridknn import masked_components, same_label_entries
        from mks_sim.lowlevel.normals import FixedGraph, estimate_normals
        from mks_sim.lowlevel.spg import SpatialProximityGraph

        if self.voxel == 0:
            return np.asarray(self.normals.curvature)
        pts = self.raw_objects
        if len(pts) < 3:
            return np.zeros(len(pts))
        # the SPG as :attr:`spg_adjacency` and :attr:`_adjacency` build it, on the raw points
        grid = len(pts) >= _GRID_MIN_POINTS and _gridknn.available()
        spg = SpatialProximityGraph(pts, m=self.config.m, method="grid" if grid else "tree")
        adj = sparse.csr_array(spg.adjacency)
        nnz = int(adj.indptr[-1])
        adj = sparse.csr_array((adj.data[:nnz], adj.indices[:nnz], adj.indptr), shape=adj.shape)
        labels = masked_components(adj, limit=self.gap)[1]
        graph = FixedGraph(same_label_entries(adj, labels))
        return np.asarray(estimate_normals(pts, graph, curvature_rings=2).curvature)

    @property
    def raw_spacing(self) -> float:
        """Median nearest-neighbour distance of the raw points."""
        return self._raw_stats[0]

    @cached_property
    def tree(self) -> cKDTree:
        """k-d tree of :attr:`points` (the verification's; the statistics, the table and the
        grouping do without it)."""
        return self._raw_tree if self.voxel == 0 else _tree(self.points)

    @cached_property
    def _stats(self) -> tuple[float, float]:
        if self.voxel == 0:
            return self._raw_stats
        # without numba on the representation's own tree, built once for the verification too
        tree = None if _grid_answers(self.points) else self.tree
        return spacing_and_noise(self.points, self._rng, tree, probes=800)

    @property
    def spacing(self) -> float:
        """Median nearest-neighbour distance of :attr:`points`."""
        return self._stats[0]

    @property
    def noise(self) -> float:
        """Noise sigma estimate of :attr:`points`."""
        return self._stats[1]

    @property
    def noisy(self) -> bool:
        """Noise comparable to the spacing (two-ring normals)."""
        return self.noise > 0.2 * self.spacing

    # ------------------------------------------------------------------ table and objects

    @cached_property
    def _table(self) -> tuple[Any, float, NDArray[np.bool_]]:
        from mks_sim.localization.verify import find_table

        vp = self.config.viewpoint
        return find_table(
            self.points,
            self._rng,
            spacing=self.spacing,
            noise=self.noise,
            near_z=self.config.table_z_m,
            viewpoint=None if vp is None else np.asarray(vp, dtype=np.float64),
        )

    @property
    def table(self) -> Any:
        """The supporting plane (:class:`~mks_sim.lowlevel.regions.Plane`, normal towards
        the objects) or None."""
        return self._table[0]

    @property
    def table_threshold(self) -> float:
        """Distance above the table below which a point counts as table."""
        return self._table[1]

    @cached_property
    def object_indices(self) -> IntArray:
        """Indices (into :attr:`points`) of the points off the table, on its object side."""
        table, thr, band = self._table
        keep = np.flatnonzero(~band)
        if table is not None:
            margin = self.config.table_margin_m
            keep = np.flatnonzero(table.distance(self.points) > (margin if margin > 0 else thr))
        return keep

    @cached_property
    def objects(self) -> FloatArray:
        """(K, 3) the object points (off the table)."""
        return self.points[self.object_indices]

    @cached_property
    def objects_tree(self) -> cKDTree:
        """k-d tree of :attr:`objects` (scipy's default build: the sphere fits' and the
        coverage tests' tree, built once for both)."""
        return cKDTree(self.objects)

    @cached_property
    def gap(self) -> float:
        """SPG edge limit joining object points."""
        g = self.config.gap_m
        return float(g) if g is not None else 4.0 * self.spacing

    @cached_property
    def graph(self) -> Any:
        """SPG of :attr:`objects` (``m`` nearest neighbours).

        Built by the compiled grid kernel when numba imports and the objects have at least
        ``_GRID_MIN_POINTS`` points (the grouping's other kernels are then in use too): the
        workstation's 4,300 object points in 4 ms against 17 by the tree; the same graph
        (the SPG's tests check both methods against brute force)."""
        from mks_sim.lowlevel import _gridknn
        from mks_sim.lowlevel.spg import SpatialProximityGraph

        grid = len(self.objects) >= _GRID_MIN_POINTS and _gridknn.available()
        return SpatialProximityGraph(
            self.objects, m=self.config.m, method="grid" if grid else "tree"
        )

    @cached_property
    def spg_adjacency(self) -> Any:
        """The SPG's CSR adjacency, edge lengths as values (the SPG builds it per access:
        once here; the grouping and the object segments read it)."""
        from scipy import sparse

        adj = sparse.csr_array(self.graph.adjacency)
        nnz = int(adj.indptr[-1])  # the SPG's arrays may hold spare room past the last row
        return sparse.csr_array((adj.data[:nnz], adj.indices[:nnz], adj.indptr), shape=adj.shape)

    @cached_property
    def labels(self) -> IntArray:
        """(K,) object (SPG component over edges <= :attr:`gap`) of each object point."""
        from mks_sim.lowlevel._gridknn import masked_components

        if len(self.objects) == 0:
            return np.zeros(0, dtype=np.intp)
        return masked_components(self.spg_adjacency, limit=self.gap)[1]

    @cached_property
    def _adjacency(self) -> Any:
        """The SPG without the edges between objects (the neighbourhoods of grouping), as a
        :class:`~mks_sim.lowlevel.normals.FixedGraph` (its symmetric closure computed once
        for the normals and the region growing)."""
        from mks_sim.lowlevel._gridknn import same_label_entries
        from mks_sim.lowlevel.normals import FixedGraph

        return FixedGraph(same_label_entries(self.spg_adjacency, self.labels))

    def components(self, min_points: int = 30) -> list[IntArray]:
        """Object-point indices of each SPG component with at least ``min_points``, largest
        first."""
        key = ("components", min_points)
        if key not in self._cache:
            counts = np.bincount(self.labels) if len(self.labels) else np.zeros(0, np.intp)
            order = np.argsort(-counts, kind="stable")
            self._cache[key] = [
                np.flatnonzero(self.labels == c) for c in order if counts[c] >= min_points
            ]
        out: list[IntArray] = self._cache[key]
        return out

    # ------------------------------------------------------------------ grouping

    @cached_property
    def normals(self) -> Any:
        """:class:`~mks_sim.lowlevel.normals.SurfaceNormals` of :attr:`objects` (two-ring
        normals when the cloud is noisy), oriented towards the viewpoint or away from each
        component's centroid."""
        from mks_sim.lowlevel.normals import SurfaceNormals, estimate_normals

        pts = self.objects
        if len(pts) < 3:
            return SurfaceNormals(np.zeros((len(pts), 3)), np.zeros(len(pts)))
        vp = self.config.viewpoint
        sn = estimate_normals(
            pts,
            self._adjacency,
            viewpoint=vp,
            normal_rings=2 if self.noisy else 1,
            curvature_rings=2,
        )
        if vp is None:  # away from each component's centroid (one convex object each)
            lab = self.labels
            n_comp = int(lab.max()) + 1 if len(lab) else 0
            counts = np.bincount(lab, minlength=n_comp).astype(np.float64)
            centre = (
                np.stack(
                    [np.bincount(lab, weights=pts[:, d], minlength=n_comp) for d in range(3)], 1
                )
                / np.maximum(counts, 1.0)[:, None]
            )
            nrm = sn.normals.copy()
            flip = np.einsum("ni,ni->n", nrm, pts - centre[lab]) < 0
            nrm[flip] *= -1.0
            sn = SurfaceNormals(nrm, sn.curvature)
        return sn

    @property
    def seeds(self) -> str:
        """Region-growing seeds: ``"planar"`` (curved surfaces stay curved regions) unless the
        noise exceeds 15 % of the spacing: then plane interiors are coded curved as often as
        a sphere's points (stereo: median surface variation 0.009 on cube faces, 0.011 on the
        sphere) and every point may seed (``"all"``)."""
        return "all" if self.noise > 0.15 * self.spacing else "planar"

    @cached_property
    def segmentation(self) -> Any:
        """:class:`~mks_sim.lowlevel.regions.Segmentation` of :attr:`objects`: planar
        regions (never across components) and curved regions with sphere fits."""
        from mks_sim.lowlevel.regions import segment_surfaces

        return segment_surfaces(
            self.objects,
            self._adjacency,
            surface_normals=self.normals,
            seeds=self.seeds,
            min_points=self.config.min_region_points,
            compiled_fit=self.config.compiled,
        )

    def planes_of(self, component: IntArray, min_points: int = 20) -> list[Any]:
        """Planar regions inside one component (indices into :attr:`objects`)."""
        lab = self.labels
        comp = int(lab[component[0]]) if len(component) else -1
        return [
            r
            for r in self.segmentation.planes
            if len(r.indices) >= min_points and int(lab[r.indices[0]]) == comp
        ]

    def vertexes_of(
        self, component: IntArray, *, min_points: int = 20, min_angle_deg: float = 30.0
    ) -> Any:
        """:class:`~mks_sim.lowlevel.vertexes.Vertexes` of one component: triples of its
        planes and the table (as the face the object rests on, when it touches it); face
        indices >= the number of planes refer to the table. Cached."""
        key = ("vertexes", int(component[0]) if len(component) else -1, min_points, min_angle_deg)
        if key not in self._cache:
            planes = self.planes_of(component, min_points)
            on_table = self.touches_table(self.objects[component]) if len(component) else False
            self._cache[key] = (
                self.plane_vertexes(planes, on_table, min_angle_deg=min_angle_deg),
                planes,
            )
        return self._cache[key]

    def touches_table(self, points: FloatArray) -> bool:
        """Some of ``points`` lie within the table band plus 4 spacings of the table (an
        object resting on it)."""
        table = self.table
        if table is None or len(points) == 0:
            return False
        touch = float(np.min(table.distance(points)))
        return touch <= self.table_threshold + 4.0 * self.spacing

    def plane_vertexes(
        self, planes: Sequence[Any], on_table: bool, *, min_angle_deg: float = 30.0
    ) -> Any:
        """:func:`~mks_sim.lowlevel.vertexes.plane_vertexes` of some of
        :attr:`segmentation`'s planes (indices into :attr:`objects`), with the table as the
        face the object rests on when ``on_table``; the tolerance 4 spacings. Cached on the
        planes: a component and the object segment that is the same points (the
        ``Vertex_Detector`` and the polyhedral candidates) intersect their faces once."""
        table = self.table if on_table else None
        key = ("plane_vertexes", tuple(id(r) for r in planes), table is not None, min_angle_deg)
        hit = self._cache.get(key)
        if hit is None or any(a is not b for a, b in zip(hit[1], planes, strict=True)):
            from mks_sim.lowlevel.vertexes import plane_vertexes

            tol = 4.0 * max(self.spacing, self.segmentation.spacing, 1e-4)
            hit = (
                plane_vertexes(
                    planes,
                    self.objects,
                    extra_planes=[table.flipped()] if table is not None else [],
                    tolerance=tol,
                    min_angle_deg=min_angle_deg,
                ),
                tuple(planes),
            )
            self._cache[key] = hit
        return hit[0]


_REGISTRY: dict[tuple[int, RepresentationConfig], tuple[Any, Representation]] = {}


def representation_of(
    stream_or_points: Any, config: RepresentationConfig | None = None
) -> Representation:
    """The one representation of a stream's points (or of an array) for ``config``.

    Keyed on the identity of the read-only data array (a stream's data never changes), so
    the snapshot, the description programs and the matchers share it while the data lives.
    """
    if isinstance(stream_or_points, np.ndarray):
        arr = stream_or_points
    else:
        arr = np.asarray(getattr(stream_or_points, "data", stream_or_points))
    cfg = config if config is not None else RepresentationConfig()
    key = (id(arr), cfg)
    hit = _REGISTRY.get(key)
    if hit is not None and hit[0]() is arr:
        return hit[1]
    rep = Representation(arr, cfg)

    def _forget(
        _ref: Any, k: tuple[int, RepresentationConfig] = key, reg: dict = _REGISTRY
    ) -> None:
        reg.pop(k, None)  # the registry bound at definition: None at interpreter exit

    try:
        ref = weakref.ref(arr, _forget)
    except TypeError:  # not weak-referenceable: no sharing
        return rep
    _REGISTRY[key] = (ref, rep)
    return rep
