"""Objects of the workstation: database objects (cube, sphere, part, any added mesh) and the
random-dot materials (clutter and flat parts come from scene files: ``sim.scenes``,
``sim.flatparts``).

Every object is a body with a free joint (``names.free_joint(body)``). The BODY frame is the
object frame (ground truth, ``mks_sim.sim.truth``): MuJoCo moves a mesh into its
principal-axes frame internally, so geom frames are not object frames.

A database object (:class:`mks_sim.models.objects.ObjectModel`) becomes MJCF by
:func:`add_object`: a builtin box or sphere with ``collision = "primitive"`` is that MuJoCo
primitive; any other mesh is a group-0 geom that renders, is ray cast and carries the mass
(exact mesh inertia) but does not collide (contype = conaffinity = 0), plus its contact shape
in group 3 (invisible, not ray cast by the devices): the mesh itself (MuJoCo collides with its
convex hull), the industrial part's hand-made decomposition, or the convex parts CoACD wrote
(``mks-sim objects add``).
"""

from __future__ import annotations

import logging
from dataclasses import dataclass, field
from typing import TYPE_CHECKING

import numpy as np
from dm_control import mjcf

from mks_sim.sim import names

if TYPE_CHECKING:
    from mks_sim.models.objects import ObjectModel

log = logging.getLogger(__name__)

OBJECT_FRICTION = (1.0, 0.01, 0.0002)  # clutter, table (database objects carry their own)
DENSITY_WOOD = 600.0  # kg/m^3; light objects the Jaco (~25 N grip) handles easily


@dataclass(frozen=True)
class ObjectSpec:
    """How an object rests on a horizontal surface.

    Attributes:
        name: body name.
        kind: short description (``"cube"``, ``"sphere"``, ``"disc"``, ...).
        rest_height_m: z of the body origin above the supporting surface when resting in
            ``rest_quat`` (then any yaw about world z keeps it resting).
        footprint_radius_m: radius of a vertical cylinder holding the object (for
            non-overlapping random placement).
        rest_quat: (w, x, y, z) canonical resting orientation before the random yaw.
        model: the database object name (None for clutter and flat parts).
        hull: (H, 3) vertexes of the convex hull in the body frame (for dropping the object
            from a random orientation: its lowest point), or None.
    """

    name: str
    kind: str
    rest_height_m: float
    footprint_radius_m: float
    rest_quat: tuple[float, float, float, float] = (1.0, 0.0, 0.0, 0.0)
    model: str | None = None
    hull: np.ndarray | None = field(default=None, compare=False, repr=False)

    @property
    def reach_m(self) -> float:
        """Largest distance of the body from its origin (any orientation's footprint)."""
        if self.hull is None:
            return float(np.hypot(self.footprint_radius_m, self.rest_height_m))
        return float(np.max(np.linalg.norm(self.hull, axis=1)))


def random_dot_material(
    root: mjcf.RootElement,
    name: str,
    rgb: tuple[float, float, float],
    dots: tuple[float, float, float],
    density: float = 0.25,
    kind: str = "cube",
    size: int = 128,
    texrepeat: tuple[float, float] | None = None,
) -> mjcf.Element:
    """Add a random-dot textured material (texture for stereo block matching).

    Args:
        root: MJCF root.
        name: material name (the texture is ``<name>_tex``).
        rgb: base colour, 0..1.
        dots: dot colour, 0..1.
        density: fraction of texels that are dots.
        kind: MuJoCo texture type (``"cube"`` for boxes/spheres, ``"2d"`` for planes).
        size: texture width/height in texels.
        texrepeat: repetitions over a plane/box face (2d textures).
    """
    tex = root.asset.add(
        "texture",
        name=f"{name}_tex",
        type=kind,
        builtin="flat",
        mark="random",
        random=density,
        rgb1=rgb,
        rgb2=rgb,
        markrgb=dots,
        width=size,
        height=size,
    )
    kwargs: dict[str, object] = {}
    if texrepeat is not None:
        kwargs["texrepeat"] = texrepeat
        kwargs["texuniform"] = True
    return root.asset.add("material", name=name, texture=tex, specular=0.1, **kwargs)


def _object_body(
    root: mjcf.RootElement, name: str, pos: tuple[float, float, float]
) -> mjcf.Element:
    body = root.worldbody.add("body", name=name, pos=pos)
    body.add("freejoint", name=names.free_joint(name))
    return body


def _triplanar_texcoords(vertices: np.ndarray, scale_m: float = 0.05) -> np.ndarray:
    """(V, 2) texture coordinates u = (x + z)/s, v = (y + z)/s: no axis-aligned face of the
    mesh gets a degenerate (zero-area) mapping, so a random-dot texture covers every face."""
    v = np.asarray(vertices, dtype=float)
    return np.column_stack([(v[:, 0] + v[:, 2]) / scale_m, (v[:, 1] + v[:, 2]) / scale_m])


