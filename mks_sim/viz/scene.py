"""Geometry for drawing: MuJoCo geoms as triangle meshes, wireframes, object clouds.

No Rerun here (plain numpy), so the pieces are testable without the viewer.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass
from typing import Any

import mujoco
import numpy as np
from numpy.typing import NDArray

from mks_sim.errors import MksError
from mks_sim.geometry.meshes import box_mesh, uv_sphere
from mks_sim.lowlevel.regions import segment_surfaces
from mks_sim.lowlevel.spg import SpatialProximityGraph
from mks_sim.sim import names
from mks_sim.viz.recorder import as_matrix

__all__ = [
    "GeomMesh",
    "flat_name",
    "grasp_point",
    "grasp_quality",
    "rebuilt_grouping",
    "undirected_edges",
    "body_mesh",
    "body_to_world",
    "feature_edges",
    "geom_meshes",
    "object_mesh",
    "wireframe",
]

log = logging.getLogger(__name__)
FloatArray = NDArray[np.float64]


@dataclass(frozen=True, eq=False)
class GeomMesh:
    """One drawable geom.

    Attributes:
        name: the geom's name (``geom_<id>`` when unnamed).
        geom_id: its id in the compiled model.
        body: the name of the body it is fixed to.
        body_id: that body's id (to read ``data.xpos/xmat``).
        geom_to_body: (4, 4) the geom frame in the body frame (constant).
        vertices: (V, 3) float vertices in the geom frame, metres.
        faces: (F, 3) int triangles.
        rgba: (4,) float colour.
    """

    name: str
    geom_id: int
    body: str
    body_id: int
    geom_to_body: FloatArray
    vertices: FloatArray
    faces: NDArray[np.int64]
    rgba: FloatArray


def _geom_triangles(model: mujoco.MjModel, g: int) -> tuple[FloatArray, NDArray[np.int64]] | None:
    t = int(model.geom_type[g])
    size = np.asarray(model.geom_size[g], dtype=float)
    if t == mujoco.mjtGeom.mjGEOM_MESH:
        m = int(model.geom_dataid[g])
        v0, nv = int(model.mesh_vertadr[m]), int(model.mesh_vertnum[m])
        f0, nf = int(model.mesh_faceadr[m]), int(model.mesh_facenum[m])
        verts = np.asarray(model.mesh_vert[v0 : v0 + nv], dtype=float)
        return verts, np.asarray(model.mesh_face[f0 : f0 + nf], dtype=np.int64)
    if t == mujoco.mjtGeom.mjGEOM_BOX:
        mesh = box_mesh(2.0 * size)
    elif t == mujoco.mjtGeom.mjGEOM_SPHERE:
        mesh = uv_sphere(float(size[0]))
    else:
        return None  # planes, capsules, cylinders: nothing the recordings need yet
    return np.asarray(mesh.vertices, dtype=float), np.asarray(mesh.faces, dtype=np.int64)


def geom_meshes(
    model: mujoco.MjModel, body_prefix: str, groups: tuple[int, ...] = (0, 1)
) -> list[GeomMesh]:
    """Meshes of the geoms of every body whose name starts with ``body_prefix``.

    Args:
        model: the compiled model.
        body_prefix: e.g. ``"jaco_arm/"`` (:data:`mks_sim.sim.names.ROBOT_PREFIX`).
        groups: geom groups drawn (0 visual, 1 robot pads; never 3, collision stand-ins).
    """
    out: list[GeomMesh] = []
    for g in range(model.ngeom):
        body = model.body(int(model.geom_bodyid[g])).name
        if not body.startswith(body_prefix) or int(model.geom_group[g]) not in groups:
            continue
        tri = _geom_triangles(model, g)
        if tri is None:
            continue
        name = model.geom(g).name or f"geom_{g}"
        bid = int(model.geom_bodyid[g])
        out.append(GeomMesh(name, g, body, bid, _geom_to_body(model, g), tri[0], tri[1],
                            np.asarray(model.geom_rgba[g], dtype=float)))  # fmt: skip
    return out


def _geom_to_body(model: mujoco.MjModel, g: int) -> FloatArray:
    R = np.zeros(9)
    mujoco.mju_quat2Mat(R, np.asarray(model.geom_quat[g], dtype=float))
    T = np.eye(4)
    T[:3, :3] = R.reshape(3, 3)
    T[:3, 3] = model.geom_pos[g]
    return T


def body_to_world(data: mujoco.MjData, body_id: int) -> FloatArray:
    """(4, 4) pose of a body in the world (after ``mj_kinematics``)."""
    T = np.eye(4)
    T[:3, :3] = np.asarray(data.xmat[body_id], dtype=float).reshape(3, 3)
    T[:3, 3] = data.xpos[body_id]
    return T


def body_mesh(model: mujoco.MjModel, body: str) -> tuple[FloatArray, NDArray[np.int64]] | None:
    """The visual geoms of one body merged into one mesh in the BODY frame (or None)."""
    bid = model.body(body).id
    verts: list[FloatArray] = []
    faces: list[NDArray[np.int64]] = []
    n = 0
    for g in range(model.ngeom):
        if int(model.geom_bodyid[g]) != bid or int(model.geom_group[g]) != 0:
            continue
        tri = _geom_triangles(model, g)
        if tri is None:
            continue
        T = _geom_to_body(model, g)
        verts.append(tri[0] @ T[:3, :3].T + T[:3, 3])
        faces.append(tri[1] + n)
        n += len(tri[0])
    if not verts:
        return None
    return np.concatenate(verts), np.concatenate(faces)


def object_mesh(name: str, world: Any = None) -> tuple[FloatArray, NDArray[np.int64]] | None:
    """An object's mesh in its body frame: the model database's object when it has one
    (``mks_sim.models.objects.load_object``), else the world's visual geoms of the body."""
    try:
        from mks_sim.models import objects  # type: ignore[attr-defined]

        mesh = objects.load_object(name).mesh
        return np.asarray(mesh.vertices, dtype=float), np.asarray(mesh.faces, dtype=np.int64)
    except Exception:  # noqa: BLE001 - the objects database is optional for drawing
        pass
    if world is None:
        return None
    try:
        return body_mesh(world.model, name)
    except KeyError:
        return None


