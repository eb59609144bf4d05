"""Objects as data: the ``[[object]]`` entries of the model database (issue 10).

An object entry says everything the workstation needs to know about a physical object: its
surface mesh (metres, body frame), symmetry, physics, the localization kinds it can be found
with, the logical sensor its default kind needs, the database models it uses, and optional
grasp hints. Sensors, matchers, grasp synthesis, evaluation and the simulator derive what they
need from it; no code names an object.

Entries live in the model database TOML files (``tasks/models/*.toml`` plus the folders given
with ``--models DIR`` and ``MKS_SIM_MODELS``), next to the ``[[model]]`` entries::

    [[object]]
    name = "cube"
    description = "the 5 cm wooden cube"
    mesh = "builtin:box"                 # builtin:box | builtin:uv_sphere |
    mesh_params = { size = 0.05 }        #   builtin:industrial_part | builtin:torus |
                                         #   builtin:blob, or a .stl/.obj/.ply file
                                         #   relative to this TOML
    units = "m"                          # mm | cm | m | in; or scale = S (file units -> m)
    symmetry = "cube"                    # see below
    kinds = ["polyhedral"]               # localization kinds, default first
    sensor = "Vertex_Detector"           # optional; default from the first kind
    models = { rotinv = "cube_5cm" }     # [[model]] entries by kind (optional)
    density = 600.0                      # kg/m^3, or mass = kg (not both)
    friction = [1.0, 0.01, 0.0002]       # MuJoCo sliding, torsional, rolling
    condim = 4                           # MuJoCo contact dimensionality (optional)
    collision = "primitive"              # see below
    rgb = [0.75, 0.2, 0.15]              # appearance (random-dot texture colours)
    dots = [1.0, 0.95, 0.8]
    grasp = { min_clearance_m = 0.012 }  # optional hints for grasp synthesis

``symmetry``: ``"none"``; ``"cube"`` (the 24 rotations of a cube centred at the origin);
``"spherical"`` (orientation not observable); ``"detect"`` (rotations that map the mesh onto
itself, found at load time); a table ``{ axis = [x, y, z], order = N, flip = false }`` (the
cyclic group of N rotations about ``axis`` through the origin, ``order = 0`` = continuous,
sampled every degree; ``flip`` adds the 180-degree turns about an axis perpendicular to it);
or a list ``[[ax, ay, az, angle_deg], ...]`` of rotations (the identity is added).

``collision``: ``"primitive"`` (the builtin box / sphere as a MuJoCo primitive);
``"mesh"`` (the surface mesh itself, convex); ``"builtin:industrial_part"`` (the part's
hand-made convex decomposition); or a list of convex part mesh files (``objects add`` writes
these with CoACD).
"""

from __future__ import annotations

import functools
import math
import os
import tomllib
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from types import MappingProxyType
from typing import Any

import numpy as np
from numpy.typing import NDArray

from mks_sim.errors import NotFound, SpecError
from mks_sim.geometry.meshes import Mesh

__all__ = [
    "BUILTIN_MESHES",
    "KIND_SENSORS",
    "KINDS",
    "UNITS",
    "ObjectModel",
    "builtin_models_dir",
    "load_object",
    "load_objects",
    "models_dirs",
    "object_names",
    "parse_symmetry",
]

FloatArray = NDArray[np.float64]

#: Environment variable holding extra model folders (``os.pathsep``-separated).
MODELS_ENV = "MKS_SIM_MODELS"
#: Localization kinds an object can declare.
KINDS = ("polyhedral", "rotinv", "sphere", "freeform")
#: The logical sensor a kind needs when the entry names none.
KIND_SENSORS: Mapping[str, str] = MappingProxyType(
    {
        "polyhedral": "Vertex_Detector",
        "rotinv": "Control_Point_Detector",
        "sphere": "Sphere_Detector",
        "freeform": "Range_Points",
    }
)
#: Length units of mesh files -> metres.
UNITS: Mapping[str, float] = MappingProxyType({"mm": 1e-3, "cm": 1e-2, "m": 1.0, "in": 0.0254})
#: Built-in meshes (``mesh = "builtin:<name>"``) and their parameters.
BUILTIN_MESHES: Mapping[str, tuple[str, ...]] = MappingProxyType(
    {
        "box": ("size",),
        "uv_sphere": ("radius",),
        "industrial_part": (),
        "torus": ("major_radius", "minor_radius"),
        "blob": (),
    }
)
SYMMETRY_NAMES = ("none", "cube", "spherical", "detect")
COLLISIONS = ("primitive", "mesh", "builtin:industrial_part")
DEFAULT_DENSITY = 600.0  # kg/m^3 (wood): light objects the Jaco handles easily
DEFAULT_FRICTION = (1.0, 0.01, 0.0002)
DEFAULT_RGB = (0.6, 0.6, 0.62)
DEFAULT_DOTS = (0.15, 0.15, 0.18)

