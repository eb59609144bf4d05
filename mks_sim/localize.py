"""Localize a model in a 3-D point cloud: the simulator-free pipeline (paper sections 2.2, 4).

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

import functools
import itertools
import logging
import time
from collections.abc import Sequence
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import TYPE_CHECKING, Any, Literal, Protocol, runtime_checkable

import numpy as np
from numpy.typing import ArrayLike, NDArray
from scipy.spatial import ConvexHull, QhullError, cKDTree

from mks_sim.errors import DataError, MksError, NotFound
from mks_sim.geometry.transforms import cube_rotations
from mks_sim.io.units import check_scale
from mks_sim.localization.hypotheses import (
    _frame,
    plane_pair_hypotheses,
    vertex_hypotheses,
)
from mks_sim.localization.representation import spacing_and_noise, voxel_average
from mks_sim.localization.verify import find_table
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
    detect_symmetries,
    verify_hypotheses,
)

if TYPE_CHECKING:
    from mks_sim.geometry.meshes import Mesh

__all__ = [
    "LocalizableModel",
    "Localization",
    "PolyhedralModel",
    "SegmentReport",
    "load_model",
    "localize_cloud",
    "plane_pair_hypotheses",
    "vertex_hypotheses",
]

log = logging.getLogger(__name__)
FloatArray = NDArray[np.float64]

#: Part of a model's surface one view is assumed to show at least (a cube seen obliquely
#: shows ~1/2, the industrial part from above ~1/3); a hypothesis under which fewer of the
#: model's surface samples than this share have a scene point nearby has its score scaled down.
VISIBLE_FRACTION = 0.2


@runtime_checkable
class LocalizableModel(Protocol):
    """What :func:`localize_cloud` needs from a model."""

    @property
    def name(self) -> str:
        """The model's name (for logs and reports)."""
        ...

    def hypotheses(
        self, scene_points: np.ndarray, scene_normals: np.ndarray | None
    ) -> list[PoseHypothesis]:
        """Candidate poses of the model in one scene segment.

        Args:
            scene_points: (N, 3) float, metres (or the model's unit), scene frame; one object
                segment (the table plane already removed).
            scene_normals: (N, 3) float unit normals oriented towards the sensor, or None.

        Returns:
            Hypotheses (``matrix`` is model -> scene, 4x4 column convention) in any order;
            ``votes`` filled, ``score`` may be nan (the pipeline verifies them).
        """
        ...

    def surface_points(self) -> np.ndarray:
        """(M, 3) float points sampled on the model surface, model frame (for ICP/scoring)."""
        ...

    def surface_normals(self) -> np.ndarray:
        """(M, 3) float outward unit normals matching :meth:`surface_points`."""
        ...

    def symmetries(self) -> np.ndarray | None:
        """(S, 3, 3) rotations about the model origin that map the model onto itself, or None.

        Hypotheses that differ by one of these are reported once (equivalents listed).
        """
        ...


# --------------------------------------------------------------------------- the model


@dataclass(frozen=True, eq=False)
class Corner:
    """A model vertex where three or more planar faces meet.

    Attributes:
        point: (3,) position, model frame.
        normals: (k >= 3, 3) outward unit normals of the faces meeting there.
    """

    point: FloatArray
    normals: FloatArray


@dataclass(frozen=True, eq=False)
class ModelFace:
    """A large planar face of the model: ``normal . x = offset`` and its surface samples."""

    normal: FloatArray
    offset: float
    points: FloatArray

    @functools.cached_property
    def extremes(self) -> FloatArray:
        """(E, 3) the samples on the convex hull of the face (in its plane): the extent of
        the face along any direction (ptp of the projections) is the extent of these."""
        pts = np.asarray(self.points, dtype=np.float64)
        if len(pts) < 4:
            return pts
        n = np.asarray(self.normal, dtype=np.float64)
        u = np.cross(n, [1.0, 0.0, 0.0] if abs(n[0]) < 0.9 else [0.0, 1.0, 0.0])
        u /= np.linalg.norm(u)
        try:
            hull = ConvexHull(np.c_[pts @ u, pts @ np.cross(n, u)])
        except QhullError:  # degenerate (collinear) samples: keep them all
            return pts
        return pts[hull.vertices]