def feature_edges(faces: NDArray[np.int64], vertices: FloatArray, angle_deg: float = 20.0):
    """(E, 2) vertex pairs of the edges where the surface bends by more than ``angle_deg``
    (and boundary edges): a box gives its 12 edges, not the triangulation's diagonals."""
    f = np.asarray(faces, dtype=np.int64)
    v = np.asarray(vertices, dtype=float)
    n = np.cross(v[f[:, 1]] - v[f[:, 0]], v[f[:, 2]] - v[f[:, 0]])
    n /= np.maximum(np.linalg.norm(n, axis=1, keepdims=True), 1e-15)
    e = np.concatenate([f[:, [0, 1]], f[:, [1, 2]], f[:, [2, 0]]])
    face_of = np.tile(np.arange(len(f)), 3)
    key = np.sort(e, axis=1)
    order = np.lexsort((key[:, 1], key[:, 0]))
    key, face_of = key[order], face_of[order]
    same = np.all(key[1:] == key[:-1], axis=1)
    keep: list[NDArray[np.int64]] = []
    cos_max = np.cos(np.deg2rad(angle_deg))
    pair = np.flatnonzero(same)
    bent = np.einsum("ij,ij->i", n[face_of[pair]], n[face_of[pair + 1]]) < cos_max
    keep.append(key[pair[bent]])
    paired = np.zeros(len(key), dtype=bool)
    paired[pair] = paired[pair + 1] = True
    keep.append(key[~paired])
    return np.unique(np.concatenate(keep), axis=0)


def wireframe(
    vertices: FloatArray, faces: NDArray[np.int64], max_edges: int = 600
) -> FloatArray:
    """(E, 2, 3) line segments drawing a mesh: its feature edges, or (for a smooth mesh such
    as a sphere, which has none) at most ``max_edges`` of its triangle edges."""
    edges = feature_edges(faces, vertices)
    if len(edges) < 3:
        f = np.asarray(faces, dtype=np.int64)
        all_e = np.unique(
            np.sort(np.concatenate([f[:, [0, 1]], f[:, [1, 2]], f[:, [2, 0]]]), axis=1), axis=0
        )
        edges = all_e[:: max(1, len(all_e) // max_edges)]
    v = np.asarray(vertices, dtype=float)
    return np.stack([v[edges[:, 0]], v[edges[:, 1]]], axis=1)


def transform_segments(segments: FloatArray, T: FloatArray) -> FloatArray:
    """(E, 2, 3) segments mapped by the 4x4 ``T`` (column convention)."""
    return segments @ T[:3, :3].T + T[:3, 3]


def object_clouds(
    points: FloatArray, table_z: float, margin: float = 0.004, gap: float = 0.012
) -> list[NDArray[np.int64]]:
    """Index sets of the points above the table split by SPG connectivity (largest first)."""
    above = np.flatnonzero(points[:, 2] > table_z + margin)
    if len(above) < 10:
        return []
    spg = SpatialProximityGraph(points[above], m=8, threshold=gap)
    n, labels = spg.components()
    groups = [above[labels == k] for k in range(n)]
    return sorted((g for g in groups if len(g) >= 30), key=len, reverse=True)


def flat_name(name: str) -> str:
    """A MuJoCo name as one entity-path part (``jaco_arm/b_1`` -> ``jaco_arm.b_1``)."""
    return name.strip("/").replace("/", ".") or "root"


def undirected_edges(adjacency: Any) -> np.ndarray:
    """(E, 2) each undirected edge of a (directed, sparse) SPG once."""
    A = adjacency.tocoo()
    pairs = np.sort(np.c_[A.row, A.col], axis=1)
    return np.unique(pairs[pairs[:, 0] != pairs[:, 1]], axis=0)


def rebuilt_grouping(points: np.ndarray) -> list[tuple[np.ndarray, np.ndarray, Any]]:
    """SPG (m = 8) and ``segment_surfaces`` of each object cloud, rebuilt for display."""
    out: list[tuple[np.ndarray, np.ndarray, Any]] = []
    for idx in object_clouds(points, names.TABLE_TOP_Z):
        cloud = points[idx]
        spg = SpatialProximityGraph(cloud, m=8)
        try:
            seg = segment_surfaces(cloud, spg)
        except MksError as exc:
            log.debug("segmentation: %s", exc)
            seg = None
        out.append((cloud, undirected_edges(spg.adjacency), seg))
    return out


def grasp_quality(c: Any, rank: int) -> float:
    """A candidate's quality: its own ``quality``, else its antipodality (1 = perfect),
    else its rank (1, 1/2, 1/3, ...)."""
    for attr in ("quality", "antipodal"):
        q = getattr(c, attr, None)
        if q is not None:
            return float(q)
    return 1.0 / (rank + 1)


def grasp_point(c: Any) -> np.ndarray | None:
    """(3,) where a grasp candidate or plan closes (its pinch point), or None."""
    for attr in ("grasp_point_world", "pinch_world", "position_world", "point_world"):
        if hasattr(c, attr):
            return np.asarray(getattr(c, attr), dtype=float)[:3]
    T = as_matrix(getattr(c, "grasp_to_world", None))
    return None if T is None else T[:3, 3]
