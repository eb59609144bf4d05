"""Scene assembly: the workstation (table, cameras, range-finder mounts, Jaco) + objects.

Each scene is an MJCF model assembled from code with dm_control's ``mjcf``; nothing is read
from disk except dm_control's robot assets. ``build_scene(name)`` returns the MJCF root, the
robot entities and the specs of the objects that ``World.randomize`` places.

Scenes (paper section 4.1):
    ``scene1``: a light tray of dark flat parts (discs, nuts, washer, plates) seen from
        above -- the paper's Figure 4-1, laid out after Tables 4-1 / 4-3.
    ``scene2``: the cube with the sphere atop it among three clutter objects (Scenes 2, 3).
    ``part``: the industrial part ("Renault piece") alone on the table (Figures 4-9..).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from dm_control import mjcf

from mks_sim.errors import NotFound
from mks_sim.sim import names, objects
from mks_sim.sim.robot import Robot, add_robot

TABLE_HALF = (0.45, 0.7, 0.02)  # m; the table centre is at y = 0.2 so the arm base fits
TABLE_CENTER_XY = (0.0, 0.2)
TIMESTEP = 0.002
# Contact model for stable grasps: elliptic cones with impratio 10 make friction nearly as
# stiff as the normal constraint (held objects do not creep); a few noslip iterations remove
# the residual drift of soft contacts. Measured slip: see docs/worlds.md.
CONTACT_OPTIONS = dict(cone="elliptic", impratio=10.0, noslip_iterations=4)


@dataclass(frozen=True)
class SceneSpec:
    """A built (uncompiled) scene.

    Attributes:
        name: scene name.
        root: the MJCF root (compile with ``mjcf.Physics.from_mjcf_model``).
        robot: the arm and hand entities.
        objects: resting specs of the movable objects, in placement order.
        stacked: (top, bottom) pairs: ``top`` rests centred on ``bottom`` (scene 2's sphere
            on the cube).
        region_center_xy: centre of the placement region (m, world).
        region_half_xy: half extents of the placement region (m).
        support_z: world z of the surface the objects rest on.
    """

    name: str
    root: mjcf.RootElement
    robot: Robot
    objects: tuple[objects.ObjectSpec, ...]
    stacked: tuple[tuple[str, str], ...] = ()
    region_center_xy: tuple[float, float] = names.OBJECT_REGION_CENTER_XY
    region_half_xy: tuple[float, float] = names.OBJECT_REGION_HALF_XY
    support_z: float = names.TABLE_TOP_Z


def look_at_xyaxes(eye: np.ndarray, target: np.ndarray) -> list[float]:
    """MJCF ``xyaxes`` of a camera at ``eye`` looking at ``target`` with world z up.

    MuJoCo cameras look along their -z axis; x is image right, y image up.
    """
    forward = np.asarray(target, float) - np.asarray(eye, float)
    forward /= np.linalg.norm(forward)
    x = np.cross(forward, [0.0, 0.0, 1.0])
    x /= np.linalg.norm(x)
    y = np.cross(x, forward)
    return [*x, *y]


def boresight_quat(eye: np.ndarray, target: np.ndarray) -> list[float]:
    """(w, x, y, z) of a frame whose +z points from ``eye`` to ``target``, +x horizontal."""
    z = np.asarray(target, float) - np.asarray(eye, float)
    z /= np.linalg.norm(z)
    x = np.cross([0.0, 0.0, 1.0], z)
    x /= np.linalg.norm(x)
    y = np.cross(z, x)
    rot = np.column_stack([x, y, z])
    from scipy.spatial.transform import Rotation

    q = Rotation.from_matrix(rot).as_quat()  # (x, y, z, w)
    return [q[3], q[0], q[1], q[2]]


def _workstation(model_name: str) -> tuple[mjcf.RootElement, Robot]:
    root = mjcf.RootElement(model=model_name)
    root.option.timestep = TIMESTEP
    for key, value in CONTACT_OPTIONS.items():
        setattr(root.option, key, value)
    vis_global = getattr(root.visual, "global")
    vis_global.offwidth = 640
    vis_global.offheight = 480
    root.visual.quality.shadowsize = 0
    root.visual.headlight.ambient = (0.35, 0.35, 0.35)
    root.visual.headlight.diffuse = (0.5, 0.5, 0.5)
    root.visual.map.znear = 0.01
    root.statistic.center = (0.0, 0.1, names.TABLE_TOP_Z)
    root.statistic.extent = 1.5

    root.asset.add(
        "texture",
        name="floor_tex",
        type="2d",
        builtin="checker",
        rgb1=(0.3, 0.3, 0.32),
        rgb2=(0.25, 0.25, 0.27),
        width=64,
        height=64,
    )
    floor_mat = root.asset.add("material", name="floor_mat", texture="floor_tex", texrepeat=(8, 8))
    root.worldbody.add("geom", name="floor", type="plane", size=(3, 3, 0.1), material=floor_mat)
    root.worldbody.add(
        "light",
        name="key_light",
        pos=(0.3, -0.6, 2.2),
        dir=(-0.15, 0.35, -1),
        directional=True,
        castshadow=False,
        diffuse=(0.6, 0.6, 0.6),
    )

    table_mat = objects.random_dot_material(
        root,
        "table_mat",
        (0.62, 0.55, 0.45),
        (0.35, 0.28, 0.2),
        density=0.3,
        kind="2d",
        size=256,
        texrepeat=(4, 6),
    )
    table = root.worldbody.add("body", name=names.TABLE, pos=(*TABLE_CENTER_XY, 0.0))
    top_z = names.TABLE_TOP_Z - TABLE_HALF[2]
    table.add(
        "geom",
        name=names.TABLE_TOP_GEOM,
        type="box",
        size=TABLE_HALF,
        pos=(0, 0, top_z),
        material=table_mat,
        friction=objects.OBJECT_FRICTION,
    )
    leg_h = (names.TABLE_TOP_Z - 2 * TABLE_HALF[2]) / 2
    for i, (sx, sy) in enumerate(((1, 1), (1, -1), (-1, 1), (-1, -1))):
        table.add(
            "geom",
            name=f"table_leg_{i}",
            type="box",
            size=(0.03, 0.03, leg_h),
            pos=(sx * (TABLE_HALF[0] - 0.05), sy * (TABLE_HALF[1] - 0.05), leg_h),
            rgba=(0.3, 0.3, 0.3, 1),
        )

    centre = np.array([*names.OBJECT_REGION_CENTER_XY, names.TABLE_TOP_Z])
    root.worldbody.add("site", name=names.OBJECT_REGION, pos=centre, size=(0.005,), group=4)
    _add_sensor_mounts(root, centre)
    robot = add_robot(root)
    return root, robot


def _add_sensor_mounts(root: mjcf.RootElement, centre: np.ndarray) -> None:
    # Overhead: 0.8 m above the table, fovy 32 deg covers ~0.61 x 0.46 m (the scene-1 tray).
    root.worldbody.add(
        "camera",
        name=names.OVERHEAD_CAMERA,
        pos=centre + (0, 0, 0.8),
        fovy=32,
        xyaxes=(1, 0, 0, 0, 1, 0),
    )
    # Stereo pair in front of the table, 45 cm from the region, looking down ~40 deg.
    # Both cameras share one orientation (parallel axes: rectified by construction).
    target = centre + (0, 0, 0.03)
    eye_mid = centre + (0.0, -0.42, 0.36)
    xyaxes = look_at_xyaxes(eye_mid, target)
    x_axis = np.array(xyaxes[:3])
    half_b = names.STEREO_BASELINE_M / 2
    for cam, sign in ((names.STEREO_LEFT, -1), (names.STEREO_RIGHT, 1)):
        root.worldbody.add(
            "camera", name=cam, pos=eye_mid + sign * half_b * x_axis, fovy=45, xyaxes=xyaxes
        )
    eye = centre + (0.42, -0.30, 0.40)
    root.worldbody.add(
        "camera", name=names.DEPTH_CAMERA, pos=eye, fovy=45, xyaxes=look_at_xyaxes(eye, target)
    )
    mounts = (centre + (0.38, -0.28, 0.32), centre + (-0.38, -0.28, 0.32))
    for name, eye in zip(names.RANGE_FINDER_MOUNTS, mounts, strict=True):
        root.worldbody.add(
            "site",
            name=name,
            pos=eye,
            quat=boresight_quat(eye, target),
            type="box",
            size=(0.02, 0.015, 0.01),
            rgba=(0.2, 0.2, 0.25, 1),
            group=4,
        )


def _rest_at(root: mjcf.RootElement, spec: objects.ObjectSpec, xy: tuple[float, float]) -> None:
    """Put ``spec``'s body at rest on the table at ``xy`` (its canonical orientation)."""
    body = root.find("body", spec.name)
    body.pos = (xy[0], xy[1], names.TABLE_TOP_Z + spec.rest_height_m)
    body.quat = spec.rest_quat