@dataclass(frozen=True, eq=False)
class PolyhedralModel:
    """A model localized by its vertexes (the paper's first approach, section 4.2).

    Attributes:
        name: model name.
        corners: the model's vertexes with their face normals.
        points: (M, 3) surface samples, model frame.
        normals: (M, 3) outward unit normals of ``points``.
        symmetry_rotations: (S, 3, 3) rotations about the origin mapping the model onto
            itself (found among the cube's 24 rotations from the vertexes).
        faces: the large planar faces (for plane-pair hypotheses when too few vertexes
            are visible).
    """

    name: str
    corners: tuple[Corner, ...]
    points: FloatArray
    normals: FloatArray
    symmetry_rotations: FloatArray
    faces: tuple[ModelFace, ...]
    _surface: ModelSurface = field(repr=False)
    _face_pairs: tuple[NDArray[np.intp], NDArray[np.intp], FloatArray, FloatArray] = field(
        repr=False
    )

    # ---- construction

    @classmethod
    def from_mesh(
        cls,
        mesh: Mesh,
        name: str = "mesh",
        *,
        n_surface: int = 4000,
        min_face_fraction: float = 0.004,
        rng: np.random.Generator | None = None,
    ) -> PolyhedralModel:
        """Model from a triangle mesh: corners where >= 3 large planar faces meet.

        Args:
            mesh: the model mesh (model frame).
            name: model name.
            n_surface: surface samples for ICP.
            min_face_fraction: a planar face counts when its area is at least this fraction of
                the mesh area (keeps the facets of tessellated curved surfaces out).
            rng: generator for the samples (default seeded 0).
        """
        from mks_sim.geometry.meshes import sample_surface

        rng = np.random.default_rng(0) if rng is None else rng
        planes, corners = _mesh_corners(mesh, min_face_fraction)
        if not corners:
            raise DataError(
                f"model {name!r}: the mesh has no vertex where three planar faces meet; "
                "a polyhedral model needs corners"
            )
        points, normals = sample_surface(mesh, n_surface, rng=rng)
        size = float(np.linalg.norm(np.ptp(points, axis=0)))
        faces = []
        for n, o in planes:
            on = (np.abs(points @ n - o) < 1e-4 * size) & (normals @ n > 0.99)
            if on.sum() >= 3:
                faces.append(ModelFace(n, float(o), points[on]))
        return cls._build(name, corners, points, normals, faces)

    @classmethod
    def from_vertexes(cls, vertexes: ArrayLike, name: str = "vertexes") -> PolyhedralModel:
        """Model of the convex polyhedron with these vertexes (e.g. the paper's cube model)."""
        from mks_sim.geometry.meshes import Mesh

        v = np.asarray(vertexes, dtype=np.float64)
        if v.ndim != 2 or v.shape[1] != 3 or len(v) < 4:
            raise DataError(f"model {name!r}: expected (V >= 4, 3) vertexes, got {v.shape}")
        hull = ConvexHull(v)
        faces = hull.simplices.copy()
        centre = v.mean(axis=0)
        for f in faces:  # orient counter-clockwise seen from outside
            n = np.cross(v[f[1]] - v[f[0]], v[f[2]] - v[f[0]])
            if n @ (v[f[0]] - centre) < 0:
                f[[1, 2]] = f[[2, 1]]
        return cls.from_mesh(Mesh(v, faces), name)

    @classmethod
    def from_points(
        cls,
        points: ArrayLike,
        name: str = "points",
        normals: ArrayLike | None = None,
        *,
        m: int = 12,
    ) -> PolyhedralModel:
        """Model from a sampled surface (a point file): grouping finds faces and vertexes.

        Args:
            points: (M, 3) points on the whole model surface.
            name: model name.
            normals: (M, 3) outward normals if known (else estimated, pointing away from the
                centroid).
            m: SPG neighbours for the grouping.
        """
        pts = np.asarray(points, dtype=np.float64)
        graph = build_graph(pts, m=m)
        seg = segment_surfaces(pts, graph, seeds="all")
        verts = plane_vertexes(seg.planes, pts, tolerance=5 * seg.spacing)
        if len(verts) == 0:
            raise DataError(f"model {name!r}: no vertexes found by grouping the model points")
        corners = [Corner(p, n) for p, n in zip(verts.points, verts.normals)]
        nrm = seg.normals if normals is None else np.asarray(normals, dtype=np.float64)
        faces = [ModelFace(r.normal, r.plane.offset, pts[r.indices]) for r in seg.planes]
        return cls._build(name, corners, pts, nrm, faces)

    @classmethod
    def _build(
        cls,
        name: str,
        corners: list[Corner],
        points: FloatArray,
        normals: FloatArray,
        faces: list[ModelFace],
    ) -> PolyhedralModel:
        surface = ModelSurface.from_arrays(points, normals)
        cpts = np.stack([c.point for c in corners])
        syms = detect_symmetries(cpts, cube_rotations(), 1e-3 * surface.size)
        pairs = [
            (a, b)
            for a, b in itertools.permutations(range(len(faces)), 2)
            if abs(float(faces[a].normal @ faces[b].normal)) <= 0.95
        ]
        pa = np.array([a for a, _ in pairs], dtype=np.intp)
        pb = np.array([b for _, b in pairs], dtype=np.intp)
        pcos = np.array([faces[a].normal @ faces[b].normal for a, b in pairs])
        frames = np.array([_frame(faces[a].normal, faces[b].normal) for a, b in pairs])
        return cls(
            name,
            tuple(corners),
            surface.points,
            surface.normals,
            syms,
            tuple(faces),
            surface,
            (pa, pb, pcos.reshape(-1), frames.reshape(-1, 3, 3)),
        )

    def scaled(self, factor: float) -> PolyhedralModel:
        """The same model with coordinates multiplied by ``factor`` (unit change)."""
        if not factor > 0:
            raise DataError(f"model {self.name!r}: scale must be > 0, got {factor}")
        corners = [Corner(c.point * factor, c.normals) for c in self.corners]
        faces = [ModelFace(f.normal, f.offset * factor, f.points * factor) for f in self.faces]
        return self._build(self.name, corners, self.points * factor, self.normals, faces)

    # ---- LocalizableModel

    @property
    def vertexes(self) -> FloatArray:
        """(V, 3) the corner positions."""
        return np.stack([c.point for c in self.corners])

    @property
    def corner_triples(self) -> tuple[FloatArray, FloatArray]:
        """Every corner with every ordered triple of its face normals: (K, 3) corner
        positions and (K, 3, 3) normals (rows)."""
        pts, nrm = [], []
        for c in self.corners:
            for perm in itertools.permutations(range(len(c.normals)), 3):
                pts.append(c.point)
                nrm.append(c.normals[list(perm)])
        return np.array(pts).reshape(-1, 3), np.array(nrm).reshape(-1, 3, 3)

    @functools.cached_property
    def face_extremes(self) -> tuple[FloatArray, FloatArray]:
        """(F, E, 3) every face's hull samples (:attr:`ModelFace.extremes`, padded by
        repeating the last) and (F,) the face offsets: face extents in arrays."""
        ex = [f.extremes for f in self.faces]
        width = max((len(e) for e in ex), default=1)
        out = np.zeros((len(ex), width, 3))
        for i, e in enumerate(ex):
            out[i, : len(e)] = e
            out[i, len(e) :] = e[-1]
        return out, np.array([f.offset for f in self.faces], dtype=np.float64)

    @property
    def face_pairs(self) -> tuple[NDArray[np.intp], NDArray[np.intp], FloatArray, FloatArray]:
        """Ordered pairs of non-parallel faces: (K,) first and second face indices, (K,)
        cosines of their normals and (K, 3, 3) frames (see :func:`_frame`)."""
        return self._face_pairs

    @property
    def surface(self) -> ModelSurface:
        return self._surface

    def surface_points(self) -> np.ndarray:
        return self.points

    def surface_normals(self) -> np.ndarray:
        return self.normals

    def symmetries(self) -> np.ndarray | None:
        return self.symmetry_rotations if len(self.symmetry_rotations) else None

    def hypotheses(
        self, scene_points: np.ndarray, scene_normals: np.ndarray | None = None
    ) -> list[PoseHypothesis]:
        """Group the segment (no table known) and match vertexes; see :func:`vertex_hypotheses`."""
        del scene_normals
        pts = np.asarray(scene_points, dtype=np.float64)
        graph = build_graph(pts, m=12)
        seg = segment_surfaces(pts, graph, seeds="all")
        verts = plane_vertexes(seg.planes, pts, tolerance=4 * seg.spacing)
        return vertex_hypotheses(self, verts, pts, vote_distance=4 * seg.spacing)