_ALLOWED = frozenset(
    {
        "name",
        "description",
        "mesh",
        "mesh_params",
        "units",
        "scale",
        "symmetry",
        "kinds",
        "sensor",
        "models",
        "density",
        "mass",
        "friction",
        "condim",
        "collision",
        "inertia",
        "rgb",
        "dots",
        "grasp",
        "decomposition",
    }
)


@dataclass(frozen=True, eq=False)
class ObjectModel:
    """One object of the model database.

    Attributes:
        name: database name (also the simulator body name).
        mesh: surface mesh, metres, body (object) frame.
        symmetries: (S, 4, 4) object-frame transforms mapping the object onto itself, the
            identity first (just the identity for ``"none"`` and ``"spherical"``).
        symmetry: how they were given: ``"none"``, ``"cube"``, ``"spherical"`` (orientation
            not observable: compare positions only), ``"axial"``, ``"declared"``,
            ``"detected"``.
        kinds: localization kinds, default first.
        sensor: the logical sensor the default kind needs.
        models: database ``[[model]]`` names by kind.
        density: kg/m^3 (None when ``mass`` is given).
        mass: kg (None when ``density`` is given).
        friction: MuJoCo (sliding, torsional, rolling).
        condim: MuJoCo contact dimensionality.
        grasp: grasp hints (free-form table, read by grasp synthesis).
        source: the TOML file of the entry (None for entries built in code).
        mesh_spec: the entry's ``mesh`` value (``"builtin:box"`` or the resolved file path).
        mesh_params: parameters of a builtin mesh.
        collision: ``"primitive"``, ``"mesh"``, ``"builtin:industrial_part"`` or the convex
            part files (absolute paths, metres, body frame).
        inertia: ``"exact"`` (from the mesh) or ``"convex"`` (MuJoCo's meaning).
        rgb: base colour of the random-dot texture, 0..1.
        dots: dot colour, 0..1.
        description: free text.
    """

    name: str
    mesh: Mesh
    symmetries: FloatArray
    symmetry: str = "none"
    kinds: tuple[str, ...] = ("polyhedral",)
    sensor: str = KIND_SENSORS["polyhedral"]
    models: Mapping[str, str] = field(default_factory=lambda: MappingProxyType({}))
    density: float | None = DEFAULT_DENSITY
    mass: float | None = None
    friction: tuple[float, float, float] = DEFAULT_FRICTION
    condim: int = 4
    grasp: Mapping[str, Any] = field(default_factory=lambda: MappingProxyType({}))
    source: Path | None = None
    mesh_spec: str = ""
    mesh_params: Mapping[str, float] = field(default_factory=lambda: MappingProxyType({}))
    collision: str | tuple[Path, ...] = "mesh"
    inertia: str = "exact"
    rgb: tuple[float, float, float] = DEFAULT_RGB
    dots: tuple[float, float, float] = DEFAULT_DOTS
    description: str = ""

    @property
    def kind(self) -> str:
        """The default localization kind."""
        return self.kinds[0]

    @property
    def orientation_observable(self) -> bool:
        """False for a sphere: any rotation is a symmetry."""
        return self.symmetry != "spherical"

    @property
    def rotations(self) -> FloatArray:
        """(S, 3, 3) rotation parts of :attr:`symmetries`."""
        return self.symmetries[:, :3, :3]

    @property
    def primitive(self) -> str | None:
        """``"box"`` / ``"sphere"`` when the mesh is that builtin primitive, else None."""
        return {"builtin:box": "box", "builtin:uv_sphere": "sphere"}.get(self.mesh_spec)

    @property
    def extent_m(self) -> float:
        """The largest bounding-box side of the mesh (metres)."""
        v = self.mesh.vertices
        return float(np.max(v.max(axis=0) - v.min(axis=0)))

    def model(self, kind: str | None = None, *, db: Any = None) -> Any:
        """The database model this object uses for ``kind`` (default: the first of its kinds
        that names one, else the first model listed).

        Args:
            kind: a localization kind listed in :attr:`models`.
            db: a :class:`~mks_sim.models.database.ModelDatabase` (default: the database of
                the folder holding this entry plus the built-in one).

        Raises:
            NotFound: the object names no model for ``kind``.
        """
        if kind is None:
            listed = [k for k in self.kinds if k in self.models] + list(self.models)
            kind = listed[0] if listed else self.kind
        if kind not in self.models:
            raise NotFound(
                f"object {self.name!r}: no database model for kind {kind!r}; "
                f"it names {dict(self.models)}"
            )
        if db is None:
            from mks_sim.models.database import ModelDatabase

            extra = (self.source.parent,) if self.source is not None else ()
            db = ModelDatabase.from_dirs(models_dirs(extra))
        return db.get(self.models[kind])


