"""Task files: which scene, which model, which matcher, and what to do with the result.

A task file (``tasks/*.toml``) holds one or more ``[[task]]`` entries::

    [[task]]
    name = "grasp_cube"
    description = "Localize the 5 cm cube and pick it up"
    scene = "cube"            # a world scene, built by mks_sim.sim.build_world(scene, seed)
    object = "cube"           # the object's name in that world
    remove = ["sphere"]       # optional: objects taken off the table at set-up (scene 2's
                              # sphere sits on the cube; the demo grasps it away instead)
    model = "cube_5cm"        # an entry of the model database (tasks/models/)
    matcher = "polyhedral"    # optional: the localization kind, one of the object's kinds
                              # in the model database (default: its first kind)

    [task.action]             # what the task does with the localization
    kind = "grasp"
    grasp_type = "antipodal"  # grasps synthesised from the model's mesh (tasks/grasp.py)
    approach_height_m = 0.12  # pre-grasp height of the pinch point above the grasp point
    lift_height_m = 0.10
    retries = 2               # re-localize and try again at most this many times

Loading is strict: an unknown key, a missing key, a value of the wrong type or out of range
raises :class:`~mks_sim.errors.SpecError` naming the file, the entry and the field.
"""

from __future__ import annotations

import tomllib
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from mks_sim.errors import NotFound, SpecError
from mks_sim.resources import data_dir

GRASP_TYPES = ("antipodal",)
ACTION_KINDS = ("grasp",)
#: Localization kinds a task's ``matcher`` may name (each object lists its own).
MATCHERS = ("polyhedral", "rotinv", "sphere", "freeform")


@dataclass(frozen=True)
class GraspAction:
    """The grasp parameters of a task.

    Attributes:
        grasp_type: ``antipodal``: top-down antipodal grasps synthesised from the object's
            mesh in the model database (:func:`mks_sim.tasks.grasp.synthesize_grasps`).
        approach_height_m: height of the pre-grasp pinch point above the grasp point, metres.
        lift_height_m: how far the object is lifted, metres.
        retries: how many times a failed grasp is re-localized and retried (0 = one attempt).
    """

    kind: str = "grasp"
    grasp_type: str = "antipodal"
    approach_height_m: float = 0.12
    lift_height_m: float = 0.10
    retries: int = 2


@dataclass(frozen=True)
class TaskSpec:
    """One task entry of a task file.

    Attributes:
        name: unique task name.
        scene: world scene name (``mks_sim.sim.build_world``).
        object: name of the object in that world.
        model: model database entry to localize.
        matcher: the localization kind (one of the object's ``kinds`` in the model
            database; its first kind when the file names none).
        action: what to do with the localization.
        description: free text.
        source: the file the task came from.
        remove: objects taken out of the scene at set-up, before anything is sensed.
    """

    name: str
    scene: str
    object: str
    model: str
    matcher: str
    action: GraspAction
    description: str = ""
    source: str = ""
    remove: tuple[str, ...] = ()


_TASK_KEYS = {"name", "description", "scene", "object", "model", "matcher", "action", "remove"}
_ACTION_FIELDS: dict[str, type] = {
    "kind": str,
    "grasp_type": str,
    "approach_height_m": float,
    "lift_height_m": float,
    "retries": int,
}


def _err(path: Path | str, entry: str, field: str, msg: str) -> SpecError:
    return SpecError(f"{path}: task {entry!r}, field {field!r}: {msg}")


def _get_str(raw: dict[str, Any], key: str, path: Path | str, entry: str) -> str:
    if key not in raw:
        raise _err(path, entry, key, "missing (expected a string)")
    value = raw[key]
    if not isinstance(value, str) or not value:
        raise _err(path, entry, key, f"expected a non-empty string, got {value!r}")
    return value