def _mesh_corners(
    mesh: Mesh, min_face_fraction: float
) -> tuple[list[tuple[FloatArray, float]], list[Corner]]:
    """The mesh's large planes ((normal, offset) pairs) and its corners."""
    v, f = mesh.vertices, mesh.faces
    tri = v[f]
    cross = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
    area2 = np.linalg.norm(cross, axis=1)
    good = area2 > 1e-18
    n = np.zeros_like(cross)
    n[good] = cross[good] / area2[good, None]
    size = float(np.linalg.norm(np.ptp(v, axis=0)))
    # Group triangles into planes by quantised (normal, offset).
    key = np.column_stack([np.round(n * 1e3), np.round((n * tri[:, 0]).sum(1) / size * 1e3)])
    _, plane_of, inverse_counts = np.unique(key, axis=0, return_inverse=True, return_counts=True)
    plane_of = plane_of.reshape(-1)
    plane_area = np.bincount(plane_of, weights=area2 / 2)
    big = plane_area >= min_face_fraction * (area2.sum() / 2)
    plane_normal = np.zeros((len(plane_area), 3))
    np.add.at(plane_normal, plane_of, n * area2[:, None])
    plane_normal /= np.clip(np.linalg.norm(plane_normal, axis=1, keepdims=True), 1e-12, None)
    plane_offset = np.zeros(len(plane_area))
    np.add.at(plane_offset, plane_of, (n * tri[:, 0]).sum(1) * area2)
    plane_offset /= np.clip(np.bincount(plane_of, weights=area2), 1e-18, None)
    incident: list[set[int]] = [set() for _ in range(len(v))]
    for t, pl in enumerate(plane_of):
        if good[t] and big[pl]:
            for vi in f[t]:
                incident[vi].add(int(pl))
    corners: list[Corner] = []
    seen: list[FloatArray] = []
    for vi, planes in enumerate(incident):
        if len(planes) < 3:
            continue
        N = plane_normal[sorted(planes)]
        if np.linalg.matrix_rank(N, tol=0.3) < 3:
            continue
        if any(np.linalg.norm(v[vi] - s) < 1e-9 * size for s in seen):
            continue
        seen.append(v[vi])
        corners.append(Corner(v[vi].copy(), N))
    del inverse_counts
    big_planes = [(plane_normal[i], float(plane_offset[i])) for i in np.flatnonzero(big)]
    return big_planes, corners


