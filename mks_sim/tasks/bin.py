"""Bin picking (issue 13): the ``bin`` scene with N instances, and the ``clear_bin`` task.

The scene is data (``worlds/bin.toml``: walls as ``[[fixture]]`` boxes, the instances as one
``[[object]]`` entry with ``count`` and ``pose = "drop"``, footprints allowed to overlap so
that the copies land on each other). :func:`bin_world` builds it with another count or
object; nothing here knows which object is in the bin.
"""

from __future__ import annotations

import tomllib
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np

from mks_sim.errors import SpecError
from mks_sim.sim.scenes import scene_file, scene_from_doc
from mks_sim.sim.world import World

__all__ = ["BIN_SCENE", "MAX_INSTANCES", "bin_world", "instance_bodies"]

BIN_SCENE = "bin"
MAX_INSTANCES = 12


def _bin_doc(scene: str | Path, count: int | None, obj: str | None) -> dict[str, Any]:
    path = scene_file(scene)
    doc = tomllib.loads(path.read_text(encoding="utf-8"))
    entries = doc.get("object", [])
    if len(entries) != 1:
        raise SpecError(f"{path}: a bin scene: expected one [[object]] entry, got {len(entries)}")
    if count is not None:
        if isinstance(count, bool) or not isinstance(count, int) or not 1 <= count <= MAX_INSTANCES:
            raise SpecError(
                f"bin scene: count: expected an integer in 1..{MAX_INSTANCES}, got {count!r}"
            )
        entries[0]["count"] = count
    if obj is not None:
        entries[0]["name"] = obj
    return doc


def bin_world(
    seed: int | None = 0,
    *,
    count: int | None = None,
    object: str | None = None,  # noqa: A002 - the CLI's --object
    scene: str | Path = BIN_SCENE,
    models: Sequence[str | Path] = (),
) -> World:
    """The bin scene with ``count`` instances of database object ``object``, settled.

    Args:
        seed: randomise (drop) the instances from this seed (None: the file's default
            layout, side by side, settled).
        count: instances (1..``MAX_INSTANCES``); default the scene file's.
        object: database object name; default the scene file's.
        scene: the bin scene file (one ``[[object]]`` entry).
        models: extra model folders.

    Raises:
        SpecError: a bad count or a scene with more than one object entry.
        NotFound: unknown scene or object.
    """
    path = scene_file(scene)
    spec = scene_from_doc(_bin_doc(path, count, object), path, models=models)
    world = World(spec)
    if seed is not None:
        world.randomize(np.random.default_rng(seed))
    else:
        world.settle()
    world.mark_initial()
    return world


def instance_bodies(world: World) -> tuple[str, ...]:
    """The bodies of the bin's instances (the database objects of the scene)."""
    return tuple(world.scene.models)