# --------------------------------------------------------------------------- folders


def builtin_models_dir() -> Path:
    """The built-in model database folder (``tasks/models``)."""
    from mks_sim.resources import data_dir

    return data_dir("tasks") / "models"


def models_dirs(extra: Sequence[str | Path] | str | Path = ()) -> list[Path]:
    """The model folders, in search order: built-in, ``extra`` (``--models DIR``), then
    ``MKS_SIM_MODELS`` (``os.pathsep``-separated); duplicates dropped.

    Raises:
        NotFound: an extra folder does not exist.
    """
    if isinstance(extra, str | Path):
        extra = (extra,)
    env = [p for p in os.environ.get(MODELS_ENV, "").split(os.pathsep) if p.strip()]
    out: list[Path] = []
    for i, p in enumerate([builtin_models_dir(), *extra, *env]):
        q = Path(p).expanduser()
        if not q.is_dir():
            where = "--models" if 0 < i <= len(extra) else MODELS_ENV
            raise NotFound(f"{where}: expected a model folder, got {str(p)!r} (not a directory)")
        q = q.resolve()
        if q not in out:
            out.append(q)
    return out


# --------------------------------------------------------------------------- symmetries


def _axis_angle(axis: Any, deg: float) -> FloatArray:
    from scipy.spatial.transform import Rotation

    a = np.asarray(axis, dtype=np.float64)
    a = a / np.linalg.norm(a)
    return Rotation.from_rotvec(a * math.radians(deg)).as_matrix()


def _to_4x4(rots: FloatArray) -> FloatArray:
    out = np.tile(np.eye(4), (len(rots), 1, 1))
    out[:, :3, :3] = rots
    return out


def _with_identity_first(rots: FloatArray) -> FloatArray:
    rots = np.asarray(rots, dtype=np.float64).reshape(-1, 3, 3)
    keep = [R for R in rots if not np.allclose(R, np.eye(3), atol=1e-9)]
    return np.concatenate([np.eye(3)[None], np.asarray(keep).reshape(-1, 3, 3)])


def parse_symmetry(spec: Any, mesh: Mesh | None, where: str) -> tuple[str, FloatArray]:
    """An entry's ``symmetry`` value -> (its name, (S, 4, 4) transforms, identity first).

    Raises:
        SpecError: a malformed value (the message names the accepted forms).
    """
    accepted = (
        "expected 'none' | 'cube' | 'spherical' | 'detect', a table {axis, order, flip} "
        "or a list of [ax, ay, az, angle_deg]"
    )
    if spec is None or spec == "none" or spec == "spherical":
        return ("none" if spec is None else spec), np.eye(4)[None]
    if spec == "cube":
        from mks_sim.geometry.transforms import cube_rotations

        return "cube", _to_4x4(cube_rotations())
    if spec == "detect":
        if mesh is None:
            raise SpecError(f"{where}: field 'symmetry': 'detect' needs a mesh")
        from mks_sim.models.symmetry import detect_symmetries

        return "detected", detect_symmetries(mesh)
    if isinstance(spec, Mapping):
        unknown = set(spec) - {"axis", "order", "flip"}
        axis = spec.get("axis")
        order = spec.get("order", 0)
        flip = spec.get("flip", False)
        if (
            unknown
            or not isinstance(axis, list)
            or len(axis) != 3
            or not all(isinstance(a, int | float) for a in axis)
            or not np.linalg.norm(axis) > 0
            or isinstance(order, bool)
            or not isinstance(order, int)
            or order < 0
            or not isinstance(flip, bool)
        ):
            raise SpecError(
                f"{where}: field 'symmetry': expected {{axis = [x, y, z], order = N >= 0, "
                f"flip = true|false}}, got {dict(spec)!r}"
            )
        n = order if order > 0 else 360
        rots = [_axis_angle(axis, 360.0 * k / n) for k in range(n)]
        if flip:
            a = np.asarray(axis, float) / np.linalg.norm(axis)
            perp = np.cross(a, [1.0, 0.0, 0.0])
            if np.linalg.norm(perp) < 1e-6:
                perp = np.cross(a, [0.0, 1.0, 0.0])
            F = _axis_angle(perp, 180.0)
            rots += [R @ F for R in rots]
        return ("axial" if order == 0 else "declared"), _to_4x4(
            _with_identity_first(np.array(rots))
        )
    if isinstance(spec, list):
        rots = []
        for i, row in enumerate(spec):
            if (
                not isinstance(row, list)
                or len(row) != 4
                or not all(isinstance(x, int | float) and not isinstance(x, bool) for x in row)
                or not np.linalg.norm(row[:3]) > 0
            ):
                raise SpecError(
                    f"{where}: field 'symmetry'[{i}]: expected [ax, ay, az, angle_deg], got {row!r}"
                )
            rots.append(_axis_angle(row[:3], float(row[3])))
        return "declared", _to_4x4(_with_identity_first(np.array(rots)))
    raise SpecError(f"{where}: field 'symmetry': {accepted}, got {spec!r}")