# --------------------------------------------------------------------------- the pipeline


@dataclass(frozen=True, eq=False)
class SegmentReport:
    """What grouping found in one object segment.

    Attributes:
        indices: (n,) indices of the segment's points in the NaN-free scene (in the
            voxel-averaged scene when :attr:`Localization.voxel` > 0).
        planes: planar regions (indices into the segment).
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

    @property
    def best(self) -> PoseHypothesis | None:
        """The best hypothesis, or None."""
        return self.hypotheses[0] if self.hypotheses else None


def _spacing_and_noise(points: FloatArray, rng: np.random.Generator) -> tuple[float, float]:
    """Median nearest-neighbour distance and noise sigma (``representation.spacing_and_noise``)."""
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


def localize_cloud(
    model: Any,
    scene_points: ArrayLike,
    *,
    scale: float = 1.0,
    viewpoint: ArrayLike | None = None,
    table: Literal["auto", "none"] | Plane = "auto",
    voxel: float | Literal["auto"] | None = "auto",
    max_points: int = 30000,
    m: int = 12,
    min_segment_points: int = 60,
    min_score: float = 0.5,
    max_hypotheses: int = 10,
    max_icp: int = 8,
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
        max_points: point budget of ``voxel="auto"``.
        m: SPG neighbours.
        min_segment_points: smaller SPG components are ignored.
        min_score: ``found`` needs the best score at least this.
        max_hypotheses: report at most this many distinct hypotheses.
        max_icp: ICP-refine at most this many distinct candidates per segment.
        rng: generator (RANSAC, subsampling); default seeded 0.

    Returns:
        :class:`Localization`.

    Raises:
        DataError: malformed points (wrong shape, fewer than 10 finite points) or model.
        NotFound: a model name or file that does not exist.
    """
    t0 = time.perf_counter()
    timing: dict[str, float] = {}
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
    finite = np.all(np.isfinite(raw), axis=1)
    dropped = int((~finite).sum())
    if dropped:
        log.warning("localize_cloud: dropped %d NaN/inf scene points of %d", dropped, len(raw))
    pts = raw[finite]
    if len(pts) < 10:
        raise DataError(f"localize_cloud: expected at least 10 finite scene points, got {len(pts)}")
    vp = None if viewpoint is None else np.asarray(viewpoint, dtype=np.float64).reshape(3)
    # Extent is linear in scale: the unscaled model's points times `scale` are loc_model's.
    size_warning = check_scale(loc_model.surface_points() / scale, pts, scale)

    t = time.perf_counter()
    spacing, noise = _spacing_and_noise(pts, rng)
    voxel_size = 0.0
    raw = pts
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
            pts = voxel_average(raw, voxel_size)
            spacing, noise = _spacing_and_noise(pts, rng)
    elif voxel is not None:
        voxel_size = float(voxel)
        pts = voxel_average(raw, voxel_size)
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
    timing["table"] = time.perf_counter() - t

    surface = (
        loc_model.surface
        if isinstance(loc_model, PolyhedralModel)
        else ModelSurface.from_arrays(loc_model.surface_points(), loc_model.surface_normals())
    )
    t = time.perf_counter()
    segments: list[SegmentReport] = []
    seg_data: list[tuple[FloatArray, Segmentation | None]] = []
    if len(obj) >= min_segment_points:
        graph = build_graph(obj, m=m, threshold=4.0 * spacing)
        from scipy.sparse import csgraph

        _, comp = csgraph.connected_components(graph.adjacency, directed=True, connection="weak")
        comp = _merge_components(obj, comp, surface.size)
        sizes = np.bincount(comp)
        for c in np.argsort(-sizes):
            if sizes[c] < min_segment_points:
                break
            members = np.flatnonzero(comp == c)
            seg_pts = obj[members]
            report, seg = _group_segment(
                seg_pts, m, spacing, vp, table_plane, normal_rings=2 if noise > 0.2 * spacing else 1
            )
            segments.append(SegmentReport(keep[members], report[0], report[1], report[2]))
            seg_data.append((seg_pts, seg))
    timing["grouping"] = time.perf_counter() - t

    t_match = 0.0
    t_refine = 0.0
    results: list[tuple[PoseHypothesis, FloatArray, float, int]] = []
    syms = loc_model.symmetries()
    # Uniform random samples: median nearest-neighbour distance = 0.47 / sqrt(density).
    from mks_sim.localization.verify import surface_coverage

    for si, (seg_pts, seg) in enumerate(seg_data):
        rep = segments[si]
        noise = float(np.median([p.plane.rmse for p in rep.planes])) if rep.planes else 0.0
        inlier = max(1.0 * spacing, voxel_size, 3.0 * noise)
        t = time.perf_counter()
        if isinstance(loc_model, PolyhedralModel):
            hyps = vertex_hypotheses(loc_model, rep.vertexes, seg_pts, vote_distance=4 * spacing)
        else:
            hyps = loc_model.hypotheses(seg_pts, None if seg is None else seg.normals)
        t_match += time.perf_counter() - t
        t = time.perf_counter()
        verified = verify_hypotheses(
            hyps,
            surface,
            seg_pts,
            inlier_distance=inlier,
            symmetries=syms,
            max_icp=max_icp,
            rng=rng,
        )
        t_refine += time.perf_counter() - t
        best_score = verified[0].hypothesis.score if verified else 0.0
        if isinstance(loc_model, PolyhedralModel) and best_score < min_score and rep.planes:
            # Too few vertexes visible: hypotheses from pairs of planes (and the table).
            t = time.perf_counter()
            pairs: list[tuple[Plane, FloatArray | None]] = [
                (r.plane, seg_pts[r.indices]) for r in _diverse_planes(rep.planes)
            ]
            if rep.on_table and table_plane is not None:
                pairs.append((table_plane.flipped(), None))
            coarse = plane_pair_hypotheses(loc_model, pairs, seg_pts, inlier_distance=inlier)
            t_match += time.perf_counter() - t
            t = time.perf_counter()
            verified += verify_hypotheses(
                coarse,
                surface,
                seg_pts,
                inlier_distance=inlier,
                icp_distance=max(4 * inlier, 0.1 * surface.size),
                symmetries=syms,
                max_icp=max(4, max_icp // 2),
                rng=rng,
            )
            t_refine += time.perf_counter() - t
        # Coverage: a pose must show about as much of the model's surface as one view does,
        # or a small segment (clutter, a fragment) that a piece of the model fits would win.
        # Counted on the model's fixed sampling (not in scene points): density independent.
        if verified:
            cover = surface_coverage(
                surface.points,
                np.stack([v.hypothesis.matrix for v in verified]),
                cKDTree(seg_pts),
                max(inlier, 1.5 * spacing, voxel_size),
            )
        for k, v in enumerate(verified):
            coverage = min(1.0, float(cover[k]) / VISIBLE_FRACTION)
            h = replace(v.hypothesis, score=v.hypothesis.score * coverage)
            results.append((h, v.equivalents, v.inlier_fraction, si))
    results.sort(key=lambda r: (-r[0].score, r[0].rmse))
    results = results[:max_hypotheses]
    if voxel_size > 0 and results:
        # The voxel-averaged cloud found the pose; polish the best on the full-resolution
        # points near it (averaging blurs edges by about a voxel).
        t = time.perf_counter()
        h0, eq0, frac0, si0 = results[0]
        results[0] = (_polish_full_resolution(h0, surface, raw, voxel_size, rng), eq0, frac0, si0)
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
    max_points: int = 4000,
) -> PoseHypothesis:
    """Point-to-plane ICP of a pose on the raw (not voxel-averaged) points near it; the pose
    is kept when ICP fails or moves it by more than a voxel."""
    from mks_sim.models.refine import icp_point_to_plane

    T = np.asarray(h.matrix, dtype=np.float64)
    centre = T[:3, :3] @ surface.points.mean(axis=0) + T[:3, 3]
    radius = 0.5 * surface.size + 2.0 * voxel
    near = raw[np.linalg.norm(raw - centre, axis=1) <= radius]
    if len(near) < 30:
        return h
    if len(near) > max_points:
        near = near[rng.choice(len(near), max_points, replace=False)]
    try:
        icp = icp_point_to_plane(surface, near, T, max_distance=2.0 * voxel, max_iterations=15)
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
    c = points - points.mean(axis=0)
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
    trees = {c: cKDTree(points[members[c]]) for c in ids}
    for a, b in itertools.combinations(ids, 2):
        ra, rb = root(a), root(b)
        if ra == rb:
            continue
        d, _ = trees[a].query(points[members[b]], distance_upper_bound=0.25 * model_size)
        if not np.isfinite(d).any():
            continue
        joined = np.concatenate([members[c] for c in ids if root(c) in (ra, rb)])
        if _pca_extent(points[joined]) <= 1.1 * model_size:
            parent[rb] = ra
    out = labels.copy()
    for c in ids:
        out[members[c]] = root(c)
    return out