def _parse_action(raw: Any, path: Path | str, entry: str) -> GraspAction:
    if not isinstance(raw, dict):
        raise _err(path, entry, "action", f"expected a table [task.action], got {raw!r}")
    unknown = set(raw) - set(_ACTION_FIELDS)
    if unknown:
        raise _err(
            path,
            entry,
            f"action.{sorted(unknown)[0]}",
            f"unknown key; expected one of {sorted(_ACTION_FIELDS)}",
        )
    values: dict[str, Any] = {}
    for key, typ in _ACTION_FIELDS.items():
        if key not in raw:
            continue
        value = raw[key]
        if typ is float and isinstance(value, int) and not isinstance(value, bool):
            value = float(value)
        if not isinstance(value, typ) or isinstance(value, bool):
            raise _err(path, entry, f"action.{key}", f"expected {typ.__name__}, got {value!r}")
        values[key] = value
    action = GraspAction(**values)
    if action.kind not in ACTION_KINDS:
        raise _err(
            path, entry, "action.kind", f"expected one of {ACTION_KINDS}, got {action.kind!r}"
        )
    if action.grasp_type not in GRASP_TYPES:
        raise _err(
            path,
            entry,
            "action.grasp_type",
            f"expected one of {GRASP_TYPES}, got {action.grasp_type!r}",
        )
    for key, low, high in (
        ("approach_height_m", 0.02, 0.5),
        ("lift_height_m", 0.0, 0.5),
    ):
        value = getattr(action, key)
        if not low <= value <= high:
            raise _err(
                path, entry, f"action.{key}", f"expected {low} <= value <= {high}, got {value}"
            )
    if not 0 <= action.retries <= 10:
        raise _err(
            path, entry, "action.retries", f"expected 0 <= retries <= 10, got {action.retries}"
        )
    return action


def parse_task(raw: Any, path: Path | str = "<string>", index: int = 0) -> TaskSpec:
    """Validate one raw ``[[task]]`` table and return its :class:`TaskSpec`.

    Raises:
        SpecError: naming ``path``, the entry (task name or ``#index``) and the field.
    """
    if not isinstance(raw, dict):
        raise _err(path, f"#{index}", "", f"expected a table, got {type(raw).__name__}")
    raw_name = raw.get("name")
    entry: str = raw_name if isinstance(raw_name, str) else f"#{index}"
    unknown = set(raw) - _TASK_KEYS
    if unknown:
        raise _err(
            path, entry, sorted(unknown)[0], f"unknown key; expected one of {sorted(_TASK_KEYS)}"
        )
    name = _get_str(raw, "name", path, entry)
    obj_name = _get_str(raw, "object", path, entry)
    from mks_sim.models.objects import load_object

    kinds = load_object(obj_name).kinds  # NotFound lists the database's objects
    matcher = _get_str(raw, "matcher", path, entry) if "matcher" in raw else kinds[0]
    if matcher not in kinds:
        raise _err(
            path, entry, "matcher", f"expected one of object {obj_name!r}'s kinds {list(kinds)}, got {matcher!r}"
        )
    description = raw.get("description", "")
    if not isinstance(description, str):
        raise _err(path, entry, "description", f"expected a string, got {description!r}")
    remove = raw.get("remove", [])
    if not isinstance(remove, list) or not all(isinstance(r, str) and r for r in remove):
        raise _err(path, entry, "remove", f"expected a list of object names, got {remove!r}")
    if "action" not in raw:
        raise _err(path, entry, "action", "missing (expected a table [task.action])")
    return TaskSpec(
        name=name,
        scene=_get_str(raw, "scene", path, entry),
        object=obj_name,
        model=_get_str(raw, "model", path, entry),
        matcher=matcher,
        action=_parse_action(raw["action"], path, entry),
        description=description,
        source=str(path),
        remove=tuple(remove),
    )