def add_object(
    root: mjcf.RootElement,
    obj: ObjectModel,
    pos: tuple[float, float, float] = (0.0, 0.0, 0.0),
    *,
    body_name: str | None = None,
) -> ObjectSpec:
    """Add database object ``obj`` as a free body named ``body_name`` (default ``obj.name``).

    Geom, material and mesh names start with the body name (``cube_geom``, ``part_visual``,
    ``part_collision_3``, ``part_mesh``, ``part_mat``). The resting spec is the mesh's
    upright pose (body z up, lowest vertex on the support).
    """
    name = body_name or obj.name
    mesh = obj.mesh
    volume = mesh.volume
    density = obj.density if obj.density is not None else float(obj.mass or 0.0) / volume
    body = _object_body(root, name, pos)
    v = mesh.vertices
    lo = v.min(axis=0)
    if abs(lo[2]) > 0.5 and obj.primitive is None:  # metres: a body origin 50 cm off the mesh
        log.warning("object %r: mesh bottom at z = %.3f m from its origin", obj.name, lo[2])
    footprint = float(np.max(np.hypot(v[:, 0], v[:, 1])))
    from scipy.spatial import ConvexHull

    hull = v[ConvexHull(v).vertices]
    spec = ObjectSpec(
        name, obj.description or obj.name, -float(lo[2]), footprint, model=obj.name, hull=hull
    )
    common = dict(friction=obj.friction, condim=obj.condim)
    if obj.primitive is not None and obj.collision == "primitive":
        mat = random_dot_material(root, f"{name}_mat", obj.rgb, obj.dots, size=64)
        if obj.primitive == "box":
            size = list((v.max(axis=0) - lo) / 2)
            spec = ObjectSpec(
                name, "box", size[2], float(np.hypot(size[0], size[1])), model=obj.name, hull=hull
            )
        else:
            size = [float(np.max(np.linalg.norm(v, axis=1)))]
            spec = ObjectSpec(name, "sphere", size[0], size[0], model=obj.name, hull=hull)
        body.add(
            "geom",
            name=f"{name}_geom",
            type=obj.primitive,
            size=size,
            material=mat,
            density=density,
            **common,
        )
        return spec
    # Unwelded (three vertices per face) with face normals: flat shading of planar faces and
    # per-face texture coordinates.
    corners = mesh.vertices[mesh.faces].reshape(-1, 3)  # (3F, 3)
    asset = root.asset.add(
        "mesh",
        name=f"{name}_mesh",
        vertex=corners.ravel(),
        face=np.arange(len(corners)),
        normal=np.repeat(mesh.normals, 3, axis=0).ravel(),
        texcoord=_triplanar_texcoords(corners).ravel(),
        inertia=obj.inertia,
    )
    mat = random_dot_material(root, f"{name}_mat", obj.rgb, obj.dots, kind="2d", size=128)
    body.add(
        "geom",
        name=f"{name}_visual",
        type="mesh",
        mesh=asset,
        material=mat,
        density=density,
        contype=0,
        conaffinity=0,
        group=names.GROUP_VISUAL,
    )
    collision = dict(
        density=0.0, group=names.GROUP_COLLISION_ONLY, rgba=(0.9, 0.4, 0.1, 0.5), **common
    )
    if obj.collision == "builtin:industrial_part":
        _add_part_primitives(body, name, collision)
    elif obj.collision == "mesh" or obj.collision == "primitive":
        hull_asset = root.asset.add(
            "mesh",
            name=f"{name}_collision_mesh",
            vertex=mesh.vertices.ravel(),
            face=mesh.faces.ravel(),
        )
        body.add("geom", name=f"{name}_collision_0", type="mesh", mesh=hull_asset, **collision)
    else:
        from mks_sim.io.mesh import read_mesh

        assert not isinstance(obj.collision, str)
        for i, path in enumerate(obj.collision):
            piece = read_mesh(path)
            piece_asset = root.asset.add(
                "mesh",
                name=f"{name}_collision_mesh_{i}",
                vertex=piece.vertices.ravel(),
                face=piece.faces.ravel(),
            )
            body.add(
                "geom", name=f"{name}_collision_{i}", type="mesh", mesh=piece_asset, **collision
            )
    return spec


def _prism(radius: float, half_h: float, n: int = 32) -> tuple[np.ndarray, np.ndarray]:
    """Vertexes and faces of a convex n-gon prism about z (MuJoCo collides with the hull)."""
    a = np.linspace(0, 2 * np.pi, n, endpoint=False)
    ring = np.column_stack([radius * np.cos(a), radius * np.sin(a)])
    v = np.vstack(
        [np.column_stack([ring, np.full(n, -half_h)]), np.column_stack([ring, np.full(n, half_h)])]
    )
    from scipy.spatial import ConvexHull

    return v, ConvexHull(v).simplices


def _add_part_primitives(body: mjcf.Element, name: str, collision: dict) -> None:
    """The industrial part's convex decomposition (``industrial_part_boxes``): boxes, and the
    boss as a 32-gon prism mesh (a MuJoCo cylinder primitive lying on the table box sinks
    into it and walks: measured with the part dropped on its side)."""
    from scipy.spatial.transform import Rotation

    from mks_sim.geometry.meshes import industrial_part_boxes

    for i, prim in enumerate(industrial_part_boxes()):
        if prim.kind == "cylinder":
            x, y, z, w = Rotation.from_matrix(prim.rotation).as_quat()
            v, f = _prism(prim.half_sizes[0], prim.half_sizes[2])
            asset = body.root.asset.add(
                "mesh", name=f"{name}_collision_mesh_{i}", vertex=v.ravel(), face=f.ravel()
            )
            body.add(
                "geom",
                name=f"{name}_collision_{i}",
                type="mesh",
                mesh=asset,
                pos=prim.centre,
                quat=(w, x, y, z),
                **collision,
            )
            continue
        x, y, z, w = Rotation.from_matrix(prim.rotation).as_quat()
        size = (
            list(prim.half_sizes)
            if prim.kind == "box"
            else [prim.half_sizes[0], prim.half_sizes[2]]
        )
        body.add(
            "geom",
            name=f"{name}_collision_{i}",
            type=prim.kind,
            size=size,
            pos=prim.centre,
            quat=(w, x, y, z),
            **collision,
        )
