"""Objects of the workstation: cube, sphere, industrial part, clutter and scene-1 flat parts.

Every object is a body with a free joint (``names.free_joint(body)``). The BODY frame is the
object frame (ground truth, ``mks_sim.sim.truth``): MuJoCo moves a mesh into its
principal-axes frame internally, so geom frames are not object frames.

Geom groups: group 0 geoms are rendered and ray cast (what sensors see). The industrial
part's true (non-convex) mesh is a group-0 geom with no collision (contype = conaffinity =
0) that carries the mass with exact mesh inertia; its contact shape is a convex
decomposition of primitives in group 3 (invisible, not ray cast by the devices).
"""

from __future__ import annotations

import logging
from dataclasses import dataclass

import numpy as np
from dm_control import mjcf

from mks_sim.sim import names

log = logging.getLogger(__name__)

OBJECT_FRICTION = (1.0, 0.01, 0.0002)
# The sphere gets rolling friction (condim 6) so it stays balanced on the cube's top face.
SPHERE_FRICTION = (1.0, 0.01, 0.0005)
DENSITY_WOOD = 600.0  # kg/m^3; light objects the Jaco (~25 N grip) handles easily
DENSITY_PART = 1200.0  # plastic-like industrial part


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
    """

    name: str
    kind: str
    rest_height_m: float
    footprint_radius_m: float
    rest_quat: tuple[float, float, float, float] = (1.0, 0.0, 0.0, 0.0)


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


def add_cube(root: mjcf.RootElement, pos: tuple[float, float, float]) -> ObjectSpec:
    """The 5 cm cube (box geom, random-dot red texture)."""
    half = names.CUBE_SIZE_M / 2
    mat = random_dot_material(root, "cube_mat", (0.75, 0.2, 0.15), (1.0, 0.95, 0.8), size=64)
    body = _object_body(root, names.CUBE, pos)
    body.add(
        "geom",
        name="cube_geom",
        type="box",
        size=[half] * 3,
        material=mat,
        density=DENSITY_WOOD,
        friction=OBJECT_FRICTION,
        condim=4,
    )
    return ObjectSpec(names.CUBE, "cube", half, half * np.sqrt(2))


def add_sphere(root: mjcf.RootElement, pos: tuple[float, float, float]) -> ObjectSpec:
    """The 3 cm radius sphere (random-dot blue texture, rolling friction)."""
    r = names.SPHERE_RADIUS_M
    mat = random_dot_material(root, "sphere_mat", (0.15, 0.3, 0.75), (0.9, 0.95, 1.0), size=64)
    body = _object_body(root, names.SPHERE, pos)
    body.add(
        "geom",
        name="sphere_geom",
        type="sphere",
        size=[r],
        material=mat,
        density=DENSITY_WOOD,
        friction=SPHERE_FRICTION,
        condim=6,
    )
    return ObjectSpec(names.SPHERE, "sphere", r, r)


def add_clutter(root: mjcf.RootElement, index: int, pos: tuple[float, float, float]) -> ObjectSpec:
    """Simple 3-D clutter of scene 2: 0 = cylinder, 1 = flat block, 2 = tall block."""
    name = names.CLUTTER[index]
    colours = [
        ((0.2, 0.6, 0.25), (0.9, 1.0, 0.8)),
        ((0.8, 0.7, 0.2), (0.3, 0.2, 0.1)),
        ((0.5, 0.3, 0.6), (1.0, 0.9, 1.0)),
    ]
    rgb, dots = colours[index]
    mat = random_dot_material(root, f"{name}_mat", rgb, dots, size=64)
    body = _object_body(root, name, pos)
    common = dict(material=mat, density=DENSITY_WOOD, friction=OBJECT_FRICTION, condim=4)
    if index == 0:
        r, h = 0.022, 0.035
        body.add("geom", name=f"{name}_geom", type="cylinder", size=[r, h], **common)
        return ObjectSpec(name, "cylinder", h, r)
    if index == 1:
        half = (0.04, 0.025, 0.015)
    else:
        half = (0.02, 0.02, 0.04)
    body.add("geom", name=f"{name}_geom", type="box", size=list(half), **common)
    return ObjectSpec(name, "block", half[2], float(np.hypot(half[0], half[1])))


def _triplanar_texcoords(vertices: np.ndarray, scale_m: float = 0.05) -> np.ndarray:
    """(V, 2) texture coordinates u = (x + z)/s, v = (y + z)/s: no axis-aligned face of the
    mesh gets a degenerate (zero-area) mapping, so a random-dot texture covers every face."""
    v = np.asarray(vertices, dtype=float)
    return np.column_stack([(v[:, 0] + v[:, 2]) / scale_m, (v[:, 1] + v[:, 2]) / scale_m])


def add_part(root: mjcf.RootElement, pos: tuple[float, float, float]) -> ObjectSpec:
    """The industrial part ("Renault piece", ``mks_sim.geometry.meshes``).

    The true mesh is generated at build time and inlined into the MJCF (``<mesh vertex=
    face= texcoord=>``; no file on disk): a group-0 geom that renders, ray casts and carries
    the mass (exact mesh inertia) but does not collide. Contact uses the convex decomposition
    ``industrial_part_boxes()`` as massless group-3 primitives.
    """
    from mks_sim.geometry.meshes import industrial_part_boxes, industrial_part_mesh

    mesh = industrial_part_mesh()
    # Unwelded (three vertices per face) with face normals: flat shading of the planar faces
    # and per-face texture coordinates.
    corners = mesh.vertices[mesh.faces].reshape(-1, 3)  # (3F, 3)
    asset = root.asset.add(
        "mesh",
        name="part_mesh",
        vertex=corners.ravel(),
        face=np.arange(len(corners)),
        normal=np.repeat(mesh.normals, 3, axis=0).ravel(),
        texcoord=_triplanar_texcoords(corners).ravel(),
        inertia="exact",
    )
    mat = random_dot_material(
        root, "part_mat", (0.55, 0.58, 0.62), (0.15, 0.15, 0.18), kind="2d", size=128
    )
    body = _object_body(root, names.PART, pos)
    body.add(
        "geom",
        name="part_visual",
        type="mesh",
        mesh=asset,
        material=mat,
        density=DENSITY_PART,
        contype=0,
        conaffinity=0,
        group=names.GROUP_VISUAL,
    )
    from scipy.spatial.transform import Rotation

    for i, prim in enumerate(industrial_part_boxes()):
        x, y, z, w = Rotation.from_matrix(prim.rotation).as_quat()
        size = (
            list(prim.half_sizes)
            if prim.kind == "box"
            else [prim.half_sizes[0], prim.half_sizes[2]]
        )
        body.add(
            "geom",
            name=f"part_collision_{i}",
            type=prim.kind,
            size=size,
            pos=prim.centre,
            quat=(w, x, y, z),
            density=0.0,
            group=names.GROUP_COLLISION_ONLY,
            rgba=(0.9, 0.4, 0.1, 0.5),
            friction=OBJECT_FRICTION,
            condim=4,
        )
    lo, hi = mesh.vertices.min(axis=0), mesh.vertices.max(axis=0)
    footprint = float(np.max(np.hypot(mesh.vertices[:, 0], mesh.vertices[:, 1])))
    if lo[2] != 0.0:
        log.warning("part mesh bottom at z = %.4f m, expected 0 (object frame)", lo[2])
    del hi
    return ObjectSpec(names.PART, "industrial part", -float(lo[2]), footprint)
