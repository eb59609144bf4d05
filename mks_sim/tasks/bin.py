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

__all__ = [
    "BIN_SCENE",
    "MAX_INSTANCES",
    "bin_roi",
    "bin_world",
    "evaluate_instances",
    "instance_bodies",
    "run_localize_all",
]

BIN_SCENE = "bin"
MAX_INSTANCES = 12
#: success: within this many mm and degrees of the ground truth (as ``mks-sim localize``).
SUCCESS_MM = 5.0
SUCCESS_DEG = 5.0
#: a surface sample counts as seen when a sensed point is this close (evaluation).
VISIBLE_DISTANCE_M = 0.002
#: the region of interest stops this far inside the region (the walls' inner faces).
ROI_MARGIN_M = 0.003
ROI_HEIGHT_M = 0.25


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


def bin_roi(world: World) -> tuple[np.ndarray, np.ndarray]:
    """(lo, hi) world corners of the bin's inside: the scene's declared region (scene data,
    a workcell calibration -- not ground truth), ``ROI_MARGIN_M`` inside the walls, up to
    ``ROI_HEIGHT_M`` above the support."""
    (cx, cy), (hx, hy) = world.scene.region_center_xy, world.scene.region_half_xy
    z = world.scene.support_z
    m = ROI_MARGIN_M
    return (
        np.array([cx - hx + m, cy - hy + m, z - 0.02]),
        np.array([cx + hx - m, cy + hy - m, z + ROI_HEIGHT_M]),
    )


def visible_fraction(mesh_points: np.ndarray, T: np.ndarray, sensed: np.ndarray) -> float:
    """Fraction of a posed model's surface samples within ``VISIBLE_DISTANCE_M`` of a sensed
    point (evaluation: ``T`` is the true pose)."""
    from scipy.spatial import cKDTree

    if len(sensed) == 0:
        return 0.0
    P = mesh_points @ T[:3, :3].T + T[:3, 3]
    d = cKDTree(sensed).query(P, distance_upper_bound=VISIBLE_DISTANCE_M)[0]
    return float(np.mean(np.isfinite(d)))


def evaluate_instances(
    world: World, object_name: str, found: Sequence[np.ndarray], sensed: np.ndarray
) -> dict[str, Any]:
    """Match found poses to the true instances -- EVALUATION ONLY (ground truth).

    Each true instance is matched at most once, to the found pose closest in position among
    those within ``SUCCESS_MM`` / ``SUCCESS_DEG`` (modulo the object's symmetries); a found
    pose matching none is a false positive.

    Returns:
        ``{"errors": per found pose {"position_mm", "rotation_deg", "instance"} (the nearest
        true instance) , "matched": per found pose the body or None, "present", "found",
        "correct", "false_positives", "visible": body -> visible fraction,
        "missed": [{"instance", "visible_fraction"}]}``.
    """
    from mks_sim.models.objects import load_object
    from mks_sim.sim import truth
    from mks_sim.tasks.evaluate import object_pose_error

    obj = load_object(object_name)
    bodies = [b for b, m in world.scene.models.items() if m == object_name]
    true = {b: truth.object_to_world(world, b) for b in bodies}
    samples = _surface_samples(obj)
    # the table under a part is no view of it: only points above the support count
    above = sensed[sensed[:, 2] > world.scene.support_z + 0.003]
    visible = {b: visible_fraction(samples, T, above) for b, T in true.items()}
    errors: list[dict[str, Any]] = []
    pairs: list[tuple[float, int, str]] = []
    for i, E in enumerate(found):
        best: tuple[float, float, str] | None = None
        for b, G in true.items():
            p, r = object_pose_error(obj, E, G)
            if best is None or p < best[0]:
                best = (p, r, b)
            if 1000 * p <= SUCCESS_MM and r <= SUCCESS_DEG:
                pairs.append((p, i, b))
        assert best is not None
        errors.append(
            {
                "position_mm": round(1000 * best[0], 3),
                "rotation_deg": round(best[1], 3),
                "instance": best[2],
            }
        )
    matched: list[str | None] = [None] * len(found)
    used: set[str] = set()
    for _, i, b in sorted(pairs):
        if matched[i] is None and b not in used:
            matched[i] = b
            used.add(b)
    return {
        "errors": errors,
        "matched": matched,
        "present": len(bodies),
        "found": len(found),
        "correct": len(used),
        "false_positives": sum(m is None for m in matched),
        "visible": {b: round(v, 4) for b, v in visible.items()},
        "missed": [
            {"instance": b, "visible_fraction": round(visible[b], 4)}
            for b in bodies
            if b not in used
        ],
    }


def _surface_samples(obj: Any) -> np.ndarray:
    """(M, 3) area-uniform samples of the object's mesh (fixed seed: evaluation)."""
    from mks_sim.geometry.meshes import sample_surface

    pts, _ = sample_surface(obj.mesh, 4000, rng=np.random.default_rng(0))
    return np.asarray(pts, dtype=np.float64)


def _round(T: np.ndarray) -> list[list[float]]:
    return [[round(float(v), 6) for v in row] for row in np.asarray(T)]


def run_localize_all(
    seed: int,
    *,
    object_name: str | None = None,
    count: int | None = None,
    fail: Sequence[str] = (),
    scene: str | Path = BIN_SCENE,
) -> dict[str, Any]:
    """Build the bin from ``seed``, sense once, localize every instance and evaluate: the
    record of ``mks-sim localize --scene bin --all``.

    Returns:
        ``{"scene", "object", "seed", "instances": [{"matrix", "score", "visible_fraction",
        "error": {"position_mm", "rotation_deg"}, "correct"}], "found", "present",
        "false_positives", "missed", "provenance", "time_s", "timing_s", "failed_devices"}``
        (``error``, ``visible_fraction``, ``correct``, ``present``, ``false_positives`` and
        ``missed`` are evaluation from ground truth).
    """
    from mks_sim.devices import DeviceFaults, make_devices
    from mks_sim.localization.instances import localize_instances

    world = bin_world(seed, count=count, object=object_name, scene=scene)
    name = object_name or next(iter(world.scene.models.values()))
    faults = {dev: DeviceFaults(failed=True) for dev in fail}
    devices = make_devices(world.model, world.data, np.random.default_rng(seed), faults)
    try:
        sensed = localize_instances(
            devices, name, roi=bin_roi(world), rng=np.random.default_rng(seed)
        )
    finally:
        devices.close()
    found = [i.matrix for i in sensed.instances.instances]
    ev = evaluate_instances(world, name, found, sensed.points)
    instances = []
    for inst, err, m in zip(sensed.instances.instances, ev["errors"], ev["matched"], strict=True):
        instances.append(
            {
                "matrix": _round(inst.matrix),
                "score": round(inst.score, 4),
                "visible_fraction": ev["visible"][m if m is not None else err["instance"]],
                "error": {k: err[k] for k in ("position_mm", "rotation_deg")},
                "correct": m is not None,
            }
        )
    return {
        "scene": world.name,
        "object": name,
        "seed": seed,
        "instances": instances,
        "found": ev["found"],
        "present": ev["present"],
        "correct": ev["correct"],
        "false_positives": ev["false_positives"],
        "missed": ev["missed"],
        "provenance": sensed.provenance,
        "time_s": round(sensed.timing["total"], 4),
        "timing_s": {k: round(v, 4) for k, v in sensed.timing.items()},
        "failed_devices": list(fail),
    }
