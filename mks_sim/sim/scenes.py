"""Scene assembly: the workstation (table, cameras, range-finder mounts, Jaco) + objects.

Scenes are data: ``worlds/<name>.toml`` (schema in ``docs/worlds.md``) names the objects by
their model-database name (``mks_sim.models.objects``) with counts, default layout and pose
randomisation (``upright``: resting on the mesh's base with random x, y, yaw; ``drop``: from
a random orientation, settled by physics onto any stable face), clutter, lights and the table
texture. ``build_scene(name_or_file)`` assembles the MJCF with dm_control's ``mjcf`` and
returns the root, the robot entities and the specs of the objects ``World.randomize`` places.
``default_scene(objects)`` is the scene of objects alone on the table, dropped.

Scenes shipped (paper section 4.1):
    ``scene1``: a light tray of dark flat parts (discs, nuts, washer, plates) seen from
        above -- the paper's Figure 4-1, laid out after Tables 4-1 / 4-3.
    ``scene2``: the cube with the sphere atop it among three clutter objects (Scenes 2, 3).
    ``part``: the industrial part ("Renault piece") alone on the table (Figures 4-9..).
"""

from __future__ import annotations

import math
import os
import tomllib
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
from dm_control import mjcf

from mks_sim.errors import NotFound, SpecError
from mks_sim.sim import flatparts, names, objects
from mks_sim.sim.robot import Robot, add_robot

TABLE_HALF = (0.45, 0.7, 0.02)  # m; the table centre is at y = 0.2 so the arm base fits
TABLE_CENTER_XY = (0.0, 0.2)
TIMESTEP = 0.002
# Contact model for stable grasps: elliptic cones with impratio 10 make friction nearly as
# stiff as the normal constraint (held objects do not creep); a few noslip iterations remove
# the residual drift of soft contacts. Measured slip: see docs/worlds.md.
CONTACT_OPTIONS = dict(cone="elliptic", impratio=10.0, noslip_iterations=4)


POSES = ("upright", "drop")


@dataclass(frozen=True)
class Placement:
    """How one object is randomised.

    Attributes:
        pose: ``"upright"`` (resting on its base, random yaw) or ``"drop"`` (random
            orientation, released just above the support and settled by physics).
        x: world x range of the body origin, or None for the scene's region.
        y: world y range, or None for the region.
        yaw: yaw range, radians.
        gap_m: least clearance between this object's footprint and the others' (negative:
            footprints may overlap; dropped objects then land on each other, a pile).
    """

    pose: str = "upright"
    x: tuple[float, float] | None = None
    y: tuple[float, float] | None = None
    yaw: tuple[float, float] = (-math.pi, math.pi)
    gap_m: float | None = None