def scene2() -> SceneSpec:
    """The cube with the sphere atop it among three clutter objects."""
    root, robot = _workstation("scene2")
    cube = objects.add_cube(root, (0.0, 0.0, 0.0))
    _rest_at(root, cube, (0.0, 0.0))
    sphere = objects.add_sphere(root, (0.0, 0.0, 0.0))
    on_top = names.TABLE_TOP_Z + 2 * cube.rest_height_m + sphere.rest_height_m
    root.find("body", names.SPHERE).pos = (0.0, 0.0, on_top)
    clutter = []
    for i, xy in enumerate(((-0.09, 0.05), (0.08, 0.06), (-0.07, -0.07))):
        clutter.append(objects.add_clutter(root, i, (0.0, 0.0, 0.0)))
        _rest_at(root, clutter[-1], xy)
    return SceneSpec(
        name="scene2",
        root=root,
        robot=robot,
        objects=(cube, sphere, *clutter),
        stacked=((names.SPHERE, names.CUBE),),
    )


def scene1() -> SceneSpec:
    """Dark flat parts on a light tray in the paper's Figure 4-1 layout (``flatparts``)."""
    from mks_sim.sim import flatparts

    root, robot = _workstation("scene1")
    flatparts.add_tray(root)
    specs = tuple(flatparts.add_flat_part(root, part) for part in flatparts.CATALOGUE)
    margin = 0.01
    return SceneSpec(
        name="scene1",
        root=root,
        robot=robot,
        objects=specs,
        region_center_xy=(0.0, 0.0),
        region_half_xy=(flatparts.TRAY_HALF[0] - margin, flatparts.TRAY_HALF[1] - margin),
        support_z=flatparts.TRAY_TOP_Z,
    )