def _group_segment(
    seg_pts: FloatArray,
    m: int,
    spacing: float,
    viewpoint: FloatArray | None,
    table_plane: Plane | None,
    normal_rings: int = 1,
) -> tuple[tuple[tuple[PlanarRegion, ...], Vertexes, bool], Segmentation | None]:
    graph = build_graph(seg_pts, m=m)
    try:
        seg = segment_surfaces(
            seg_pts, graph, viewpoint=viewpoint, seeds="all", normal_rings=normal_rings
        )
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


# --------------------------------------------------------------------------- model loading

_MESH_EXT = (".stl", ".obj")
_CLOUD_EXT = (".pcd", ".npy", ".npz")


def load_model(spec: Any, *, name: str | None = None, kind: str = "auto") -> LocalizableModel:
    """Resolve a model: an object implementing the protocol, a mesh, a file, or a name.

    Args:
        spec: a :class:`LocalizableModel`; a ``Mesh``; a path to a mesh (``.stl``, ``.obj``,
            ``.ply`` with faces) or point cloud (``.ply`` without faces, ``.pcd``, ``.npy``,
            ``.npz``) of the whole model surface; or a name in the model database
            (``mks_sim.models.database.ModelDatabase``).
        name: model name for reports (default: the file stem or the given name).
        kind: for a mesh: ``auto`` (a mostly curved mesh -> ``freeform``, a sphere ->
            ``sphere``, else ``polyhedral``; :func:`mks_sim.localization.model.mesh_kind`),
            or one of ``polyhedral``, ``freeform``, ``sphere``.

    Raises:
        NotFound: no such file or model name.
        DataError: the file or entry does not give a usable model.
    """
    if isinstance(spec, LocalizableModel):
        return spec
    from mks_sim.localization.model import model_from_mesh

    if type(spec).__name__ == "Mesh":
        return model_from_mesh(spec, name or "mesh", kind)[0]  # type: ignore[no-any-return]
    if isinstance(spec, str | Path):
        path = Path(spec)
        if path.suffix.lower() in (*_MESH_EXT, *_CLOUD_EXT, ".ply") or path.exists():
            return _load_model_file(path, name or path.stem, kind)
        return _load_model_name(str(spec))
    raise DataError(
        f"load_model: expected a model name, file path, Mesh or LocalizableModel, "
        f"got {type(spec).__name__}"
    )