@dataclass(frozen=True)
class OutputBox:
    """A walled box on the support that picked parts are placed in (``[output_box]``: the
    bin scene's; scene data, a workcell's layout -- not ground truth).

    Attributes:
        center_xy: world xy of its middle (m).
        half_xy: half sides between the walls' centres (m).
        wall_height_m: the walls' height above the support (its rim).
        wall_thickness_m: the walls' thickness.
    """

    center_xy: tuple[float, float]
    half_xy: tuple[float, float]
    wall_height_m: float
    wall_thickness_m: float

    @property
    def inner_half_xy(self) -> tuple[float, float]:
        """Half sides between the walls' inner faces (m)."""
        t = 0.5 * self.wall_thickness_m
        return self.half_xy[0] - t, self.half_xy[1] - t


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
        placements: body -> how ``World.randomize`` places it (bodies not listed: upright
            anywhere in the region with a uniform yaw).
        source: the scene file (None for scenes built in code).
        flat_parts: the ``[[flat_part]]`` entries (what each flat part is: evaluation's
            scene list, :func:`mks_sim.sim.truth.scene1_manifest`).
        output_box: the ``[output_box]`` picked parts go to (None: the scene has none).
    """

    name: str
    root: mjcf.RootElement
    robot: Robot
    objects: tuple[objects.ObjectSpec, ...]
    stacked: tuple[tuple[str, str], ...] = ()
    region_center_xy: tuple[float, float] = names.OBJECT_REGION_CENTER_XY
    region_half_xy: tuple[float, float] = names.OBJECT_REGION_HALF_XY
    support_z: float = names.TABLE_TOP_Z
    placements: Mapping[str, Placement] = field(default_factory=dict)
    source: Path | None = None
    flat_parts: tuple[flatparts.FlatPart, ...] = ()
    output_box: OutputBox | None = None

    @property
    def models(self) -> dict[str, str]:
        """Body -> database object name, for the database objects of the scene."""
        return {o.name: o.model for o in self.objects if o.model is not None}


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


#: MuJoCo arena per world (``<size memory>``): room for the contacts of a full bin.
ARENA = "64M"


def _workstation(
    model_name: str,
    table_rgb: tuple[float, float, float] = (0.62, 0.55, 0.45),
    table_dots: tuple[float, float, float] = (0.35, 0.28, 0.2),
) -> tuple[mjcf.RootElement, Robot]:
    root = mjcf.RootElement(model=model_name)
    root.option.timestep = TIMESTEP
    # MuJoCo's arena (contacts, constraint solver): the size it derives from the model ran out
    # in a bin of six parts piled against the walls ("mj_stackAlloc: out of memory", bin
    # benchmark seed 3000-3003 at bafc4a2)
    root.size.memory = ARENA
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
        table_rgb,
        table_dots,
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


# --------------------------------------------------------------------------- scene files

_SCENE_KEYS = {"name", "description", "region", "support", "noslip_iterations"}
MAX_NOSLIP_ITERATIONS = 1000
_OBJECT_KEYS = {"name", "count", "at", "yaw_deg", "pose", "x", "y", "yaw", "on", "gap_m"}
_FIXTURE_KEYS = {"size", "at", "z", "rgb"}
_OUTPUT_BOX_KEYS = {"center", "half", "wall_height", "wall_thickness", "rgb"}
_CLUTTER_KEYS = {"shape", "size", "at", "rgb", "dots"}
_LIGHT_KEYS = {"name", "pos", "dir", "diffuse", "directional"}
_TOP_KEYS = {
    "scene", "table", "object", "clutter", "light", "fixture", "tray", "flat_parts", "flat_part",
    "output_box",
}  # fmt: skip


def _pair(v: Any, where: str, key: str) -> tuple[float, float]:
    if (
        not isinstance(v, list)
        or len(v) != 2
        or not all(isinstance(x, int | float) and not isinstance(x, bool) for x in v)
        or not all(math.isfinite(x) for x in v)
    ):
        raise SpecError(f"{where}: field {key!r}: expected [a, b] finite numbers, got {v!r}")
    return float(v[0]), float(v[1])


#: n finite numbers from a scene-file field (the one check, shared with the flat parts).
_vec = flatparts._floats


def _table(v: Any, where: str) -> Mapping[str, Any]:
    if not isinstance(v, Mapping):
        raise SpecError(f"{where}: expected a table, got {v!r}")
    return v


def _tables(doc: Mapping[str, Any], key: str, where: str) -> list[Mapping[str, Any]]:
    v = doc.get(key, [])
    if not isinstance(v, list) or not all(isinstance(e, Mapping) for e in v):
        raise SpecError(f"{where}: '{key}': expected [[{key}]] tables, got {v!r}")
    return v


def _unknown(entry: Mapping[str, Any], allowed: set[str], where: str) -> None:
    _table(entry, where)
    extra = set(entry) - allowed
    if extra:
        raise SpecError(f"{where}: unknown field(s) {sorted(extra)}; allowed: {sorted(allowed)}")


def scene_file(name: str | Path) -> Path:
    """The scene file of ``name``: a path to a ``.toml``, or ``worlds/<name>.toml``.

    Raises:
        NotFound: no such file (the message lists the shipped scenes).
    """
    p = Path(name)
    if p.suffix == ".toml" or p.is_file():
        if not p.is_file():
            raise NotFound(f"scene file not found: {p}")
        return p
    from mks_sim.resources import data_dir

    q = data_dir("worlds") / f"{name}.toml"
    if not q.is_file():
        raise NotFound(
            f"unknown scene {str(name)!r}; expected one of {scene_names()} or a .toml file"
        )
    return q


def scene_names() -> list[str]:
    """The scenes shipped in ``worlds/`` (the scene list is the folder), sorted."""
    from mks_sim.resources import data_dir

    return sorted(p.stem for p in data_dir("worlds").glob("*.toml"))


def scene_objects(name: str | Path) -> list[str]:
    """The database object names a scene file lists (its TOML only; nothing is built)."""
    path = scene_file(name)
    try:
        doc = tomllib.loads(path.read_text(encoding="utf-8"))
    except tomllib.TOMLDecodeError as exc:
        raise SpecError(f"{path}: not valid TOML: {exc}") from exc
    return [str(e.get("name")) for e in doc.get("object", []) if isinstance(e, Mapping)]


def load_scene_file(
    path: str | Path, *, models: Sequence[str | Path] = (), name: str | None = None
) -> SceneSpec:
    """Build the scene described by the TOML file ``path``.

    Args:
        path: the scene file.
        models: extra model folders for database object names (``--models DIR``).
        name: the scene (and MJCF model) name; default the file's ``[scene] name`` or stem.

    Raises:
        SpecError: a malformed file (one line: file, entry, field, expected, got).
        NotFound: the file, or a database object it names, does not exist.
    """
    path = Path(path)
    try:
        doc = tomllib.loads(path.read_text(encoding="utf-8"))
    except FileNotFoundError as exc:
        raise NotFound(f"scene file not found: {path}") from exc
    except tomllib.TOMLDecodeError as exc:
        raise SpecError(f"{path}: not valid TOML: {exc}") from exc
    return scene_from_doc(doc, path, models=models, name=name)


def scene_from_doc(
    doc: Mapping[str, Any],
    path: Path | str,
    *,
    models: Sequence[str | Path] = (),
    name: str | None = None,
) -> SceneSpec:
    """Build a scene from a parsed scene file ``doc`` (``path`` names it in messages)."""
    path = Path(path)
    _unknown(doc, _TOP_KEYS, str(path))
    head = doc.get("scene", {})
    _unknown(head, _SCENE_KEYS, f"{path}: [scene]")
    scene_name = name or head.get("name", path.stem)
    if not isinstance(scene_name, str) or not scene_name:
        raise SpecError(f"{path}: [scene]: field 'name': expected a string, got {scene_name!r}")
    table = doc.get("table", {})
    _unknown(table, {"rgb", "dots"}, f"{path}: [table]")
    root, robot = _workstation(
        scene_name,
        _vec(table.get("rgb", [0.62, 0.55, 0.45]), 3, f"{path}: [table]", "rgb"),  # type: ignore[arg-type]
        _vec(table.get("dots", [0.35, 0.28, 0.2]), 3, f"{path}: [table]", "dots"),  # type: ignore[arg-type]
    )
    for i, light in enumerate(_tables(doc, "light", str(path))):
        where = f"{path}: light {i}"
        _unknown(light, _LIGHT_KEYS, where)
        if not isinstance(light.get("name", ""), str) or not isinstance(
            light.get("directional", False), bool
        ):
            raise SpecError(f"{where}: fields 'name' (a string), 'directional' (true|false)")
        root.worldbody.add(
            "light",
            name=str(light.get("name", f"light_{i}")),
            pos=_vec(light.get("pos", [0.0, 0.0, 2.0]), 3, where, "pos"),
            dir=_vec(light.get("dir", [0.0, 0.0, -1.0]), 3, where, "dir"),
            directional=bool(light.get("directional", False)),
            castshadow=False,
            diffuse=_vec(light.get("diffuse", [0.3, 0.3, 0.3]), 3, where, "diffuse"),
        )
    noslip = head.get("noslip_iterations", CONTACT_OPTIONS["noslip_iterations"])
    if (
        isinstance(noslip, bool)
        or not isinstance(noslip, int)
        or not 0 <= noslip <= MAX_NOSLIP_ITERATIONS
    ):
        raise SpecError(
            f"{path}: [scene]: field 'noslip_iterations': expected an integer in "
            f"0..{MAX_NOSLIP_ITERATIONS}, got {noslip!r}"
        )
    root.option.noslip_iterations = noslip
    support = head.get("support", "table")
    if support not in ("table", "tray"):
        raise SpecError(
            f"{path}: [scene]: field 'support': expected 'table' or 'tray', got {support!r}"
        )
    region_c, region_h = names.OBJECT_REGION_CENTER_XY, names.OBJECT_REGION_HALF_XY
    support_z = names.TABLE_TOP_Z
    specs: list[objects.ObjectSpec] = []
    if support == "tray":
        tray_half, tray_rgba = flatparts.parse_tray(doc, str(path))
        support_z = flatparts.add_tray(root, tray_half, tray_rgba)
        margin = 0.01
        region_c = (0.0, 0.0)
        region_h = (tray_half[0] - margin, tray_half[1] - margin)
    elif "tray" in doc:
        raise SpecError(f"{path}: [tray]: expected [scene] support = 'tray' with it, got {support!r}")  # fmt: skip
    flat_parts = flatparts.parse_flat_parts(doc, str(path))
    specs += [flatparts.add_flat_part(root, part, support_z) for part in flat_parts]
    if "region" in head:
        reg = head["region"]
        _unknown(reg, {"center", "half"}, f"{path}: [scene] region")
        region_c = _pair(reg.get("center", list(region_c)), f"{path}: [scene] region", "center")
        region_h = _pair(reg.get("half", list(region_h)), f"{path}: [scene] region", "half")
    from mks_sim.models.objects import load_object

    placements: dict[str, Placement] = {}
    stacked: list[tuple[str, str]] = []
    for i, entry in enumerate(_tables(doc, "object", str(path))):
        db_name = entry.get("name")
        where = f"{path}: object {db_name!r}" if db_name else f"{path}: object {i}"
        if not isinstance(db_name, str):
            raise SpecError(
                f"{where}: field 'name': expected a database object name, got {db_name!r}"
            )
        _unknown(entry, _OBJECT_KEYS, where)
        obj = load_object(db_name, models=models)
        count = entry.get("count", 1)
        if isinstance(count, bool) or not isinstance(count, int) or count < 1:
            raise SpecError(f"{where}: field 'count': expected an integer >= 1, got {count!r}")
        pose = entry.get("pose", "upright")
        if pose not in POSES:
            raise SpecError(f"{where}: field 'pose': expected one of {list(POSES)}, got {pose!r}")
        yaw = tuple(math.radians(d) for d in _pair(entry.get("yaw", [-180, 180]), where, "yaw"))
        xr = _pair(entry["x"], where, "x") if "x" in entry else None
        yr = _pair(entry["y"], where, "y") if "y" in entry else None
        at = _pair(entry.get("at", list(region_c)), where, "at")
        yaw_deg = entry.get("yaw_deg", 0.0)
        if isinstance(yaw_deg, bool) or not isinstance(yaw_deg, int | float):
            raise SpecError(f"{where}: field 'yaw_deg': expected a number, got {yaw_deg!r}")
        yaw0 = math.radians(float(yaw_deg))
        gap = entry.get("gap_m")
        if gap is not None and (
            isinstance(gap, bool) or not isinstance(gap, int | float) or not math.isfinite(gap)
        ):
            raise SpecError(f"{where}: field 'gap_m': expected a number (metres), got {gap!r}")
        on = entry.get("on")
        if on is not None and not isinstance(on, str):
            raise SpecError(f"{where}: field 'on': expected an object name, got {on!r}")
        for k in range(count):
            body = db_name if k == 0 else f"{db_name}_{k}"
            spec = objects.add_object(root, obj, body_name=body)
            specs.append(spec)
            placements[body] = Placement(
                pose,
                xr,
                yr,
                yaw,  # type: ignore[arg-type]
                None if gap is None else float(gap),
            )
            xy = (at[0] + 2.2 * spec.reach_m * k, at[1])  # copies side by side
            if on is not None:
                below = next((s for s in specs if s.name == on), None)
                if below is None:
                    raise SpecError(
                        f"{where}: field 'on': expected an object listed above, got {on!r}"
                    )
                b = root.find("body", on)
                z = float(b.pos[2]) + below.rest_height_m + spec.rest_height_m
                root.find("body", body).pos = (float(b.pos[0]), float(b.pos[1]), z)
                stacked.append((body, on))
                continue
            root.find("body", body).pos = (xy[0], xy[1], support_z + spec.rest_height_m)
            if yaw0:
                root.find("body", body).quat = (math.cos(yaw0 / 2), 0.0, 0.0, math.sin(yaw0 / 2))
    for i, entry in enumerate(_tables(doc, "fixture", str(path))):
        _add_fixture(root, i, entry, f"{path}: fixture {i}", support_z)
    output_box = None
    if "output_box" in doc:
        output_box = _add_output_box(root, doc["output_box"], f"{path}: [output_box]", support_z)
    for i, entry in enumerate(_tables(doc, "clutter", str(path))):
        where = f"{path}: clutter {i}"
        _unknown(entry, _CLUTTER_KEYS, where)
        spec = _add_clutter(
            root,
            len([s for s in specs if s.model is None and s.name.startswith("clutter_")]),
            entry,
            where,
        )
        specs.append(spec)
        xy = _pair(entry.get("at", [0.0, 0.0]), where, "at")
        root.find("body", spec.name).pos = (xy[0], xy[1], support_z + spec.rest_height_m)
    if not specs:
        raise SpecError(
            f"{path}: expected at least one [[object]], [[clutter]] or [[flat_part]], got none"
        )
    return SceneSpec(
        name=scene_name,
        root=root,
        robot=robot,
        objects=tuple(specs),
        stacked=tuple(stacked),
        region_center_xy=region_c,
        region_half_xy=region_h,
        support_z=support_z,
        placements=placements,
        source=path if path.is_file() else None,
        flat_parts=flat_parts,
        output_box=output_box,
    )


def _add_output_box(root: mjcf.RootElement, entry: Any, where: str, support_z: float) -> OutputBox:
    """The ``[output_box]`` table: four static walls on the support around ``center``,
    ``half`` apart (between the walls' centres), ``wall_height`` high (default 0.06 m),
    ``wall_thickness`` thick (default 0.008 m). Visible to the sensors and collides."""
    _unknown(entry, _OUTPUT_BOX_KEYS, where)
    c = _pair(entry.get("center"), where, "center")
    h = _pair(entry.get("half"), where, "half")
    height = entry.get("wall_height", 0.06)
    thick = entry.get("wall_thickness", 0.008)
    for key, v in (("wall_height", height), ("wall_thickness", thick)):
        if isinstance(v, bool) or not isinstance(v, int | float) or not 0 < v < 1:
            raise SpecError(f"{where}: field {key!r}: expected metres in (0, 1), got {v!r}")
    if min(h) <= float(thick):
        raise SpecError(
            f"{where}: field 'half': expected half sides over the wall thickness "
            f"({thick} m), got {list(h)}"
        )
    rgb = _vec(entry.get("rgb", [0.45, 0.35, 0.3]), 3, where, "rgb")
    hz, ht = 0.5 * float(height), 0.5 * float(thick)
    walls = [  # (half extents, centre): the x walls span the y sides and the corners
        ((ht, h[1] + ht, hz), (c[0] + s * h[0], c[1])) for s in (1.0, -1.0)
    ] + [((h[0] + ht, ht, hz), (c[0], c[1] + s * h[1])) for s in (1.0, -1.0)]
    for i, (size, xy) in enumerate(walls):
        _static_box(root, f"output_box_wall_{i}", size, xy, support_z, rgb)
    return OutputBox(c, h, float(height), float(thick))


def _add_fixture(
    root: mjcf.RootElement, index: int, entry: Mapping[str, Any], where: str, support_z: float
) -> None:
    """One ``[[fixture]]`` entry: a static box (half extents ``size``) standing on the support
    at ``at`` (``z``: its bottom above the support) -- e.g. the walls of a bin. Visible to the
    sensors and collides; not an object (nothing localizes or moves it)."""
    _unknown(entry, _FIXTURE_KEYS, where)
    size = _vec(entry.get("size"), 3, where, "size")
    if min(size) <= 0:
        raise SpecError(f"{where}: field 'size': expected 3 half extents > 0, got {list(size)}")
    xy = _pair(entry.get("at", [0.0, 0.0]), where, "at")
    z = entry.get("z", 0.0)
    if isinstance(z, bool) or not isinstance(z, int | float) or not math.isfinite(z):
        raise SpecError(f"{where}: field 'z': expected a number (metres), got {z!r}")
    rgb = _vec(entry.get("rgb", [0.35, 0.4, 0.5]), 3, where, "rgb")
    _static_box(root, f"fixture_{index}", size, xy, support_z + float(z), rgb)


def _static_box(
    root: mjcf.RootElement,
    name: str,
    size: Sequence[float],
    xy: Sequence[float],
    bottom_z: float,
    rgb: Sequence[float],
) -> None:
    """A static box geom (half extents ``size``) standing at ``xy`` with its bottom at
    ``bottom_z``: visible to the sensors, colliding, never moving (fixtures, box walls)."""
    root.worldbody.add(
        "geom",
        name=name,
        type="box",
        size=list(size),
        pos=(xy[0], xy[1], bottom_z + size[2]),
        rgba=(*rgb, 1.0),
        friction=objects.OBJECT_FRICTION,
    )


def _add_clutter(
    root: mjcf.RootElement, index: int, entry: Mapping[str, Any], where: str
) -> objects.ObjectSpec:
    """One ``[[clutter]]`` entry: a textured cylinder ([radius, half height]) or box (half
    extents), not a database object (nothing localizes it)."""
    shape = entry.get("shape")
    if shape not in ("cylinder", "box"):
        raise SpecError(f"{where}: field 'shape': expected 'cylinder' or 'box', got {shape!r}")
    size = _vec(entry.get("size"), 2 if shape == "cylinder" else 3, where, "size")
    name = f"clutter_{index}"
    mat = objects.random_dot_material(
        root,
        f"{name}_mat",
        _vec(entry.get("rgb", [0.5, 0.5, 0.5]), 3, where, "rgb"),  # type: ignore[arg-type]
        _vec(entry.get("dots", [1.0, 1.0, 1.0]), 3, where, "dots"),  # type: ignore[arg-type]
        size=64,
    )
    body = root.worldbody.add("body", name=name, pos=(0.0, 0.0, 0.0))
    body.add("freejoint", name=names.free_joint(name))
    common = dict(
        material=mat, density=objects.DENSITY_WOOD, friction=objects.OBJECT_FRICTION, condim=4
    )
    body.add("geom", name=f"{name}_geom", type=shape, size=list(size), **common)
    if shape == "cylinder":
        return objects.ObjectSpec(name, "cylinder", size[1], size[0])
    return objects.ObjectSpec(name, "block", size[2], float(np.hypot(size[0], size[1])))


def default_scene(
    object_names: Sequence[str], *, models: Sequence[str | Path] = (), name: str | None = None
) -> SceneSpec:
    """The database objects ``object_names`` alone on the table, each dropped from a random
    orientation (``World.randomize``) anywhere in the object region."""
    if not object_names:
        raise SpecError("default scene: expected at least one object name, got none")
    doc = {
        "scene": {"name": name or "+".join(object_names)},
        "object": [{"name": o, "pose": "drop"} for o in object_names],
    }
    return scene_from_doc(doc, "default scene", models=models)


def default_scene_file(object_names: Sequence[str]) -> Path:
    """A scene file of :func:`default_scene` (the objects alone, dropped), written once to a
    cache folder, for code that names scenes by path (task files, worker processes)."""
    import tempfile

    if not object_names:
        raise SpecError("default scene: expected at least one object name, got none")
    folder = Path(tempfile.gettempdir()) / "mks_sim_scenes"
    folder.mkdir(exist_ok=True)
    name = "+".join(object_names)
    path = folder / f"default_{name}.toml"
    text = f'[scene]\nname = "{name}"\n' + "".join(
        f'[[object]]\nname = "{o}"\npose = "drop"\n' for o in object_names
    )
    if not path.is_file() or path.read_text(encoding="utf-8") != text:
        tmp = path.with_suffix(f".{os.getpid()}.tmp")
        tmp.write_text(text, encoding="utf-8")
        tmp.replace(path)  # atomic: parallel workers never read half a file
    return path


def build_scene(name: str | Path, *, models: Sequence[str | Path] = ()) -> SceneSpec:
    """Build the MJCF of scene ``name``: ``worlds/<name>.toml`` or a scene file path.

    Raises:
        NotFound: unknown scene name (the message lists the known ones).
        SpecError: a malformed scene file.
    """
    return load_scene_file(scene_file(name), models=models)


def scene1() -> SceneSpec:
    """Dark flat parts on a light tray in the paper's Figure 4-1 layout (``worlds/scene1.toml``)."""
    return build_scene("scene1")


def scene2() -> SceneSpec:
    """The cube with the sphere atop it among three clutter objects (``worlds/scene2.toml``)."""
    return build_scene("scene2")


def part_scene() -> SceneSpec:
    """The industrial part alone on the table (``worlds/part.toml``)."""
    return build_scene("part")


def export_scene(
    name: str | Path | SceneSpec, out_dir: str | Path, *, models: Sequence[str | Path] = ()
) -> Path:
    """Write a scene as a standalone MJCF (+ the robot's mesh files) to ``out_dir``.

    For viewing and debugging outside mks_sim, e.g.
    ``python -m mujoco.viewer --mjcf=<out_dir>/<name>.xml``. Object meshes (and their convex
    collision parts) are inlined in the XML. The objects are at the scene's default layout;
    ``World`` state (arm home pose, randomisation) is not part of the file.

    Returns:
        Path of the written XML file.
    """
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    spec = name if isinstance(name, SceneSpec) else build_scene(name, models=models)
    mjcf.export_with_assets(spec.root, str(out), out_file_name=f"{spec.name}.xml")
    return out / f"{spec.name}.xml"
