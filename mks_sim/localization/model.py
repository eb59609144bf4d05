"""The models the engine localizes: the protocol, the polyhedral model, kinds and loading.

- :class:`LocalizableModel` — what the pipeline needs from a model (surface samples and
  normals, symmetries, hypotheses from a scene segment);
- :class:`PolyhedralModel` — corners with their face normals, large planar faces and surface
  samples (from a mesh, a point file or vertexes), with cached per-model tables (surface
  k-d tree, face pairs and their frames, face hull samples);
- :func:`load_model` / :func:`adapt_model` — a model from a name, file, mesh or database entry.

Kinds (``KINDS``):

- ``polyhedral`` — :class:`PolyhedralModel`: vertexes and faces of a mostly
  planar surface (cube, industrial part);
- ``freeform`` — :class:`mks_sim.models.freeform.FreeformModel`: point-pair features of a
  curved surface (torus, blob);
- ``sphere`` — :class:`mks_sim.models.sphere.SphereModel`: a radius;
- ``auto`` — :func:`mesh_kind` chooses from the mesh: ``sphere`` when every vertex is at one
  distance from the centroid, ``polyhedral`` when most of the area lies in large planar
  facets, else ``freeform``.

The pipeline is chosen by the model's kind, never by an object's name.
"""

from __future__ import annotations

import functools
import itertools
import logging
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any, Protocol, runtime_checkable

import numpy as np
from numpy.typing import ArrayLike, NDArray
from scipy.spatial import ConvexHull, QhullError

from mks_sim.errors import DataError, NotFound
from mks_sim.geometry.transforms import cube_rotations
from mks_sim.localization.hypotheses import _frame, vertex_hypotheses
from mks_sim.lowlevel.grouping import build_graph, plane_vertexes, segment_surfaces
from mks_sim.models.pose import PoseHypothesis
from mks_sim.models.refine import ModelSurface, detect_symmetries

if TYPE_CHECKING:
    from mks_sim.geometry.meshes import Mesh
    from mks_sim.models.database import ModelDatabase

__all__ = [
    "KINDS",
    "Corner",
    "LocalizableModel",
    "ModelFace",
    "PolyhedralModel",
    "adapt_model",
    "db_for",
    "default_db",
    "load_model",
    "PLANAR_AREA_FRACTION",
    "mesh_kind",
    "model_from_mesh",
    "model_kind",
    "planar_area_fraction",
]

log = logging.getLogger(__name__)
FloatArray = NDArray[np.float64]

#: The model kinds ``localize-cloud --kind`` accepts.
KINDS = ("auto", "polyhedral", "freeform", "sphere")
#: A mesh with at least this fraction of its area in large planar facets is polyhedral.
PLANAR_AREA_FRACTION = 0.6
#: A planar facet counts as large when it holds this fraction of the mesh area (the facets of
#: a tessellated curved surface are each far smaller; the polyhedral model's own threshold).
LARGE_FACET_FRACTION = 0.004


def planar_area_fraction(mesh: Any, min_face_fraction: float = LARGE_FACET_FRACTION) -> float:
    """Fraction of the mesh area lying in planar facets (coplanar triangles merged) of at
    least ``min_face_fraction`` of the area each."""
    v, f = np.asarray(mesh.vertices, dtype=np.float64), np.asarray(mesh.faces)
    tri = v[f]
    cross = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
    area2 = np.linalg.norm(cross, axis=1)
    good = area2 > 1e-18
    if not good.any():
        raise DataError("mesh has no triangle of non-zero area")
    n = cross[good] / area2[good, None]
    size = float(np.linalg.norm(np.ptp(v, axis=0)))
    offset = np.einsum("ij,ij->i", n, tri[good, 0]) / size
    key = np.column_stack([np.round(n * 1e3), np.round(offset * 1e3)])
    _, plane_of = np.unique(key, axis=0, return_inverse=True)
    plane_area = np.bincount(plane_of.reshape(-1), weights=area2[good])
    total = float(area2[good].sum())
    return float(plane_area[plane_area >= min_face_fraction * total].sum() / total)


def _sphere_radius(mesh: Any) -> float | None:
    """The radius when every vertex lies at one distance (within 2 %) from the centroid."""
    v = np.asarray(mesh.vertices, dtype=np.float64)
    r = np.linalg.norm(v - v.mean(axis=0), axis=1)
    mean = float(r.mean())
    if mean > 0 and float(np.max(np.abs(r - mean))) <= 0.02 * mean and len(v) >= 20:
        return mean
    return None


def mesh_kind(mesh: Any) -> str:
    """``sphere``, ``polyhedral`` or ``freeform`` for a model mesh (see the module doc)."""
    if _sphere_radius(mesh) is not None:
        return "sphere"
    return "polyhedral" if planar_area_fraction(mesh) >= PLANAR_AREA_FRACTION else "freeform"