# --------------------------------------------------------------------------- meshes


def builtin_mesh(name: str, params: Mapping[str, float], where: str = "builtin mesh") -> Mesh:
    """A builtin mesh by name (``box``, ``uv_sphere``, ``industrial_part``, ``torus``,
    ``blob``) with its parameters (metres).

    Raises:
        SpecError: unknown name or parameter.
    """
    from mks_sim.geometry import meshes

    if name not in BUILTIN_MESHES:
        raise SpecError(
            f"{where}: field 'mesh': unknown builtin mesh {name!r}; "
            f"known: {['builtin:' + n for n in BUILTIN_MESHES]}"
        )
    unknown = set(params) - set(BUILTIN_MESHES[name])
    if unknown:
        raise SpecError(
            f"{where}: field 'mesh_params': unknown parameter(s) {sorted(unknown)} for "
            f"builtin:{name}; allowed: {list(BUILTIN_MESHES[name])}"
        )
    p = {k: float(v) for k, v in params.items()}
    if name == "box":
        return meshes.box_mesh(p.get("size", 0.05))
    if name == "uv_sphere":
        return meshes.uv_sphere(p.get("radius", 0.03))
    if name == "industrial_part":
        return meshes.industrial_part_mesh()
    if name == "torus":
        return meshes.torus_mesh(p.get("major_radius", 0.04), p.get("minor_radius", 0.012))
    return meshes.blob_mesh()


def _scaled(mesh: Mesh, s: float) -> Mesh:
    return mesh if s == 1.0 else Mesh(mesh.vertices * s, mesh.faces)


# --------------------------------------------------------------------------- parsing


def _number(entry: Mapping[str, Any], key: str, where: str, *, positive: bool = True) -> float:
    v = entry[key]
    if isinstance(v, bool) or not isinstance(v, int | float) or not math.isfinite(v):
        raise SpecError(f"{where}: field {key!r}: expected a number, got {v!r}")
    if positive and not v > 0:
        raise SpecError(f"{where}: field {key!r}: expected a number > 0, got {v!r}")
    return float(v)


def _triple(entry: Mapping[str, Any], key: str, where: str, default: Any) -> tuple[float, ...]:
    v = entry.get(key, default)
    if (
        not isinstance(v, list | tuple)
        or len(v) != 3
        or not all(isinstance(x, int | float) and not isinstance(x, bool) for x in v)
        or not all(x >= 0 for x in v)
    ):
        raise SpecError(f"{where}: field {key!r}: expected 3 numbers >= 0, got {v!r}")
    return tuple(float(x) for x in v)