def _load_model_file(path: Path, name: str, kind: str = "auto") -> LocalizableModel:
    if not path.is_file():
        raise NotFound(f"model file not found: {path}")
    ext = path.suffix.lower()
    from mks_sim.io import _ply

    # A PLY with faces is a mesh (its errors are shown as they are); without, a point cloud.
    if ext in _MESH_EXT or (ext == ".ply" and _ply.has_element(path, "face")):
        from mks_sim.io.mesh import read_mesh
        from mks_sim.localization.model import model_from_mesh

        return model_from_mesh(read_mesh(path), name, kind)[0]  # type: ignore[no-any-return]
    from mks_sim.io.pointcloud import read_point_cloud

    cloud = read_point_cloud(path)
    return PolyhedralModel.from_points(cloud.points, name, cloud.normals)


def _load_model_name(model_name: str) -> LocalizableModel:
    try:
        from mks_sim.models.database import ModelDatabase
    except ImportError as exc:
        raise NotFound(
            f"model {model_name!r}: not a file, and the model database is unavailable"
        ) from exc
    db = ModelDatabase.from_dir()
    entry = db.get(model_name)
    return adapt_model(entry, model_name)


def adapt_model(entry: Any, name: str) -> LocalizableModel:
    """Turn a model-database entry into a :class:`LocalizableModel`.

    Accepted: an object implementing the protocol; an object with a ``mesh`` (a ``Mesh``);
    an object with ``vertexes`` / ``model_points`` / ``points`` ((V, 3), the convex polyhedron
    with those vertexes, like the paper's cube model).
    """
    if isinstance(entry, LocalizableModel):
        return entry
    for attr in ("localizable", "as_localizable"):
        fn = getattr(entry, attr, None)
        if callable(fn):
            out = fn()
            if isinstance(out, LocalizableModel):
                return out
    mesh = getattr(entry, "mesh", None)
    if mesh is not None:
        mesh = mesh() if callable(mesh) else mesh
        return PolyhedralModel.from_mesh(mesh, name)
    for attr in ("vertexes", "model_points", "points"):
        pts = getattr(entry, attr, None)
        if pts is not None:
            try:
                return PolyhedralModel.from_vertexes(np.asarray(pts, dtype=np.float64), name)
            except DataError as exc:
                raise DataError(
                    f"model {name!r}: its {len(np.asarray(pts))} model points are not the "
                    "vertexes of a convex polyhedron (control points?); localizing in a "
                    f"point cloud needs the model's surface: give a mesh file instead ({exc})"
                ) from exc
    raise DataError(
        f"model {name!r}: database entry of type {type(entry).__name__} has no mesh, vertexes "
        "or model points to localize with"
    )