def part_scene() -> SceneSpec:
    """The industrial part alone on the table (yawed so no face is axis-aligned)."""
    root, robot = _workstation("part")
    spec = objects.add_part(root, (0.0, 0.0, 0.0))
    _rest_at(root, spec, (0.0, 0.0))
    root.find("body", names.PART).quat = (np.cos(0.175), 0.0, 0.0, np.sin(0.175))  # yaw 0.35
    return SceneSpec(name="part", root=root, robot=robot, objects=(spec,))


_SCENES: dict[str, Callable[[], SceneSpec]] = {
    "scene1": scene1,
    "scene2": scene2,
    "part": part_scene,
}


def register_scene(name: str, builder: Callable[[], SceneSpec]) -> None:
    """Register a scene builder under ``name``."""
    _SCENES[name] = builder


def build_scene(name: str) -> SceneSpec:
    """Build the MJCF of scene ``name``.

    Raises:
        NotFound: unknown scene name (the message lists the known ones).
    """
    try:
        builder = _SCENES[name]
    except KeyError:
        raise NotFound(f"unknown scene {name!r}; expected one of {sorted(_SCENES)}") from None
    return builder()


def export_scene(name: str, out_dir: str | Path) -> Path:
    """Write scene ``name`` as a standalone MJCF (+ the robot's mesh files) to ``out_dir``.

    For viewing and debugging outside mks_sim, e.g.
    ``python -m mujoco.viewer --mjcf=<out_dir>/<name>.xml``. The objects are at the scene's
    default layout; ``World`` state (arm home pose, randomisation) is not part of the file.

    Returns:
        Path of the written XML file.
    """
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    spec = build_scene(name)
    mjcf.export_with_assets(spec.root, str(out), out_file_name=f"{name}.xml")
    return out / f"{name}.xml"