def parse_object(entry: Mapping[str, Any], where: str, base: Path | None) -> ObjectModel:
    """One ``[[object]]`` table -> :class:`ObjectModel`.

    Args:
        entry: the table.
        where: ``"<file>: object '<name>'"`` for messages.
        base: folder relative mesh paths start from (the TOML file's folder).

    Raises:
        SpecError: an unknown or malformed field (one line naming file, entry and field).
        NotFound: a mesh file that does not exist.
    """
    unknown = set(entry) - _ALLOWED
    if unknown:
        raise SpecError(f"{where}: unknown field(s) {sorted(unknown)}; allowed: {sorted(_ALLOWED)}")
    name = entry.get("name")
    if not isinstance(name, str) or not name or not name.replace("_", "").isalnum():
        raise SpecError(f"{where}: field 'name': expected letters, digits and _, got {name!r}")
    # --- mesh
    mesh_value = entry.get("mesh")
    if not isinstance(mesh_value, str) or not mesh_value:
        raise SpecError(f"{where}: field 'mesh': expected 'builtin:<name>' or a mesh file")
    params = entry.get("mesh_params", {})
    if not isinstance(params, Mapping) or not all(
        isinstance(v, int | float) and not isinstance(v, bool) and v > 0 for v in params.values()
    ):
        raise SpecError(f"{where}: field 'mesh_params': expected a table of numbers > 0")
    if "units" in entry and "scale" in entry:
        raise SpecError(f"{where}: fields 'units' and 'scale': give one, not both")
    scale = 1.0
    if "units" in entry:
        if entry["units"] not in UNITS:
            raise SpecError(
                f"{where}: field 'units': expected one of {list(UNITS)}, got {entry['units']!r}"
            )
        scale = UNITS[entry["units"]]
    elif "scale" in entry:
        scale = _number(entry, "scale", where)
    if mesh_value.startswith("builtin:"):
        mesh = builtin_mesh(mesh_value.split(":", 1)[1], params, where)
        mesh_spec = mesh_value
    else:
        if params:
            raise SpecError(f"{where}: field 'mesh_params': only for builtin meshes")
        path = Path(mesh_value)
        if not path.is_absolute() and base is not None:
            path = base / path
        from mks_sim.io.mesh import read_mesh

        mesh = read_mesh(path)
        mesh_spec = str(path)
    mesh = _scaled(mesh, scale)
    # --- symmetry
    sym_name, syms = parse_symmetry(entry.get("symmetry", "none"), mesh, where)
    # --- kinds, sensor, models
    kinds = entry.get("kinds", ["polyhedral"])
    if (
        not isinstance(kinds, list)
        or not kinds
        or not all(k in KINDS for k in kinds)
        or len(set(kinds)) != len(kinds)
    ):
        raise SpecError(
            f"{where}: field 'kinds': expected a non-empty list of distinct kinds from "
            f"{list(KINDS)}, got {kinds!r}"
        )
    sensor = entry.get("sensor", KIND_SENSORS[kinds[0]])
    if not isinstance(sensor, str) or not sensor:
        raise SpecError(f"{where}: field 'sensor': expected a logical sensor name, got {sensor!r}")
    models = entry.get("models", {})
    if not isinstance(models, Mapping) or not all(
        k in KINDS and isinstance(v, str) and v for k, v in models.items()
    ):
        raise SpecError(
            f"{where}: field 'models': expected a table kind = \"model name\" with kinds from "
            f"{list(KINDS)}, got {models!r}"
        )
    # --- physics
    if "density" in entry and "mass" in entry:
        raise SpecError(f"{where}: fields 'density' and 'mass': give one, not both")
    mass = _number(entry, "mass", where) if "mass" in entry else None
    density = None
    if mass is None:
        density = _number(entry, "density", where) if "density" in entry else DEFAULT_DENSITY
    friction = _triple(entry, "friction", where, DEFAULT_FRICTION)
    condim = entry.get("condim", 4)
    if condim not in (1, 3, 4, 6):
        raise SpecError(f"{where}: field 'condim': expected 1, 3, 4 or 6, got {condim!r}")
    inertia = entry.get("inertia", "exact")
    if inertia not in ("exact", "convex", "shell", "legacy"):
        raise SpecError(
            f"{where}: field 'inertia': expected 'exact' | 'convex' | 'shell' | 'legacy', "
            f"got {inertia!r}"
        )
    # --- collision
    collision: str | tuple[Path, ...]
    col = entry.get(
        "collision", "primitive" if mesh_spec in ("builtin:box", "builtin:uv_sphere") else "mesh"
    )
    if isinstance(col, str):
        if col not in COLLISIONS:
            raise SpecError(
                f"{where}: field 'collision': expected one of {list(COLLISIONS)} or a list of "
                f"convex part files, got {col!r}"
            )
        if col == "primitive" and mesh_spec not in ("builtin:box", "builtin:uv_sphere"):
            raise SpecError(
                f"{where}: field 'collision': 'primitive' needs mesh builtin:box or "
                f"builtin:uv_sphere, got {mesh_value!r}"
            )
        collision = col
    elif isinstance(col, list) and col and all(isinstance(c, str) for c in col):
        parts = []
        for c in col:
            q = Path(c)
            q = q if q.is_absolute() or base is None else base / q
            if not q.is_file():
                raise NotFound(f"{where}: field 'collision': part file not found: {q}")
            parts.append(q)
        collision = tuple(parts)
    else:
        raise SpecError(
            f"{where}: field 'collision': expected a name or a list of files, got {col!r}"
        )
    grasp = entry.get("grasp", {})
    if not isinstance(grasp, Mapping):
        raise SpecError(f"{where}: field 'grasp': expected a table of hints, got {grasp!r}")
    desc = entry.get("description", "")
    if not isinstance(desc, str):
        raise SpecError(f"{where}: field 'description': expected a string, got {desc!r}")
    return ObjectModel(
        name=name,
        mesh=mesh,
        symmetries=syms,
        symmetry=sym_name,
        kinds=tuple(kinds),
        sensor=sensor,
        models=MappingProxyType(dict(models)),
        density=density,
        mass=mass,
        friction=friction,  # type: ignore[arg-type]
        condim=int(condim),
        grasp=MappingProxyType(dict(grasp)),
        source=None if base is None else Path(where.split(": object ")[0]),
        mesh_spec=mesh_spec,
        mesh_params=MappingProxyType({k: float(v) for k, v in params.items()}),
        collision=collision,
        inertia=inertia,
        rgb=_triple(entry, "rgb", where, DEFAULT_RGB),  # type: ignore[arg-type]
        dots=_triple(entry, "dots", where, DEFAULT_DOTS),  # type: ignore[arg-type]
        description=desc,
    )