def load_task_file(path: str | Path) -> list[TaskSpec]:
    """Read every ``[[task]]`` of one TOML file.

    Raises:
        SpecError: unreadable TOML, no ``[[task]]`` entries, or a bad entry.
    """
    path = Path(path)
    try:
        with path.open("rb") as fh:
            doc = tomllib.load(fh)
    except OSError as exc:
        raise SpecError(f"{path}: cannot read task file: {exc}") from exc
    except tomllib.TOMLDecodeError as exc:
        raise SpecError(f"{path}: not valid TOML: {exc}") from exc
    unknown = set(doc) - {"task"}
    if unknown:
        raise SpecError(f"{path}: unknown top-level key {sorted(unknown)[0]!r}; expected [[task]]")
    entries = doc.get("task")
    if not isinstance(entries, list) or not entries:
        raise SpecError(f"{path}: expected at least one [[task]] entry, got {entries!r}")
    tasks = [parse_task(raw, path, i) for i, raw in enumerate(entries)]
    names = [t.name for t in tasks]
    for name in names:
        if names.count(name) > 1:
            raise _err(path, name, "name", "duplicate task name")
    return tasks


def load_tasks(folder: str | Path | None = None) -> dict[str, TaskSpec]:
    """All tasks of the ``*.toml`` files directly in ``folder`` (default ``data_dir("tasks")``).

    The model database (``tasks/models/``) is a sub-folder and is not read here.
    """
    folder = Path(folder) if folder is not None else data_dir("tasks")
    tasks: dict[str, TaskSpec] = {}
    for path in sorted(folder.glob("*.toml")):
        for task in load_task_file(path):
            if task.name in tasks:
                raise _err(
                    path, task.name, "name", f"duplicate of the task in {tasks[task.name].source}"
                )
            tasks[task.name] = task
    return tasks


def get_task(name: str, folder: str | Path | None = None) -> TaskSpec:
    """The task called ``name``.

    Raises:
        NotFound: no such task (the message lists the known ones).
    """
    tasks = load_tasks(folder)
    if name not in tasks:
        raise NotFound(f"task {name!r} not found; known tasks: {sorted(tasks)}")
    return tasks[name]


def task_for_object(obj: str, folder: str | Path | None = None) -> TaskSpec:
    """The grasp task for ``obj``: task ``grasp_<obj>`` of the task files, else (any other
    object of the model database, e.g. one added with ``mks-sim objects add``)
    :func:`default_task`.

    Raises:
        NotFound: no such task and no such database object (the message lists the objects).
    """
    try:
        return get_task(f"grasp_{obj}", folder)
    except NotFound:
        from mks_sim.models.objects import object_names

        if obj not in object_names():
            raise
        return default_task(obj)


def object_scene(obj: str, folder: str | Path | None = None) -> str | None:
    """The scene object ``obj`` is localized and grasped in: the ``scene`` field of its task
    (``grasp_<obj>`` in the task files), or None when it has no task file -- then the default
    scene (the object alone on the table, dropped from a random orientation:
    :func:`mks_sim.sim.scenes.default_scene`).

    The one source of "which scene for this object" (``mks-sim localize`` without
    ``--scene``, :func:`default_task`, the tests and benchmarks).
    """
    try:
        return get_task(f"grasp_{obj}", folder).scene
    except NotFound:
        return None


def default_task(obj: str) -> TaskSpec:
    """Grasp database object ``obj`` (one without a task file) with the default action in the
    default scene (the object alone on the table, dropped from a random orientation:
    :func:`mks_sim.sim.scenes.default_scene_file`). Extra model folders come from
    ``MKS_SIM_MODELS`` (``--models`` sets it)."""
    from mks_sim.models.objects import load_object
    from mks_sim.sim.scenes import default_scene_file

    o = load_object(obj)
    scene = str(default_scene_file([obj]))
    model = next(iter(o.models.values()), obj)
    return TaskSpec(
        name=f"grasp_{obj}",
        scene=scene,
        object=obj,
        model=model,
        matcher=o.kind,
        action=GraspAction(),
        description=f"grasp {obj} (default task from the model database)",
    )
