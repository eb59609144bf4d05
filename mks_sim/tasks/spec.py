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
raises :class:`~mks_sim.errors.SpecError` naming the file, the entry and the field, in the
one message format of sensor, model and scene files (:func:`mks_sim.specs.spec_error`)::

    tasks/x.toml: task 'grasp_cube': field 'action.lift_height_m': expected a number <= 0.5, got 3.0
"""

from __future__ import annotations

import tomllib
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from mks_sim.errors import NotFound
from mks_sim.resources import data_dir
from mks_sim.specs import (
    MISSING,
    Where,
    require_keys,
    require_list,
    require_number,
    require_str,
)

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


def _parse_action(raw: Any, where: Where) -> GraspAction:
    """``[task.action]`` (``where``: the task entry, fields under ``action``)."""
    at = where.at("action")
    require_keys(raw, tuple(_ACTION_FIELDS), at)
    values: dict[str, Any] = {
        "kind": require_str(raw, "kind", at, default="grasp", choices=ACTION_KINDS),
        "grasp_type": require_str(raw, "grasp_type", at, default="antipodal",
                                  choices=GRASP_TYPES),
        "approach_height_m": float(require_number(raw, "approach_height_m", at, 0.02, 0.5,
                                                  default=0.12)),
        "lift_height_m": float(require_number(raw, "lift_height_m", at, 0.0, 0.5,
                                              default=0.10)),
        "retries": require_number(raw, "retries", at, 0, 10, default=2, integer=True),
    }  # fmt: skip
    return GraspAction(**values)


def parse_task(raw: Any, path: Path | str = "<string>", index: int = 0) -> TaskSpec:
    """Validate one raw ``[[task]]`` table and return its :class:`TaskSpec`.

    Raises:
        SpecError: in the one message format of every spec file
            (:func:`mks_sim.specs.spec_error`): ``FILE: task 'NAME': field 'F': expected
            ..., got ...`` (``task[INDEX]`` when the entry has no usable name).
    """
    at_index = Where(path, f"task[{index}]")
    if not isinstance(raw, dict):
        raise at_index.error(None, "a table [[task]]", raw)
    raw_name = raw.get("name")
    where = Where(path, "task", raw_name) if isinstance(raw_name, str) and raw_name else at_index
    require_keys(raw, sorted(_TASK_KEYS), where)
    name = require_str(raw, "name", where)
    obj_name = require_str(raw, "object", where)
    scene = require_str(raw, "scene", where)
    model = require_str(raw, "model", where)
    from mks_sim.models.objects import load_object

    kinds = load_object(obj_name).kinds  # NotFound lists the database's objects
    matcher = require_str(raw, "matcher", where, default=kinds[0])
    if matcher not in kinds:
        raise where.error("matcher", f"one of object {obj_name!r}'s kinds {list(kinds)}", matcher)
    description = require_str(raw, "description", where, default="", allow_empty=True)
    remove = require_list(raw, "remove", where, default=())
    if "action" not in raw:
        raise where.error("action", "a table [task.action]", MISSING)
    return TaskSpec(
        name=name,
        scene=scene,
        object=obj_name,
        model=model,
        matcher=matcher,
        action=_parse_action(raw["action"], where),
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
    top = Where(path)
    try:
        with path.open("rb") as fh:
            doc = tomllib.load(fh)
    except OSError as exc:
        raise top.fail(f"cannot read task file: {exc}") from exc
    except tomllib.TOMLDecodeError as exc:
        raise top.fail(f"malformed TOML: {exc}") from exc
    require_keys(doc, ["task"], top)
    entries = doc.get("task")
    if not isinstance(entries, list) or not entries:
        raise top.error("task", "at least one [[task]] entry", entries if entries else MISSING)
    tasks = [parse_task(raw, path, i) for i, raw in enumerate(entries)]
    names = [t.name for t in tasks]
    for name in names:
        if names.count(name) > 1:
            raise Where(path, "task", name).error("name", "distinct task names", name)
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
                first = tasks[task.name].source
                where = Where(path, "task", task.name)
                raise where.error("name", f"a name no task of {first} has", task.name)
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