def _object_entries(path: Path) -> list[Mapping[str, Any]]:
    try:
        doc = tomllib.loads(path.read_text(encoding="utf-8"))
    except tomllib.TOMLDecodeError as exc:
        raise SpecError(f"{path}: not valid TOML: {exc}") from exc
    entries = doc.get("object", [])
    if not isinstance(entries, list) or not all(isinstance(e, Mapping) for e in entries):
        raise SpecError(f"{path}: 'object': expected [[object]] tables, got {entries!r}")
    return entries


@functools.lru_cache(maxsize=16)
def _load_all(dirs: tuple[Path, ...], stamp: tuple[float, ...]) -> dict[str, ObjectModel]:
    del stamp  # part of the cache key only: an edited file is read again
    out: dict[str, ObjectModel] = {}
    for folder in dirs:
        for path in sorted(folder.glob("*.toml")):
            for j, entry in enumerate(_object_entries(path)):
                name = entry.get("name")
                where = (
                    f"{path}: object {name!r}" if isinstance(name, str) else f"{path}: object {j}"
                )
                obj = parse_object(entry, where, path.parent)
                if obj.name in out:
                    raise SpecError(
                        f"{where}: duplicate object name (first defined in {out[obj.name].source})"
                    )
                out[obj.name] = obj
    return out


def _stamp(dirs: Sequence[Path]) -> tuple[float, ...]:
    return tuple(p.stat().st_mtime for d in dirs for p in sorted(d.glob("*.toml")))


def load_objects(models: Sequence[str | Path] | str | Path = ()) -> dict[str, ObjectModel]:
    """All objects of the database folders (:func:`models_dirs` of ``models``), by name."""
    dirs = tuple(models_dirs(models))
    return dict(_load_all(dirs, _stamp(dirs)))


def object_names(models: Sequence[str | Path] | str | Path = ()) -> list[str]:
    """The object names of the database, sorted."""
    return sorted(load_objects(models))


def load_object(name: str, *, models: Sequence[str | Path] | str | Path = ()) -> ObjectModel:
    """The object ``name`` of the model database.

    Args:
        name: object name (``"cube"``, ``"sphere"``, ``"part"``, or one added with
            ``mks-sim objects add``).
        models: extra model folders (``--models DIR``), searched after the built-in one and
            before ``MKS_SIM_MODELS``.

    Raises:
        NotFound: no object of that name (the message lists the known ones).
        SpecError: a malformed entry in one of the folders.
    """
    objs = load_objects(models)
    try:
        return objs[name]
    except KeyError:
        raise NotFound(
            f"object {name!r} not in the model database; known objects: {sorted(objs)}"
        ) from None