def model_from_mesh(mesh: Any, name: str, kind: str = "auto") -> tuple[Any, str]:
    """A localizable model of ``mesh`` of the given kind; returns (model, the kind built).

    Raises:
        DataError: unknown kind, or a mesh the kind cannot use (a polyhedral model of a mesh
            without corners; a sphere of a mesh that is not one).
    """
    if kind not in KINDS:
        raise DataError(f"model kind: expected one of {list(KINDS)}, got {kind!r}")
    try:
        chosen = mesh_kind(mesh) if kind == "auto" else kind
    except DataError as exc:
        raise DataError(f"model {name!r}: {exc}") from None
    if chosen == "sphere":
        from mks_sim.models.sphere import SphereModel

        r = _sphere_radius(mesh)
        if r is None:
            raise DataError(f"model {name!r}: the mesh is not a sphere (vertex radii differ)")
        # the mesh's facets sit inside the true sphere by up to its sagitta
        return SphereModel(name, r, max(0.05 * r, 1e-6)), chosen
    if chosen == "freeform":
        from mks_sim.models.freeform import FreeformModel

        return FreeformModel.from_mesh(mesh, name), chosen
    return PolyhedralModel.from_mesh(mesh, name), chosen


def model_kind(model: Any) -> str:
    """The kind of a localizable model: ``sphere`` (a radius), ``polyhedral`` (corners and
    faces), ``freeform`` (point-pair tables), else its ``kind`` attribute or type name."""
    kind = getattr(model, "kind", None)
    if isinstance(kind, str) and kind in KINDS:
        return kind
    if isinstance(getattr(model, "radius_m", None), float):
        return "sphere"
    if hasattr(model, "corners") and hasattr(model, "faces"):
        return "polyhedral"
    if type(model).__name__ == "FreeformModel":
        return "freeform"
    return type(model).__name__


# --------------------------------------------------------------------------- the protocol


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
    def _axes(self) -> tuple[FloatArray, FloatArray]:
        """Two orthonormal axes in the face's plane (u, n x u)."""
        n = np.asarray(self.normal, dtype=np.float64)
        u = np.cross(n, [1.0, 0.0, 0.0] if abs(n[0]) < 0.9 else [0.0, 1.0, 0.0])
        u /= np.linalg.norm(u)
        return u, np.cross(n, u)

    @functools.cached_property
    def extremes(self) -> FloatArray:
        """(E, 3) the samples on the convex hull of the face (in its plane): the extent of
        the face along any direction (ptp of the projections) is the extent of these."""
        pts = np.asarray(self.points, dtype=np.float64)
        if len(pts) < 4:
            return pts
        u, v = self._axes
        try:
            hull = ConvexHull(np.c_[pts @ u, pts @ v])
        except QhullError:  # degenerate (collinear) samples: keep them all
            return pts
        return pts[hull.vertices]

    @functools.cached_property
    def width(self) -> float:
        """The face's minimum width: its extent along the in-plane direction where that is
        least (the convex hull's, exact: the least over the hull's edges of the farthest
        hull point from the edge's line)."""
        u, v = self._axes
        ext = np.asarray(self.extremes, dtype=np.float64)
        uv = np.c_[ext @ u, ext @ v]
        if len(uv) < 3:
            return 0.0
        edge = np.roll(uv, -1, axis=0) - uv  # (the hull's points go round it in order)
        length = np.linalg.norm(edge, axis=1)
        ok = length > 0
        if not ok.any():
            return 0.0
        d = edge[ok] / length[ok, None]
        rel = uv[None, :, :] - uv[ok][:, None, :]  # (E, V, 2)
        far = np.abs(d[:, None, 0] * rel[..., 1] - d[:, None, 1] * rel[..., 0]).max(axis=1)
        return float(far.min())


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

    @functools.cached_property
    def feature_width(self) -> float:
        """The median of the faces' minimum widths (:attr:`ModelFace.width`; 0 without
        faces): how finely a scan must sample the object for its faces to be found
        (of their samples' hulls: a 50 mm cube 49.7 mm, the industrial part 21.5 mm)."""
        widths = [f.width for f in self.faces]
        return float(np.median(widths)) if widths else 0.0

    @functools.cached_property
    def vertexes(self) -> FloatArray:
        """(V, 3) the corner positions (read-only; computed once)."""
        out = np.stack([c.point for c in self.corners])
        out.setflags(write=False)
        return out

    @functools.cached_property
    def corner_triples(self) -> tuple[FloatArray, FloatArray]:
        """Every corner with every ordered triple of its face normals: (K, 3) corner
        positions and (K, 3, 3) normals (rows); read-only, computed once (the vertex
        matcher asks for them per segment)."""
        pts, nrm = [], []
        for c in self.corners:
            for perm in itertools.permutations(range(len(c.normals)), 3):
                pts.append(c.point)
                nrm.append(c.normals[list(perm)])
        p, n = np.array(pts).reshape(-1, 3), np.array(nrm).reshape(-1, 3, 3)
        p.setflags(write=False)
        n.setflags(write=False)
        return p, n

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


# --------------------------------------------------------------------------- the database


@functools.lru_cache(maxsize=1)
def default_db() -> ModelDatabase:
    """The shipped model database (``tasks/models``), loaded once."""
    from mks_sim.models.database import ModelDatabase

    return ModelDatabase.from_dir()


@functools.lru_cache(maxsize=4)
def db_for(models: tuple[str, ...]) -> ModelDatabase:
    """The model database of the shipped folder plus ``models`` (``--models``), loaded once."""
    from mks_sim.models.database import ModelDatabase
    from mks_sim.models.objects import models_dirs

    return ModelDatabase.from_dirs(models_dirs(models))
