"""Bin picking (issue 13): the ``bin`` scene with N instances, and the ``clear_bin`` task.

The scene is data (``worlds/bin.toml``: walls as ``[[fixture]]`` boxes, the instances as one
``[[object]]`` entry with ``count`` and ``pose = "drop"``, footprints allowed to overlap so
that the copies land on each other). :func:`bin_world` builds it with another count or
object; nothing here knows which object is in the bin.
"""

from __future__ import annotations

import logging
import time
import tomllib
from collections.abc import Callable, Sequence
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any, TypeVar

import mujoco
import numpy as np
from scipy.ndimage import maximum_filter

from mks_sim.errors import SpecError
from mks_sim.sensing.faults import fault_fields
from mks_sim.sim.piles import randomize_settled
from mks_sim.sim.scenes import OutputBox, scene_file, scene_from_doc
from mks_sim.sim.world import World

__all__ = [
    "BIN_SCENE",
    "MAX_INSTANCES",
    "bin_roi",
    "BinPicker",
    "bin_world",
    "clear_bin",
    "evaluate_instances",
    "instance_bodies",
    "run_localize_all",
]

logger = logging.getLogger(__name__)

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
    cache: bool = True,
) -> World:
    """The bin scene with ``count`` instances of database object ``object``, settled.

    Args:
        seed: randomise (drop) the instances from this seed (None: the file's default
            layout, side by side, settled).
        count: instances (1..``MAX_INSTANCES``); default the scene file's.
        object: database object name; default the scene file's.
        scene: the bin scene file (one ``[[object]]`` entry).
        models: extra model folders.
        cache: a pile settled before from the same model and seed is restored from the
            pile cache (:mod:`mks_sim.sim.piles`; the same state to the bit), and a new one
            saved there; False: always dropped and settled.

    Raises:
        SpecError: a bad count or a scene with more than one object entry.
        NotFound: unknown scene or object.
    """
    path = scene_file(scene)
    spec = scene_from_doc(_bin_doc(path, count, object), path, models=models)
    world = World(spec)
    if seed is not None and cache:
        randomize_settled(world, seed)
    elif seed is not None:
        world.randomize(np.random.default_rng(seed))
    else:
        world.settle()
    world.mark_initial()
    return world


def instance_bodies(world: World) -> tuple[str, ...]:
    """The bodies of the bin's instances (the database objects of the scene)."""
    return tuple(world.scene.models)


def bin_walls_xy(world: World) -> tuple[np.ndarray, np.ndarray]:
    """((2,) lo, (2,) hi) world xy of the bin walls' inner faces: the scene's declared region
    (scene data, a workcell calibration -- not ground truth)."""
    (cx, cy), (hx, hy) = world.scene.region_center_xy, world.scene.region_half_xy
    return np.array([cx - hx, cy - hy]), np.array([cx + hx, cy + hy])


def bin_roi(world: World) -> tuple[np.ndarray, np.ndarray]:
    """(lo, hi) world corners of the bin's inside: ``ROI_MARGIN_M`` inside the walls
    (:func:`bin_walls_xy`), up to ``ROI_HEIGHT_M`` above the support."""
    lo, hi = bin_walls_xy(world)
    z = world.scene.support_z
    m = ROI_MARGIN_M
    return np.array([*(lo + m), z - 0.02]), np.array([*(hi - m), z + ROI_HEIGHT_M])


#: The table search (:func:`table_roi`) leaves out the bin, its walls and the box with this
#: margin around their outer faces.
SPILL_MARGIN_M = 0.005


def _static_boxes_xy(world: World, prefix: str) -> list[tuple[np.ndarray, np.ndarray]]:
    """World xy corners ((2,) lo, (2,) hi) of the static box geoms whose names start with
    ``prefix`` (``fixture_``: the scene's ``[[fixture]]`` boxes, the bin's walls;
    ``output_box_wall_``: the output box's walls) -- scene data, not ground truth."""
    m = world.model
    return [
        _geom_xy(world, g)
        for g in range(m.ngeom)
        if (mujoco.mj_id2name(m, mujoco.mjtObj.mjOBJ_GEOM, g) or "").startswith(prefix)
    ]


def _geom_xy(world: World, g: int) -> tuple[np.ndarray, np.ndarray]:
    """World xy corners ((2,) lo, (2,) hi) of box geom ``g`` seen from above."""
    d = world.data
    half = np.abs(d.geom_xmat[g].reshape(3, 3)[:2]) @ world.model.geom_size[g]
    return d.geom_xpos[g][:2] - half, d.geom_xpos[g][:2] + half


def _outer_xy(world: World, prefix: str) -> tuple[np.ndarray, np.ndarray] | None:
    """The xy bounding box of :func:`_static_boxes_xy` (None: no such geom)."""
    boxes = _static_boxes_xy(world, prefix)
    if not boxes:
        return None
    return np.min([b[0] for b in boxes], axis=0), np.max([b[1] for b in boxes], axis=0)


def table_roi(
    world: World,
) -> tuple[tuple[np.ndarray, np.ndarray], list[tuple[np.ndarray, np.ndarray]]]:
    """((lo, hi) world corners of the table top up to ``ROI_HEIGHT_M`` above it, [(lo, hi)
    xy regions left out]): where parts that ended outside the bin are searched
    (:meth:`BinPicker.to_table`). Left out, :data:`SPILL_MARGIN_M` beyond their outer faces:
    the bin and the output box (:func:`containers`). Scene data (the table's and fixtures'
    geoms), not ground truth."""
    from mks_sim.sim import names

    g = mujoco.mj_name2id(world.model, mujoco.mjtObj.mjOBJ_GEOM, names.TABLE_TOP_GEOM)
    lo, hi = _geom_xy(world, g)
    z = world.scene.support_z
    roi = (np.array([*lo, z - 0.02]), np.array([*hi, z + ROI_HEIGHT_M]))
    return roi, [
        (w.outer_lo - SPILL_MARGIN_M, w.outer_hi + SPILL_MARGIN_M) for w in containers(world)
    ]


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
    world: World,
    object_name: str,
    found: Sequence[np.ndarray],
    sensed: np.ndarray,
    *,
    models: Sequence[str | Path] = (),
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

    obj = load_object(object_name, models=tuple(str(m) for m in models))
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
    """(M, 3) area-uniform samples of the object's mesh (fixed seed; ~2 mm apart on the
    industrial part)."""
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
    active: bool = True,
    models: Sequence[str | Path] = (),
) -> dict[str, Any]:
    """Build the bin from ``seed``, sense (more views when the first is not good enough:
    :meth:`BinPicker.sense`), localize every instance and evaluate: the record of
    ``mks-sim localize --scene bin --all``.

    Returns:
        ``{"scene", "object", "seed", "instances": [{"matrix", "score", "visible_fraction",
        "error": {"position_mm", "rotation_deg"}, "correct", "stability"}], "found",
        "present", "false_positives", "missed", "unsure" (instances found but not reported:
        their pose not pinned down or seen through, ``localize_all``'s ``min_stability`` and
        ``max_inside_reported``), "provenance",
        "views", "view_names", "view_log", "faults", "warnings", "fault_reasons", "time_s",
        "timing_s", "failed_devices"}``
        (``error``, ``visible_fraction``, ``correct``, ``present``, ``false_positives`` and
        ``missed`` are evaluation from ground truth).
    """
    from mks_sim.devices import DeviceFaults, make_devices

    world = bin_world(seed, count=count, object=object_name, scene=scene, models=models)
    name = object_name or next(iter(world.scene.models.values()))
    faults = {dev: DeviceFaults(failed=True) for dev in fail}
    devices = make_devices(world.model, world.data, np.random.default_rng(seed), faults)
    try:
        robot = BinPicker(
            world, devices, object_name=name, rng=np.random.default_rng(seed), active=active,
            models=models,
        )  # fmt: skip
        robot.sense()
        sensed = robot.sensed
    finally:
        devices.close()
    found = [i.matrix for i in sensed.instances.instances]
    ev = evaluate_instances(world, name, found, sensed.points, models=models)
    instances = []
    for inst, err, m in zip(sensed.instances.instances, ev["errors"], ev["matched"], strict=True):
        instances.append(
            {
                "matrix": _round(inst.matrix),
                "score": round(inst.score, 4),
                "visible_fraction": ev["visible"][m if m is not None else err["instance"]],
                "error": {k: err[k] for k in ("position_mm", "rotation_deg")},
                "correct": m is not None,
                "stability": round(inst.stability, 4),
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
        "unsure": len(sensed.instances.unsure),
        "provenance": sensed.provenance,
        "views": robot.views,
        "view_names": list(sensed.views),
        "view_log": robot.view_log,
        **fault_fields(robot.faults, sensed.provenance),
        "fault_reasons": dict(robot.faults),
        "time_s": round(robot.perception_s, 4),
        "timing_s": {
            **{k: round(v, 4) for k, v in sensed.timing.items()},
            "total": round(robot.perception_s, 4),
        },
        "failed_devices": list(fail),
    }


# --------------------------------------------------------------------------- clear_bin

#: The output box is the scene's ``[output_box]`` (:class:`mks_sim.sim.scenes.OutputBox`,
#: worlds/bin.toml); with no pinch point to plan from, a part is let go this high above the
#: table over its middle.
RELEASE_HEIGHT_M = 0.14
#: A part is let go with its predicted footprint this far inside the box's walls' centres
#: (the walls are 8 mm thick), where it overlaps least the parts let go before. Not less:
#: a part held off its centre of mass turns in the grasp and hangs up to ~30 mm from where
#: its estimate says (tuning bin 6: one let go over the wall, which a 6 mm margin allowed).
PLACE_MARGIN_M = 0.015
#: Candidate places of a part's middle: a grid of this many per side over the room left.
PLACE_GRID = 23
#: A part carried top-down is turned about the vertical by at most 90 degrees, in these
#: steps, so that its footprint's bounding rectangle is smallest (parts lie side by side).
PLACE_TURN_STEP_DEG = 15.0
#: The bin's walls are this high (worlds/bin.toml: 40 mm); a carried part's lowest point keeps
#: ``CARRY_MARGIN_M`` above them and the output box's walls on the way.
BIN_WALL_M = 0.04
CARRY_MARGIN_M = 0.02
#: A held part is lowered over the box until its lowest point (predicted from the estimate
#: it was grasped at, carried by the hand) is this high above the box's rim, then let go:
#: dropped from RELEASE_HEIGHT_M, a 100 mm part bounced out of a 30 mm box (tuning bins
#: 4001, 4004: 5 of 8 failed picks). Not lower: the parts already in the box are not sensed,
#: and a part pressed into them by the arm overflowed the simulator's contacts (seed 4001).
RELEASE_GAP_M = 0.015
#: ... except a bundle (parts lifted with the held one, :func:`held_and_passengers`) whose place
#: overlaps no part let go before (the robot's own record): it goes on down until its
#: lowest point is this high above the box's floor (the release gap and 15 mm for an
#: estimate a part turned in the grasp). Passengers lie on or beside the held part and were
#: let go 10-18 cm above the floor; from there one tumbled over a wall (tuning bins 5, 22,
#: 36). Tuning bins 5 and 22 with it: 6 of 6 each (5 without); bin 36's bundle had no free
#: place (5 of 6 either way).
BUNDLE_FLOOR_GAP_M = 0.03
#: The fingertips reach this far below the pinch point (pad centre 8 mm below, 7 mm half
#: height, grasp.PAD_CENTRE_BELOW_M): they too keep the gap.
TIPS_BELOW_PINCH_M = 0.018
#: A part is carried from the bin to the box at this waypoint spacing, ...
CARRY_SPACING_M = 0.02
#: ... a bundle lifted this much higher before it is carried, and carried at this waypoint
#: spacing (half as fast). Tuning bins 45 and 47 (traced with the ground truth): a
#: passenger seen as 715 points hung lower than seen and dragged over the bin's and the
#: box's walls until the held part was pulled out of the grasp; a held part with two
#: passengers turned out of the pads 20 cm into the carry, touching nothing but them.
BUNDLE_LIFT_M = 0.06
BUNDLE_SPACING_M = 0.01
#: A failed pick within this distance of an instance's estimate puts that instance last.
FAILED_NEAR_M = 0.015


def _near_failed(T: np.ndarray, failed_at: Sequence[np.ndarray]) -> bool:
    """An estimate's origin lies within :data:`FAILED_NEAR_M` of where a pick failed."""
    return any(np.linalg.norm(T[:3, 3] - f) < FAILED_NEAR_M for f in failed_at)


#: Fingers closed beyond this (rad; 1.35 = fully closed) hold nothing: the narrowest grasp the
#: bin asks of the synthesis (:data:`BIN_MIN_WIDTH_M`) closes the pads at ~1.2 rad
#: (grasp.PAD_APERTURE_M).
EMPTY_HAND_Q = 1.25
#: The bin's narrowest pinch: narrower ones (the synthesis goes down to 8 mm for thin walls)
#: close the fingers to where this test cannot tell a part from pads touching each other.
BIN_MIN_WIDTH_M = 0.02
#: Contact faces of a top-down pinch lean at most this far from the vertical in the bin: the
#: friction cone's 45 deg, with which clear_bin was tuned and measured (the single-object
#: synthesis default, 25 deg, was chosen on the thin bracket and not tried in bins).
BIN_MAX_FACE_LEAN_DEG = 45.0
CLEARANCE_ABOVE_M = 0.16  # travel height of the pinch point above the table between bin and box


@dataclass(frozen=True)
class Pick:
    """One pick of :func:`clear_bin`.

    Attributes:
        instance: index of the instance picked, in the score order of that sensing.
        success: the part ended in the output box (ground truth, evaluation only).
        believed: what the robot concluded (two-sided touch while lifting).
        failure: why it failed ("" on success): ``no grasp``, ``unreachable`` (pre-grasp
            out of reach, or the descent blocked),
            ``no two-sided contact``, ``closed on nothing``, ``slipped``, ``not in the box``;
            ``pushed``: no pick but a push of a part away from a wall (:func:`plan_push`).
        time_s: wall-clock seconds: sensing + localization + planning + motion.
        perception_s: of which sensing + localization.
        views: sensing views used for the pick.
        score: the picked instance's localization score.
        body: the body it was (evaluation: the true instance nearest the estimate).
        tilt_deg: how far the grasp's approach was from straight down (0: top-down; a part
            on its side or upside down is grasped tilted).
        passenger_points: points of other parts the range finder saw lifted with the held
            one at the travel height (:func:`held_and_passengers`; 0: none seen).
        unsure: the instance was one whose pose its points do not pin down or see through
            (``Instances.unsure``), picked because no other was left
            (:meth:`BinPicker.unsure_left`).
        hung_on: times the hand, opened over the box, still felt the part on a pad and was
            lowered to set it down (:func:`_set_down_hung`; 0: it fell free).
        region: where the part was searched: ``"bin"``, or ``"table"`` (around the bin,
            :meth:`BinPicker.to_table`).
    """

    instance: int
    success: bool
    believed: bool
    failure: str
    time_s: float
    perception_s: float
    views: int
    score: float
    body: str | None
    tilt_deg: float = 0.0
    passenger_points: int = 0
    unsure: bool = False
    hung_on: int = 0
    region: str = "bin"

    def to_json(self) -> dict[str, Any]:
        """The CLI's record of the pick."""
        return {
            "instance": self.instance,
            "success": self.success,
            "believed": self.believed,
            "failure": self.failure,
            "time_s": round(self.time_s, 3),
            "perception_s": round(self.perception_s, 3),
            "views": self.views,
            "score": round(self.score, 4),
            "body": self.body,
            "tilt_deg": round(self.tilt_deg, 1),
            "passenger_points": self.passenger_points,
            "unsure": self.unsure,
            "hung_on": self.hung_on,
            "region": self.region,
        }


#: A part counts as in the box with its origin at most this high above the rim (resting on
#: the parts below it; the 30 mm box's criterion was 80 mm above the table).
IN_BOX_ABOVE_RIM_M = 0.05


def output_box(world: World) -> OutputBox:
    """The scene's ``[output_box]``.

    Raises:
        SpecError: the scene has none (``clear_bin`` has nowhere to put the parts).
    """
    box = world.scene.output_box
    if box is None:
        raise SpecError(
            f"scene {world.scene.name!r} has no [output_box]: clear_bin needs one to place "
            "the picked parts in"
        )
    return box


def _inside_box_walls(box: OutputBox, p: np.ndarray) -> bool:
    """The point ``p`` (x, y, ...) lies inside the box's walls (their centres), seen from
    above."""
    return bool(np.all(np.abs(np.asarray(p)[:2] - np.asarray(box.center_xy)) < box.half_xy))


def _counts_in_box(world: World, box: OutputBox, p: np.ndarray) -> bool:
    """A part's origin at ``p`` (3,) counts as in the box: inside its walls, no higher than
    :data:`IN_BOX_ABOVE_RIM_M` above its rim."""
    top = world.scene.support_z + box.wall_height_m + IN_BOX_ABOVE_RIM_M
    return _inside_box_walls(box, p) and bool(p[2] < top)


def in_output_box(world: World, body: str) -> bool:
    """The body's origin is inside the output box's walls, no higher than
    :data:`IN_BOX_ABOVE_RIM_M` above its rim (evaluation only)."""
    from mks_sim.sim import truth

    return _counts_in_box(world, output_box(world), truth.object_to_world(world, body)[:3, 3])


def parts_left(world: World) -> dict[str, int]:
    """Where the parts not in the output box (:func:`in_output_box`) are, by their origins
    (evaluation only): ``"bin"`` inside the bin's walls (:func:`bin_walls_xy`), ``"box"``
    inside the box's walls but above the height that counts, ``"outside"`` anywhere else
    (on the table, on a rim, on the floor). Every key is present."""
    from mks_sim.sim import truth

    lo, hi = bin_walls_xy(world)
    box = output_box(world)
    out = {"bin": 0, "box": 0, "outside": 0}
    for b in instance_bodies(world):
        p = truth.object_to_world(world, b)[:3, 3]  # read once per part
        if _counts_in_box(world, box, p):
            continue
        if np.all(p[:2] > lo) and np.all(p[:2] < hi):
            out["bin"] += 1
        elif _inside_box_walls(box, p):
            out["box"] += 1
        else:
            out["outside"] += 1
    return out


def _nearest_body(world: World, bodies: Sequence[str], T: np.ndarray) -> str | None:
    """The true instance nearest the estimate ``T`` (evaluation only)."""
    from mks_sim.sim import truth

    if not bodies:
        return None
    return min(
        bodies,
        key=lambda b: float(np.linalg.norm(truth.object_to_world(world, b)[:3, 3] - T[:3, 3])),
    )


PlanPerturbation = Callable[[int, Any], Any]

#: The logical sensor that fuses the views (``sensors/views.toml``).
VIEWS_SENSOR = "Fused_Points"
#: Nothing found in the scanner's view but at least this many sensed points higher than
#: ``LEFT_ABOVE_M`` above the table: something is left, take a wrist view (a part shows
#: ~300-1500 points at the scanner's 2.5 mm spacing; the empty bin's floor noise none).
LEFT_POINTS = 60
LEFT_ABOVE_M = 0.005


def _database_objects() -> list[str]:
    from mks_sim.models.objects import object_names

    return object_names()


def _views_graph() -> Any:
    from mks_sim.workstation import _default_graph

    return _default_graph()


def _view_params(graph: Any) -> Any:
    """The fused sensor's params (its next-view data) as ``FuseParams``."""
    from mks_sim.sensing.programs.views import FuseParams
    from mks_sim.sensing.registry import params_of

    return params_of(FuseParams, graph.sensor(VIEWS_SENSOR).params, "fuse_views")


class BinPicker:
    """The robot side of bin picking: sense all instances, plan a grasp, pick into the box.

    Used by :func:`clear_bin` (the scripted loop) and ``mks_sim/BinPick-v0`` (an agent
    chooses the instance). Nothing here reads ground truth; :meth:`evaluate_pick` does, for
    the report only.

    Args:
        world: the bin world (:func:`bin_world`).
        devices: the devices (``make_devices``; failed ones are served by alternates).
        object_name: the database object in the bin (default the scene's).
        rng: grasp sampling and localization.
        active: take more views when the first is not good enough (:meth:`sense`).
        graph: the logical sensors (default ``SensorGraph.from_dir()``: ``Fused_Points``).
        models: extra model folders (``--models``).
    """

    def __init__(
        self,
        world: World,
        devices: Any,
        *,
        object_name: str | None = None,
        rng: np.random.Generator | None = None,
        active: bool = True,
        graph: Any = None,
        models: Sequence[str | Path] = (),
    ) -> None:
        from mks_sim.models.objects import load_object
        from mks_sim.sim import names
        from mks_sim.tasks.controller import ArmHandController, RobotNames
        from mks_sim.tasks.episode import make_touch_reader
        from mks_sim.tasks.spec import GraspAction, task_for_object

        self.world = world
        self.devices = devices
        self.rng = np.random.default_rng(0) if rng is None else rng
        self.name = object_name or next(iter(world.scene.models.values()))
        self.obj = load_object(self.name, models=tuple(str(m) for m in models))
        if models and self.name not in _database_objects():
            self.action = GraspAction()  # an object of a --models folder: the default action
        else:
            self.action = task_for_object(self.name).action
        self.bodies = [b for b, m in world.scene.models.items() if m == self.name]
        self.ctl = ArmHandController(
            world.physics, RobotNames.from_model(world.model), make_touch_reader(devices)
        )
        self.home_pos, self.home_yaw = self.ctl.pinch_pos(), self.ctl.pinch_yaw()
        self.table_z = names.TABLE_TOP_Z
        self.roi = bin_roi(world)
        self.exclude: list[tuple[np.ndarray, np.ndarray]] = []
        self.region = "bin"  # where parts are searched: "bin", or "table" (:meth:`to_table`)
        self.samples = _surface_samples(self.obj)  # the model's surface, for its own points
        self.sensed: Any = None
        self.last_tilt_deg = 0.0  # the last pick's approach from straight down (degrees)
        self.perception_s = 0.0
        self.models = tuple(str(m) for m in models)
        # active sensing (sensors/views.toml: the fused sensor and its next-view data)
        self.graph = graph if graph is not None else _views_graph()
        self.view = _view_params(self.graph)
        self.active = active
        self.views = 0
        self.view_log: list[dict[str, Any]] = []
        self.faults: dict[str, str] = {}  # devices that failed in the last sensing
        self.faults_seen: dict[str, str] = {}  # ... in any sensing
        self._grasp_memo: tuple[Any, int, str, list[Any]] | None = None
        self._used_views: list[int] = []
        self.view_gains: dict[int, int] = {}
        self.placed: list[np.ndarray] = []  # footprints of the parts let go in the box
        self.failed_grasps: list[Any] = []  # grasps the arm could not reach (not tried again)
        # where descents stopped short since a part last left the bin (:func:`felt_points`)
        self.felt: list[np.ndarray] = []
        self.last_passengers = 0  # points of parts lifted with the last pick's part
        self.last_hung_on = 0  # times the last pick's part hung on the opened hand
        self.retry_failed = False  # ... unless the bin has stalled (:meth:`_untried`)

    @property
    def box(self) -> OutputBox:
        """The scene's output box (:func:`output_box`; SpecError without one)."""
        return output_box(self.world)

    def sense(self) -> list[Any]:
        """Every instance found, best score first (``Instance``), from one view or more.

        The first view is the range finder's (when it fails, the wrist camera's from the first
        reachable viewpoint; with both failed, the fixed cameras: the sensor's alternates).
        When the best instance scores below the fused sensor's ``rescan_below`` or fewer than
        ``min_pad_points`` sensed points lie near a pad contact of its best grasp, the arm
        takes the wrist camera to the candidate viewpoint that sees most of that instance's
        predicted surface not seen yet, and the views are fused and localized again (up to
        ``max_views``). ``views`` and ``view_log`` say what was done; a failed device is
        named in ``faults`` and the views go on without it.

        Raises:
            MksError: sensing failed (every way of the points sensor).
        """
        from mks_sim.errors import MksError
        from mks_sim.sensing.programs.views import HeldViews

        t = time.perf_counter()
        self.faults = {}
        self.view_log = []
        # every input of the fused sensor, holding no view until one is captured
        held: dict[str, Any] = {d: HeldViews(d) for d in ("range_finder", "wrist_camera")}
        self._used_views = []
        if self.region == "table":  # the scanner sees the table; the wrist views the bin
            scanned = self._capture(held, "range_finder")
            self.faults_seen.update(self.faults)
            if not scanned:
                from mks_sim.errors import SensorFailure

                why = self.faults.get("range_finder", "no reading")
                raise SensorFailure("range_finder", f"the table is searched in its view: {why}")
            self.sensed = self._localize(held)
            self.views = 1
            self.perception_s = time.perf_counter() - t
            return list(self.sensed.instances.instances)
        if not self._capture(held, "range_finder"):
            # no scanner: the wrist camera's first view from the first reachable viewpoint
            if self._move_to_next_view() is not None or not self.view.viewpoints:
                self._capture(held, "wrist_camera")
        self.sensed = self._localize(held)
        while self.active and self._held_views(held) < self.view.max_views:
            why = self._needs_view(scanned=bool(held["range_finder"].readings))
            if not why:
                break
            try:
                moved = self._move_to_next_view()
            except MksError as exc:  # planning the view failed: keep what we have
                self.view_log.append({"reason": why, "taken": False, "why_not": str(exc)})
                break
            if moved is None:
                self.view_log.append({"reason": why, "taken": False, "why_not": "no viewpoint"})
                break
            if not self._capture(held, "wrist_camera"):
                why_not = self.faults.get("wrist_camera", "no reading")
                self.view_log.append({"reason": why, "taken": False, "why_not": why_not})
                break
            before = self.sensed
            self.sensed = self._localize(held, before)
            self.view_log.append(
                {"reason": why, "taken": True, "viewpoint": [round(float(v), 4) for v in moved],
                 "points_before": len(before.points), "points_after": len(self.sensed.points)}
            )  # fmt: skip
        self.views = self._held_views(held) or 1  # none held: a fixed camera's one view
        self.faults_seen.update(self.faults)
        self.perception_s = time.perf_counter() - t
        return list(self.sensed.instances.instances)

    def to_table(self) -> None:
        """Search the table around the bin from now on (:func:`table_roi`: parts that ended
        outside the bin and the box, lifted out with a picked part or dropped on the way),
        with the range finder's view alone (the wrist camera's viewpoints are over the bin);
        grasps keep their fingers off the bin's and the box's walls
        (:func:`walls_block_outside`)."""
        self.roi, self.exclude = table_roi(self.world)
        self.region = "table"
        self.redraw()

    def unsure_left(self, avoid: Sequence[np.ndarray] = ()) -> list[Any]:
        """When the last sensing reported nothing: its unsure instances (found, their pose not
        pinned down by their points or seen through, ``Instances.unsure``) whose origin is
        farther than :data:`FAILED_NEAR_M` from every point in ``avoid`` (where picks
        failed), best score first. They become the sensing's instances, so that
        :meth:`grasps` plans on them: a part whose pose is only unsure is tried rather than
        left in the bin with "nothing found". [] (the sensing unchanged) when there are
        none."""
        insts = self.sensed.instances
        if insts.instances:
            return []
        left = [u for u in insts.unsure if not _near_failed(u.matrix, avoid)]
        if not left:
            return []
        left.sort(key=lambda u: -u.score)
        rest = tuple(u for u in insts.unsure if all(u is not v for v in left))
        self.sensed = replace(
            self.sensed, instances=replace(insts, instances=tuple(left), unsure=rest)
        )
        return left

    # -- active sensing ----------------------------------------------------------------------
    def _capture(self, held: dict[str, Any], device: str) -> bool:
        """Read ``device`` once into the held views; a failure is named in ``faults``."""
        from mks_sim.errors import DeviceFailure

        dev = self.devices.get(device)
        if dev is None:
            self.faults[device] = "not connected"
            return False
        try:
            reading = dev.read()
        except DeviceFailure as exc:
            self.faults[device] = str(exc)
            return False
        held[device].readings.append(reading)
        return True

    @staticmethod
    def _held_views(held: dict[str, Any]) -> int:
        return sum(len(h.readings) for h in held.values())

    def _localize(self, held: dict[str, Any], before: Any = None) -> Any:
        """Localize every instance in the held views; the instances of the sensing
        ``before`` (fewer views) are checked first and kept when the fused views agree."""
        from mks_sim.localization.instances import localize_instances

        prior = [i.matrix for i in before.instances.instances] if before is not None else []
        # the held views stand for their devices; the others serve the sensor's alternates
        return localize_instances(
            {**self.devices, **held}, self.name, roi=self.roi, exclude=self.exclude,
            graph=self.graph, rng=self.rng, models=self.models, sensor=VIEWS_SENSOR, prior=prior,
        )  # fmt: skip

    def _needs_view(self, *, scanned: bool = True) -> str:
        """Why another view is wanted ("" : it is not): the best instance's score is low, or
        its best grasp's pad contacts have few sensed points near them (occluded); without a
        scanner view (range finder failed) always, up to ``max_views``: one wrist view sees
        the bin from one side (6-part bins 1, 2, 4: 10 -> 14 of 18 found, the false positive
        gone). With the scanner's view of the whole bin, nothing found is an empty bin only
        when fewer than :data:`LEFT_POINTS` points stand above the table: more are a part
        the scanner sees too little of (leaning on a wall), and the wrist camera looks."""
        insts = self.sensed.instances.instances
        if not scanned:
            # the wrist camera alone sees part of the bin from one viewpoint: look from all
            return "nothing found" if not insts else "no scanner view"
        if not insts:
            table = self.sensed.instances.table
            if table is None:
                return ""
            up = int(np.sum(table.distance(self.sensed.points) > LEFT_ABOVE_M))
            return f"nothing found, {up} points above the table" if up >= LEFT_POINTS else ""
        if insts[0].score < self.view.rescan_below:
            return f"score {insts[0].score:.2f} < {self.view.rescan_below}"
        cands = self.grasps(0)
        if not cands:
            return ""
        from scipy.spatial import cKDTree

        tree = cKDTree(self.sensed.points)
        near = [
            len(tree.query_ball_point(c, self.view.pad_radius_m)) for c in cands[0].contacts_world
        ]
        if min(near) < self.view.min_pad_points:
            return f"grasp side occluded ({min(near)} points near a pad)"
        return ""

    def _move_to_next_view(self) -> np.ndarray | None:
        """Move the wrist camera to the candidate viewpoint not used yet that sees most of the
        best instance's unseen predicted surface (nothing found yet: the next in the list),
        and reachable; its pinch position, or None."""

        cam = self.devices.get("wrist_camera")
        if cam is None or not self.view.viewpoints:
            return None
        unused = [k for k in range(len(self.view.viewpoints)) if k not in self._used_views]
        yaw = self.ctl.pinch_yaw()
        insts = self.sensed.instances.instances if self.sensed is not None else ()
        if not insts:
            order = unused
        else:
            order = self._rank_views(cam, insts[0], unused, yaw)
        for k in order:
            target = np.asarray(self.view.viewpoints[k], dtype=float)
            self._used_views.append(k)
            if self.ctl.move_to(target, yaw, spacing_m=0.03):
                return target
        return None

    def _rank_views(self, cam: Any, inst: Any, candidates: list[int], yaw: float) -> list[int]:
        """The candidate viewpoints that see some of the instance's unseen predicted surface,
        most first (the model ray-cast at its estimate, :mod:`mks_sim.localization.next_view`)."""
        from mks_sim.localization.instances import instance_model
        from mks_sim.localization.next_view import best_view
        from mks_sim.sim import names
        from mks_sim.sim.robot import hand_down_quat

        model = instance_model(self.name, self.models)
        T = inst.matrix
        surf = np.asarray(model.surface_points()) @ T[:3, :3].T + T[:3, 3]
        nrm = np.asarray(model.surface_normals()) @ T[:3, :3].T
        data = self.world.data
        pinch = np.eye(4)
        pinch[:3, :3] = data.site(names.PINCH_SITE).xmat.reshape(3, 3)
        pinch[:3, 3] = data.site(names.PINCH_SITE).xpos
        mount = np.linalg.inv(pinch) @ cam.pose()  # the camera on the hand (robot's own model)
        R = np.zeros(9)
        mujoco.mju_quat2Mat(R, hand_down_quat(yaw))
        cameras = []
        for k in candidates:
            P = np.eye(4)
            P[:3, :3] = R.reshape(3, 3)
            P[:3, 3] = self.view.viewpoints[k]
            cameras.append(P @ mount)
        seen = self.sensed.points
        order, gains = best_view(
            surf, nrm, cameras, cam.K, (cam.height, cam.width), self.sensed.scene_points, seen
        )
        self.view_gains = {candidates[j]: gains[j] for j in range(len(candidates))}
        return [candidates[j] for j in order if gains[j] > 0]

    def grasps(self, i: int, *, obstacles: str = "all") -> list[Any]:
        """Collision-free grasp candidates of instance ``i`` of the last sensing, best first.

        Args:
            i: the instance (score order).
            obstacles: ``"all"``: the other instances' points and everything else sensed
                (walls) are obstacles; ``"fixed"``: only what no instance explains (walls: the
                fingers may push neighbouring parts aside); ``"tight"``: the same, the
                fingertips allowed :data:`TIGHT_CLEARANCE_M` from them (a rigid wall, not a
                part that may move); ``"touch"``: the same at :data:`TOUCH_CLEARANCE_M`
                (the fingertips may graze a wall); ``"none"``. In every round but
                ``"none"``, top-down candidates whose open fingers would come down on a
                wall (:func:`walls_block`) are left out. ``"partial"``: as ``"touch"``,
                and the pads may reach over a face's top edge (:data:`PARTIAL_PAD_COVER_M`:
                a thin flange is pinched).
        """
        from mks_sim.tasks.grasp import FINGER_CLEARANCE_M, PAD_COVER_M, synthesize_grasps

        memo = self._grasp_memo
        if memo is not None and memo[0] is self.sensed and memo[1:3] == (i, obstacles):
            return self._untried(memo[3], obstacles)  # planned already for this sensing
        T = self.sensed.instances.instances[i].matrix
        obs = None
        if obstacles != "none":
            obs = grasp_obstacles(
                self.sensed, i, self.samples, self.table_z, parts=obstacles == "all"
            )
        clearance = {
            "tight": TIGHT_CLEARANCE_M, "touch": TOUCH_CLEARANCE_M, "partial": TOUCH_CLEARANCE_M
        }.get(obstacles, FINGER_CLEARANCE_M)  # fmt: skip
        cands = synthesize_grasps(
            self.obj, T, table_z=self.table_z, obstacles=obs, rng=self.rng,
            preferred_yaw=self.ctl.pinch_yaw(), finger_clearance_m=clearance,
            min_width_m=BIN_MIN_WIDTH_M, max_face_lean_deg=BIN_MAX_FACE_LEAN_DEG,
            pad_cover_m=PARTIAL_PAD_COVER_M if obstacles == "partial" else PAD_COVER_M,
        )  # fmt: skip
        if obstacles != "none":  # the walls are rigid: no round lets the fingers onto them
            over = TOUCH_WALL_OVERLAP_M if obstacles in ("touch", "partial") else 0.0
            if self.region == "table":
                walls = containers(self.world)
                blocked = [walls_block_outside(c, walls, self.table_z, over) for c in cands]
                cands = [c for c, b in zip(cands, blocked, strict=True) if not b]
            else:
                lo, hi = bin_walls_xy(self.world)
                cands = [c for c in cands if not walls_block(c, lo, hi, self.table_z, over)]
        self._grasp_memo = (self.sensed, i, obstacles, cands)
        return self._untried(cands, obstacles)

    def redraw(self) -> None:
        """Forget the last planned candidates: the next :meth:`grasps` draws the synthesis'
        random samples anew (:data:`GRASP_REDRAWS`)."""
        self._grasp_memo = None

    def clear_of_neighbours(self, i: int, cands: Sequence[Any]) -> list[Any]:
        """``cands`` of instance ``i`` (:meth:`grasps` of a round in which neighbours are no
        obstacles) reordered by :func:`_split_clear` (clear, blocked, tilted), or [] when no
        top-down one keeps its open fingers clear of the other instances' points."""
        parts = neighbour_points(self.sensed, i, self.table_z)
        clear, blocked, tilted = _split_clear(cands, parts)
        return clear + blocked + tilted if clear else []

    def _untried(self, cands: Sequence[Any], obstacles: str) -> list[Any]:
        """``cands`` without those alike (:func:`_alike`: the hand within 25 degrees and
        10 mm) a grasp the arm could not reach before in this bin (:attr:`failed_grasps`:
        the pre-grasp out of reach or the descent blocked; the same hand at the same place
        fails the same way: tuning bin 11 spent its budget on 8 such picks). A grasp that
        closed on one side, on nothing or slipped may be tried again: each try nudges the
        part, and a fourth try held in tuning bin 8, a second in bin 13. ``obstacles="none"``
        (the report's "blocked or without a pair") keeps them all.

        With :attr:`retry_failed` (set by :func:`clear_bin` when nothing else is left) the
        alike ones come after the others instead of going, those failed themselves last: a
        blocked descent is not always repeatable (tuning bin 10's last part, its state
        replayed: a candidate 2 mm beside the blocked one reached, held and was carried).

        Top-down candidates that would bring an open finger down where a finger stopped a
        descent before (:attr:`felt`, :func:`felt_points`) count as alike a failed grasp:
        the hand felt something there, which the sensed points did not show (tuning bin 4:
        nine descents onto one part, by candidates more than 25 degrees apart, all stopped
        on the same neighbour's end under a fingertip)."""
        if obstacles == "none" or not (self.failed_grasps or self.felt):
            return list(cands)
        felt = np.concatenate(self.felt) if self.felt else np.empty((0, 3))
        fresh = [
            c for c in cands
            if not any(_alike(c, f) for f in self.failed_grasps)
            and not fingers_blocked(c, felt, 0.0)
        ]  # fmt: skip
        if not self.retry_failed:
            return fresh
        failed_ids = {id(f) for f in self.failed_grasps}
        fresh_or_failed = failed_ids | {id(c) for c in fresh}
        alike = [c for c in cands if id(c) not in fresh_or_failed]
        return fresh + alike + [c for c in cands if id(c) in failed_ids]

    def pick(
        self,
        cands: Sequence[Any],
        index: int = 0,
        perturb: PlanPerturbation | None = None,
        *,
        instance: int | None = None,
    ) -> tuple[bool, str]:
        """Reach, close, lift out, lower into the output box, let go, go home. Returns
        (believed success from touch, failure reason).

        Args:
            cands: grasp candidates of the instance (:meth:`grasps`), best first.
            index: the pick's number (passed to ``perturb``).
            perturb: ``(index, GraspPlan) -> GraspPlan`` applied before execution (tests).
            instance: the instance the candidates grasp (score order of the last sensing;
                default the one :meth:`grasps` planned last): its estimate, carried by the
                hand, says how low the held part hangs and where its middle is, so that it
                is lowered into the box instead of dropped.
        """
        from mks_sim.tasks.episode import TOUCH_THRESHOLD_N
        from mks_sim.tasks.grasp import down_rotation

        ctl = self.ctl
        if instance is None and self._grasp_memo is not None and self._grasp_memo[0] is self.sensed:
            instance = self._grasp_memo[1]
        ok, failure, pinch_to_world, failed = _pick(
            ctl, cands, self.action, index, perturb, self.table_z, TOUCH_THRESHOLD_N,
            felt=self.felt,
        )  # fmt: skip
        self.failed_grasps += failed
        if ok:  # a part left the bin: what was felt may have gone with it
            self.felt.clear()
        self.last_tilt_deg = float(
            np.degrees(np.arccos(np.clip(-ctl.pinch_rotation()[2, 2], -1, 1)))
        )
        # a tilted hand keeps its orientation until it has let go, then turns back to the
        # top-down home on the way there
        keep = _kept(ctl)
        tilted = keep is not None
        self.last_passengers = 0
        if ok and pinch_to_world is not None and instance is not None:
            T = self.sensed.instances.instances[instance].matrix
            V = np.asarray(self.obj.mesh.vertices, dtype=float)
            part_to_pinch = np.linalg.inv(pinch_to_world) @ T
            # the part as it hangs in the hand, seen at the travel height (it may have turned
            # in the grasp), else as it was grasped
            riders, seen = self._passengers(part_to_pinch)
            part_to_pinch = part_to_pinch if seen is None else seen
            self.last_passengers = len(riders)
            failure = _carry_to_box(
                ctl, V @ part_to_pinch[:3, :3].T + part_to_pinch[:3, 3], self.table_z, keep,
                self.box, placed=self.placed, passengers=riders,
            )  # fmt: skip
            ok = not failure
        elif ok:
            over = np.array([*self.box.center_xy, self.table_z + RELEASE_HEIGHT_M])
            ctl.move_to(over, ctl.pinch_yaw(), spacing_m=0.03, rotation=keep)
        ctl.open(50)  # the part falls free before the hand moves (15 periods dragged it out)
        self.last_hung_on = _set_down_hung(ctl, self.table_z) if ok else 0
        up = ctl.pinch_pos()
        up[2] = max(up[2], self.table_z + CLEARANCE_ABOVE_M)
        ctl.move_to(up, ctl.pinch_yaw(), spacing_m=0.02, rotation=keep)
        home_rot = down_rotation(self.home_yaw) if tilted else None
        ctl.move_to(self.home_pos, self.home_yaw, spacing_m=0.03, rotation=home_rot)
        self.world.step(100)  # what was dropped comes to rest
        return ok, failure

    def _passengers(self, part_to_pinch: np.ndarray) -> tuple[np.ndarray, np.ndarray | None]:
        """One range finder reading at the travel height (:func:`held_and_passengers`):
        ((K, 3) points of parts lifted with the held one, in the pinch frame now, (0, 3) when
        none are seen; the held part's pose in the pinch frame refined on its points seen,
        or None when they do not say more than ``part_to_pinch``, the estimate it was
        grasped at). ((0, 3), None) without a reading (the range finder failed: the wrist
        camera, on the hand, does not see below it)."""
        from mks_sim.devices.range_finder import merge_scans
        from mks_sim.errors import DeviceFailure

        dev = self.devices.get("range_finder")
        if dev is None or self.sensed is None:
            return np.empty((0, 3)), None
        try:
            points = merge_scans(dev.read())[0]
        except DeviceFailure as exc:
            self.faults_seen.setdefault("range_finder", str(exc))
            return np.empty((0, 3)), None
        pinch = np.eye(4)
        pinch[:3, :3], pinch[:3, 3] = self.ctl.pinch_rotation(), self.ctl.pinch_pos()
        held, riders = held_and_passengers(
            points, self.sensed.scene_points, self.samples, pinch @ part_to_pinch,
            pinch[:3, 3], self.table_z,
        )  # fmt: skip
        if len(riders):
            logger.info("passenger: %d points lifted with the held part", len(riders))
        seen = None if held is None else np.linalg.inv(pinch) @ held
        return (riders - pinch[:3, 3]) @ pinch[:3, :3], seen

    # -- evaluation only (ground truth) ------------------------------------------------------
    def body_of(self, T: np.ndarray) -> str | None:
        """The true instance nearest the estimate ``T`` (evaluation only)."""
        return _nearest_body(self.world, self.bodies, T)

    def picked(self) -> int:
        """Instances in the output box (evaluation only)."""
        return sum(in_output_box(self.world, b) for b in self.bodies)


def clear_bin(
    world: World,
    devices: Any,
    *,
    object_name: str | None = None,
    rng: np.random.Generator | None = None,
    budget: int | None = None,
    perturb: PlanPerturbation | None = None,
    active: bool = True,
    models: Sequence[str | Path] = (),
    table: bool = True,
) -> dict[str, Any]:
    """Clear the bin: sense, localize every instance, pick the best-scored one that has a
    collision-free reachable grasp, lift it out, drop it in the output box, repeat.

    The bin is done when nothing is found, or no instance found has a collision-free grasp.
    Then (``table``) the table around the bin is searched (:meth:`BinPicker.to_table`: parts
    lifted out with a picked one or dropped on the way) and picked the same way, until
    nothing is found there either, or no grasp. Stops when that is done, or ``budget`` picks
    were tried. A failed pick is recorded with its reason and the loop goes
    on (the instance it failed on is tried last next time). When no instance has a grasp
    but one with an antipodal pair, or one that leans (:func:`leans`), lies against a wall,
    it is pushed away from the wall (:func:`plan_push`, at most
    :data:`PUSHES_PER_INSTANCE` times per part and :data:`PUSHES_PER_BIN` per bin),
    recorded as a pick that failed ``pushed``, and the bin is sensed again. When no push is
    left either, a grasp whose pads reach over a face's top edge is tried
    (:func:`_partial_grasp`).

    Args:
        world: the bin world (:func:`bin_world`).
        devices: the devices (``make_devices``; failed ones are served by alternates).
        object_name: the database object in the bin (default the scene's).
        rng: grasp sampling and localization (default seeded 0).
        budget: picks at most (default 2 x the instances present + 2).
        perturb: ``(pick index, GraspPlan) -> GraspPlan`` applied before execution (tests:
            a grasp made to miss).
        active: take a second view when the first is not good enough (``BinPicker.sense``).
        models: extra model folders (``--models``).
        table: when the bin is done, pick the parts found on the table around it.

    Returns:
        ``{"present", "picked", "cleared_fraction", "picks": [Pick.to_json()], "time_s",
        "stopped", "table_stopped", "pushes"}`` (``picked``, ``present``, ``success`` are
        evaluation from ground truth; ``stopped``: why the bin was done; ``table_stopped``:
        why the search of the table after it ended, null when the table was not searched --
        ``table`` off, the range finder failed, the budget spent in the bin; a pick's
        ``region`` says where its part was).

    Raises:
        SpecError: the scene has no ``[output_box]`` (at the first part carried to it;
            :func:`run_clear_bin` checks before it starts).
    """
    from dm_control.rl.control import PhysicsError

    from mks_sim.errors import MksError

    t_start = time.perf_counter()
    robot = BinPicker(
        world, devices, object_name=object_name, rng=rng, active=active, models=models
    )
    budget = 2 * len(robot.bodies) + 2 if budget is None else budget
    failed_at: list[np.ndarray] = []
    picks: list[Pick] = []
    retries = 0
    pushed: list[np.ndarray] = []  # (2, 3) per push: the part's estimated origin, and + push
    stopped = "budget spent"  # why the search of the region (the bin, then the table) ended
    bin_stopped: str | None = None  # ... of the bin, once the table is searched

    def done(why: str) -> bool:
        """The region is done for ``why``: go on with the table (True), or stop."""
        nonlocal bin_stopped, stopped
        if table and robot.region == "bin" and "range_finder" not in robot.faults:
            bin_stopped, stopped = why, "budget spent"
            robot.to_table()
            return True
        stopped = why
        return False

    while len(picks) < budget:
        t0 = time.perf_counter()
        try:
            found = robot.sense()
        except MksError as exc:
            stopped = f"sensing failed: {exc}"
            break
        unsure = False
        if not found:
            # only parts whose pose is unsure left (and not where a pick failed): try them
            found = robot.unsure_left(failed_at)
            unsure = bool(found)
        if not found:
            if done("nothing found"):
                continue
            break
        # instances a pick failed on go last (the failure may repeat); before them, those
        # with another instance resting on them (it would be carried along and dropped)
        covered = [covered_points(robot.sensed, i, robot.obj) > COVERED_POINTS for i in
                   range(len(found))]  # fmt: skip
        near_failed = [_near_failed(inst.matrix, failed_at) for inst in found]
        order = sorted(range(len(found)), key=lambda i: (near_failed[i], covered[i]))
        chosen, blocked, no_pair = _choose_grasp(
            robot.grasps, order, near_failed, robot.clear_of_neighbours
        )
        if chosen is None and robot.failed_grasps and retries < RETRY_FAILED_ROUNDS:
            # stalled on grasps the arm could not reach before: try them once more
            retries += 1
            robot.retry_failed = True
            chosen, blocked, no_pair = _choose_grasp(
                robot.grasps, order, near_failed, robot.clear_of_neighbours
            )
        draws = 0
        while chosen is None and draws < GRASP_REDRAWS:
            # the synthesis samples the model's surface at random: draw again before
            # pushing or stopping
            draws += 1
            robot.redraw()
            chosen, blocked, no_pair = _choose_grasp(
                robot.grasps, order, near_failed, robot.clear_of_neighbours
            )
        if chosen is None and robot.region == "bin" and len(pushed) < PUSHES_PER_BIN:
            # a part against a wall: push it away with the closed hand, sense again
            push = _push_candidate(robot, found, order, pushed)
            if push is not None:
                i, plan = push
                body = robot.body_of(found[i].matrix)  # evaluation only (the report)
                try:
                    _push(robot.ctl, plan, robot.home_pos, robot.home_yaw)
                    world.step(100)  # the pushed part comes to rest
                except PhysicsError as exc:
                    stopped = f"simulation failed: {exc}"
                pushed.append(_pushed_from_to(found[i].matrix, plan))
                robot.felt.clear()  # the push moved what the fingers had felt
                dt = time.perf_counter() - t0
                picks.append(
                    Pick(i, False, False, PUSHED, dt, robot.perception_s, robot.views,
                         float(found[i].score), body)
                )  # fmt: skip
                if stopped.startswith("simulation failed"):
                    break
                continue
        if chosen is None:
            # last of all: pads that reach over a face's top edge (a thin flange)
            chosen = _partial_grasp(robot, order, near_failed)
        if chosen is None:
            why = f"no grasp ({blocked} blocked by obstacles, {no_pair} without a pair)"
            dt = time.perf_counter() - t0
            picks.append(
                Pick(-1, False, False, why, dt, robot.perception_s, robot.views, 0.0, None,
                     region=robot.region)
            )  # fmt: skip
            if done("no collision-free grasp for any instance found"):
                continue
            break
        i, cands = chosen
        T = found[i].matrix
        body = robot.body_of(T)  # evaluation only (the report)
        try:
            ok, failure = robot.pick(cands, len(picks), perturb, instance=i)
            robot.retry_failed = False
        except PhysicsError as exc:  # the state is invalid: no further pick can run
            ok, failure = False, "simulation failed"
            stopped = f"simulation failed: {exc}"
        if not ok:  # the hand's own belief: the ground truth below is for the report only
            failed_at.append(T[:3, 3].copy())
        success = body is not None and in_output_box(world, body)
        if ok and not success:
            failure = "not in the box"
        dt = time.perf_counter() - t0
        picks.append(
            Pick(
                i,
                success,
                ok,
                "" if success else failure,
                dt,
                robot.perception_s,
                robot.views,
                float(found[i].score),
                body,
                robot.last_tilt_deg,
                robot.last_passengers,
                unsure,
                robot.last_hung_on,
                robot.region,
            )  # fmt: skip
        )
        if stopped.startswith("simulation failed"):
            break
    picked = robot.picked()
    return {
        "present": len(robot.bodies),
        "picked": picked,
        "cleared_fraction": round(picked / max(len(robot.bodies), 1), 4),
        "picks": [p.to_json() for p in picks],
        "time_s": round(time.perf_counter() - t_start, 3),
        "stopped": stopped if bin_stopped is None else bin_stopped,
        "table_stopped": None if bin_stopped is None else stopped,
        "pushes": len(pushed),
        **fault_fields(
            robot.faults_seen, robot.sensed.provenance if robot.sensed is not None else {}
        ),
        "fault_reasons": dict(robot.faults_seen),
    }


def _choose_grasp(
    grasps: Callable[..., list[Any]],
    order: Sequence[int],
    near_failed: Sequence[bool],
    clear: Callable[[int, list[Any]], list[Any]] | None = None,
) -> tuple[tuple[int, list[Any]] | None, int, int]:
    """The first instance in ``order`` that has grasp candidates, and them, round by round
    (``grasps(i, obstacles=...)``, :meth:`BinPicker.grasps`); with the "tight" round's counts
    of instances every pair of which was blocked by obstacles and of those without a pair.

    Clear of everything first; in a pile every part may have a neighbour within the fingers'
    clearance: then the fingers may push neighbouring parts (not the walls); then the
    fingertips may pass the walls closer (a part lying against a wall); last they may graze
    them, the instances not failed on first, then those failed on (the bin stops otherwise:
    tuning bin 1's last part, upside down 77 mm from a wall, failed once and was left with
    2-5 candidates at the grazing clearance). The pads reaching over a face's top edge come
    after all of these, and after a push (:func:`_partial_grasp`).

    With ``clear`` (``(i, candidates) -> candidates``, :meth:`BinPicker.clear_of_neighbours`:
    those whose open fingers do not come down on a neighbour, first, or [] when none does
    not), the rounds in which neighbours are no obstacles are taken twice: first any instance
    with a candidate that ``clear`` keeps, then as before. Fingertips drawn onto a
    neighbour's top stopped the descent (tuning bins 1, 4, 10, 11: 19 of 24 descents blocked
    on a neighbour came from those rounds) while another instance had a clear grasp at the
    walls' closer clearances (tuning bin 10).
    """
    last = _failed_last(order, near_failed)
    if clear is not None:
        for obstacles, among in (("all", order), ("fixed", order), ("tight", order),
                                 ("touch", last)):  # fmt: skip
            for i in among:
                cands = grasps(i, obstacles=obstacles)
                if cands and obstacles != "all":
                    cands = clear(i, cands)
                if cands:
                    return (i, cands), 0, 0
    blocked = no_pair = 0
    for obstacles in ("all", "fixed", "tight"):
        blocked = no_pair = 0
        for i in order:
            cands = grasps(i, obstacles=obstacles)
            if cands:
                return (i, cands), blocked, no_pair
            # why not: no antipodal pair at all, or every pair blocked by obstacles
            if grasps(i, obstacles="none"):
                blocked += 1
            else:
                no_pair += 1
    for i in last:  # the counts stay those of the "tight" round, for the report
        if cands := grasps(i, obstacles="touch"):
            return (i, cands), blocked, no_pair
    return None, blocked, no_pair


_Found = TypeVar("_Found")


def _partial_grasp(
    robot: Any, order: Sequence[int], near_failed: Sequence[bool]
) -> tuple[int, list[Any]] | None:
    """The first instance (those not failed on first) with candidates in the ``"partial"``
    round (:meth:`BinPicker.grasps`: the pads may reach over a face's top edge), in up to
    1 + :data:`GRASP_REDRAWS` draws of the synthesis, and them; or None.

    :func:`clear_bin` asks for these last of all, when no other round has a grasp and no
    push is left: a part lying with its tall end against a wall has its only whole-pad
    pinches there (the industrial part's 22 mm step; tuning bins 14 and 16, each stopped
    with the part left after two pushes that did not move it)."""
    last = _failed_last(order, near_failed)

    def first_with_candidates() -> tuple[int, list[Any]] | None:
        for i in last:
            if cands := robot.grasps(i, obstacles="partial"):
                return i, cands
        return None

    return _in_draws(robot, first_with_candidates)


def _failed_last(order: Sequence[int], near_failed: Sequence[bool]) -> list[int]:
    """``order`` with the instances a pick failed on (``near_failed``) moved to its end."""
    return [i for i in order if not near_failed[i]] + [i for i in order if near_failed[i]]


def _in_draws(robot: Any, find: Callable[[], _Found | None]) -> _Found | None:
    """The first answer of ``find`` that is not None in up to 1 + :data:`GRASP_REDRAWS`
    draws of the synthesis (:meth:`BinPicker.redraw` before each but the first), or None."""
    for k in range(1 + GRASP_REDRAWS):
        if k:
            robot.redraw()
        if (found := find()) is not None:
            return found
    return None


#: Fingertips may pass this close to what no instance explains (the bin's walls: rigid and
#: where they were sensed) in the last planning round; the fingertip is ~10 mm thick.
TIGHT_CLEARANCE_M = 0.012
#: ... and this close in a last round, once per instance (a fingertip's half thickness and
#: 2 mm: the fingertip may graze the wall; a part against a wall is otherwise left in the bin).
TOUCH_CLEARANCE_M = 0.007
#: ... where an open finger's footprint (:func:`walls_block`) may reach this far over a
#: wall's inner face (its discs hold the fingers loosely, by up to 6 mm).
TOUCH_WALL_OVERLAP_M = 0.003
#: In the last round of all ("partial", after the pushes), a pad need only have the surface
#: this far above its centre (the whole pad: grasp.PAD_COVER_M, 9 mm): a face thinner than
#: the 15 mm pad, a flange, may be pinched with the pad reaching over its top edge.
PARTIAL_PAD_COVER_M = 0.003

#: An instance with more than this many of other instances' sensed points resting on it is
#: picked after the free ones.
COVERED_POINTS = 15
#: A point lies on an instance when it is within this distance across (xy) of the instance's
#: posed surface and higher than it by at least ``COVER_ABOVE_M``.
COVER_XY_M = 0.006
COVER_ABOVE_M = 0.004


def covered_points(sensed: Any, i: int, obj: Any) -> int:
    """Sensed points claimed by other instances that rest on instance ``i``: within
    :data:`COVER_XY_M` across of its estimated surface (the model posed at the estimate) and
    at least :data:`COVER_ABOVE_M` above the surface's highest point there. Nothing but the
    sensing and the estimates is used."""
    from scipy.spatial import cKDTree

    from mks_sim.geometry.meshes import sample_surface

    insts = sensed.instances.instances
    others = _parts_points(sensed, i)
    if not others:
        return 0
    P = np.concatenate(others)
    key = "bin_cover_samples"
    if key not in obj.mesh._cache:
        obj.mesh._cache[key] = sample_surface(obj.mesh, 3000, rng=np.random.default_rng(0))[0]
    T = insts[i].matrix
    S = obj.mesh._cache[key] @ T[:3, :3].T + T[:3, 3]
    near = cKDTree(S[:, :2]).query_ball_point(P[:, :2], COVER_XY_M)
    top = np.array([S[n, 2].max() if n else np.inf for n in near])
    return int(np.sum(P[:, 2] > top + COVER_ABOVE_M))


#: A sensed point within this distance of an instance's estimated surface is the instance's
#: own, no obstacle to its grasp. Before, every point within the model's radius (+ 5 mm) of
#: the estimate's origin was: the bin's wall beside a part lying 38-49 mm from it was no
#: obstacle, and the fingers came down on it (tuning bins 7 and 10, the last part: every
#: descent blocked by the wall, the bin stopped).
OWN_DISTANCE_M = 0.006


def _near_surface(
    samples: np.ndarray, T: np.ndarray, points: np.ndarray, dist: float
) -> np.ndarray:
    """(M,) ``points`` within ``dist`` of the surface ``samples`` (model frame) posed at ``T``."""
    from scipy.spatial import cKDTree

    posed = samples @ T[:3, :3].T + T[:3, 3]
    d = cKDTree(posed).query(points, distance_upper_bound=dist)[0]
    return np.isfinite(d)


def grasp_obstacles(
    sensed: Any, i: int, samples: np.ndarray, table_z: float, *, parts: bool = True
) -> np.ndarray:
    """(K, 3) the sensed points that are obstacles to a grasp of instance ``i``: every scene
    point above the table but the instance's own (within :data:`OWN_DISTANCE_M` of its
    estimated surface, ``samples`` posed at its estimate, and claimed by no other instance);
    ``parts=False``: the points any instance claimed are no obstacle either (the fingers may
    push a neighbouring part, not a wall)."""
    P = sensed.scene_points
    T = sensed.instances.instances[i].matrix
    own = _near_surface(samples, T, P, OWN_DISTANCE_M) & ~_claimed_mask(sensed, i)
    if not parts:
        own |= _claimed_mask(sensed, -1)
    return np.asarray(P[~own & (P[:, 2] > table_z + 0.004)])


def neighbour_points(sensed: Any, i: int, table_z: float) -> np.ndarray:
    """(L, 3) the sensed points the other instances than ``i`` claimed, above the table
    (neighbouring parts, which the fingers may push): the part of :func:`grasp_obstacles`
    that ``parts=False`` leaves out."""
    P = sensed.scene_points
    return np.asarray(P[_claimed_mask(sensed, i) & (P[:, 2] > table_z + 0.004)])


#: The open fingers' footprint, measured on the hand's meshes (``mks_sim.sim.robot``: the
#: proximal and distal links of each finger, the 25 mm above its lowest point, the hand
#: pointing down, pre-shaped to the aperture): per pad aperture (m), the centre of each
#: finger's footprint beyond its pad (outward along the closing axis, m), across the closing
#: axis (pinch frame y, m; fingers 1, 2, 3) and the radius that holds it (m, +0.5 mm). The
#: synthesis' fingertip points (grasp.FINGERTIPS_Y: -16, -44, 14 mm, at the pad) are 6 to 10
#: mm off these centres, and a fingertip reaches up to 24 mm from its point: a wall at the
#: "touch" round's 7 mm stopped a descent with the back of the finger (tuning bin 10).
FOOTPRINT_APERTURE_M = (0.055, 0.075, 0.095, 0.115, 0.135, 0.159)
FOOTPRINT_OUT_M = (0.0041, 0.0034, 0.0029, 0.0031, 0.0017, -0.0027)
FOOTPRINT_ACROSS_M = (
    (-0.0057, -0.0379, 0.0079),
    (-0.0076, -0.0399, 0.0099),
    (-0.0096, -0.0418, 0.0118),
    (-0.0120, -0.0432, 0.0132),
    (-0.0141, -0.0444, 0.0144),
    (-0.0166, -0.0456, 0.0156),
)
FOOTPRINT_RADIUS_M = (0.0143, 0.0147, 0.0153, 0.0156, 0.0185, 0.0231)
#: ... and the open fingers reach at most this far below the pinch point (measured 9.8 mm at
#: the narrowest pre-shape, less when wider: the fingers swing up as they open).
FOOTPRINT_BELOW_PINCH_M = 0.012
#: The open fingers keep this far from a neighbour's points to count as clear of it.
NEIGHBOUR_MARGIN_M = 0.002


def finger_footprint(aperture_m: float) -> tuple[np.ndarray, float]:
    """((3, 2) centres in the pinch frame (x along the closing axis, y across; fingers 1, 2,
    3), radius) of the open fingers' footprint at pad aperture ``aperture_m`` (m),
    interpolated in the measured table (:data:`FOOTPRINT_APERTURE_M`)."""
    ap = float(np.clip(aperture_m, FOOTPRINT_APERTURE_M[0], FOOTPRINT_APERTURE_M[-1]))
    out = float(np.interp(ap, FOOTPRINT_APERTURE_M, FOOTPRINT_OUT_M))
    across = np.array(
        [np.interp(ap, FOOTPRINT_APERTURE_M, col) for col in np.asarray(FOOTPRINT_ACROSS_M).T]
    )
    x = 0.5 * ap + out
    centres = np.column_stack([[x, -x, -x], across])
    return centres, float(np.interp(ap, FOOTPRINT_APERTURE_M, FOOTPRINT_RADIUS_M))


def fingers_blocked(cand: Any, points: np.ndarray, margin_m: float) -> bool:
    """A top-down descent of ``cand`` (pre-shaped to its width + grasp.PRESHAPE_MARGIN_M)
    would bring an open finger within ``margin_m`` of one of ``points`` (M, 3), world,
    metres: a point within the footprint's radius + margin across (xy) of a finger's centre
    and higher than :data:`FOOTPRINT_BELOW_PINCH_M` below the pinch point. Tilted
    candidates are not checked here (False)."""
    if getattr(cand, "rotation_world", None) is not None or len(points) == 0:
        return False
    pinch = np.asarray(cand.pinch_world, dtype=float)
    P = points[points[:, 2] > pinch[2] - FOOTPRINT_BELOW_PINCH_M]
    if len(P) == 0:
        return False
    world, radius = _footprint_world(cand)
    d = np.linalg.norm(P[None, :, :2] - world[:, None, :], axis=2)  # (3, M)
    return bool(np.any(d < radius + margin_m))


def felt_points(cand: Any, stopped_at: np.ndarray) -> np.ndarray | None:
    """(3, 3) where a top-down descent of ``cand`` that stopped short with the pinch site at
    ``stopped_at`` (the arm's forward kinematics) felt something: the open fingers'
    footprint centres (:func:`finger_footprint`) moved to where the hand stopped, at the
    fingers' lowest point (:data:`FOOTPRINT_BELOW_PINCH_M` below the pinch site). Which
    finger met it the hand cannot tell (its touch pads face inward), so each is a point:
    :func:`fingers_blocked` with them keeps a later descent's fingers off all three spots
    while it would go lower. None for a tilted candidate (no footprint)."""
    if getattr(cand, "rotation_world", None) is not None:
        return None
    world, _ = _footprint_world(cand)
    stop = np.asarray(stopped_at, dtype=float)
    xy = world + (stop[:2] - np.asarray(cand.pinch_world, dtype=float)[:2])
    return np.column_stack([xy, np.full(3, stop[2] - FOOTPRINT_BELOW_PINCH_M)])


def _footprint_world(cand: Any) -> tuple[np.ndarray, float]:
    """((3, 2) world xy of a top-down candidate's open fingers' footprint centres, radius)
    (:func:`finger_footprint`, pre-shaped to the candidate's width + grasp.PRESHAPE_MARGIN_M)."""
    from mks_sim.tasks.grasp import PRESHAPE_MARGIN_M

    pinch = np.asarray(cand.pinch_world, dtype=float)
    centres, radius = finger_footprint(cand.width_m + PRESHAPE_MARGIN_M)
    c, s = np.cos(cand.yaw_rad), np.sin(cand.yaw_rad)
    # the pinch frame's x is (cos yaw, sin yaw), its y (sin yaw, -cos yaw) (z down)
    world = pinch[:2] + centres[:, :1] * np.array([c, s]) + centres[:, 1:] * np.array([s, -c])
    return world, radius


def walls_block(
    cand: Any, walls_lo: np.ndarray, walls_hi: np.ndarray, table_z: float, overlap_m: float = 0.0
) -> bool:
    """A top-down descent of ``cand`` would bring an open finger onto one of the bin's walls:
    its footprint (:func:`finger_footprint`) crosses a wall's inner face (``walls_lo``,
    ``walls_hi``: (2,) xy, :func:`bin_walls_xy`, scene data) by more than ``overlap_m``
    while the fingers reach below the walls' top (:data:`BIN_WALL_M` above ``table_z``).
    Tilted candidates are not checked here (False).

    The synthesis sees the walls only as sensed points and its fingertips as three points
    with a clearance; the real fingers reach up to 24 mm from those points. Tuning bin 11:
    the descents onto an upside-down part near two walls stopped on the walls' top, 21-36
    mm above the grasp, pick after pick until the budget was spent."""
    if getattr(cand, "rotation_world", None) is not None:
        return False
    if float(cand.pinch_world[2]) - FOOTPRINT_BELOW_PINCH_M >= table_z + BIN_WALL_M:
        return False
    world, radius = _footprint_world(cand)
    lo, hi = np.asarray(walls_lo, dtype=float), np.asarray(walls_hi, dtype=float)
    r = radius - overlap_m
    return bool(np.any(world - r < lo) or np.any(world + r > hi))


@dataclass(frozen=True)
class Walls:
    """A walled container on the table seen from above (scene data): the bin or the box.

    Attributes:
        inner_lo, inner_hi: (2,) xy corners of the walls' inner faces.
        outer_lo, outer_hi: (2,) xy corners of their outer faces.
        height_m: the walls' top above the table.
    """

    inner_lo: np.ndarray
    inner_hi: np.ndarray
    outer_lo: np.ndarray
    outer_hi: np.ndarray
    height_m: float


def containers(world: World) -> list[Walls]:
    """The bin (its region inside the fixtures, :data:`BIN_WALL_M` high) and the output box
    (:class:`~mks_sim.sim.scenes.OutputBox`) as :class:`Walls` (scene data)."""
    lo, hi = bin_walls_xy(world)
    outer = _outer_xy(world, "fixture_")
    olo, ohi = (lo, hi) if outer is None else (np.minimum(lo, outer[0]), np.maximum(hi, outer[1]))
    out = [Walls(lo, hi, olo, ohi, BIN_WALL_M)]
    box = world.scene.output_box
    if box is not None:
        c = np.asarray(box.center_xy, dtype=float)
        inner = np.asarray(box.inner_half_xy, dtype=float)
        full = np.asarray(box.half_xy, dtype=float) + 0.5 * box.wall_thickness_m
        out.append(Walls(c - inner, c + inner, c - full, c + full, box.wall_height_m))
    return out


def walls_block_outside(
    cand: Any, walls: Sequence[Walls], table_z: float, overlap_m: float = 0.0
) -> bool:
    """A top-down descent of ``cand``, whose pinch point lies outside every container's
    inner faces (a part on the table beside the bin or the box), would bring an open finger
    onto a container's walls: a finger's footprint (:func:`finger_footprint`, its radius less
    ``overlap_m``) reaches within the walls' outer faces while the fingers reach below their
    top. The fingers must stay on the pinch point's side of every wall. A pinch point
    inside a container is :func:`walls_block`'s case (True here: not a table grasp).
    Tilted candidates are not checked here (False)."""
    if getattr(cand, "rotation_world", None) is not None:
        return False
    pinch = np.asarray(cand.pinch_world, dtype=float)
    world, radius = _footprint_world(cand)
    r = radius - overlap_m
    for w in walls:
        if pinch[2] - FOOTPRINT_BELOW_PINCH_M >= table_z + w.height_m:
            continue
        if np.all(pinch[:2] > w.inner_lo) and np.all(pinch[:2] < w.inner_hi):
            return True
        gap = np.maximum(np.maximum(w.outer_lo - world, world - w.outer_hi), 0.0)  # (3, 2)
        if np.any(np.linalg.norm(gap, axis=1) < r):
            return True
    return False


def _split_clear(cands: Sequence[Any], parts: np.ndarray) -> tuple[list[Any], list[Any], list[Any]]:
    """``cands`` as (the top-down ones whose open fingers stay :data:`NEIGHBOUR_MARGIN_M`
    clear of the neighbours' points ``parts`` (M, 3), the other top-down ones, the tilted
    ones), each in its order (:func:`fingers_blocked` once per candidate). A planning round
    in which neighbours are no obstacles drew fingertips onto a neighbour's top: of 38
    descents stopped short (tuning bins 0-11), 20 within 12 mm of the grasp depth."""
    top = [c for c in cands if getattr(c, "rotation_world", None) is None]
    tilted = [c for c in cands if getattr(c, "rotation_world", None) is not None]
    ok = [not fingers_blocked(c, parts, NEIGHBOUR_MARGIN_M) for c in top]
    return (
        [c for c, k in zip(top, ok, strict=True) if k],
        [c for c, k in zip(top, ok, strict=True) if not k],
        tilted,
    )


def _parts_points(sensed: Any, i: int) -> list[np.ndarray]:
    """The sensed points each instance found but ``i`` claimed (``i = -1``: every one),
    those found but not reported (``Instances.unsure``: a part whose pose its points do not
    pin down is a part all the same) included."""
    insts = sensed.instances.instances
    unsure = getattr(sensed.instances, "unsure", ())  # test stubs hold instances alone
    return [sensed.points[inst.points] for j, inst in enumerate(insts) if j != i] + [
        sensed.points[u.points] for u in unsure
    ]


def _claimed_mask(sensed: Any, i: int) -> np.ndarray:
    """(M,) over ``sensed.scene_points``: points some OTHER instance than ``i`` claimed
    (``i = -1``: any instance)."""
    from scipy.spatial import cKDTree

    claimed = _parts_points(sensed, i)
    mask = np.zeros(len(sensed.scene_points), dtype=bool)
    if not claimed:
        return mask
    tree = cKDTree(np.concatenate(claimed))
    d = tree.query(sensed.scene_points, distance_upper_bound=1e-9)[0]
    mask[np.isfinite(d)] = True
    return mask


#: Candidates a pick tries when the arm cannot reach one (the pre-grasp out of reach, or the
#: descent blocked): the best top-down ones, then the best tilted ones.
TRY_TOP_DOWN = 4
TRY_TILTED = 4
#: Two candidates are alike when their hands differ less than this in rotation and position:
#: the next ones tried differ from those tried (a blocked descent repeats for its neighbours).
ALIKE_DEG = 25.0
ALIKE_M = 0.01
#: When no instance has a grasp left but some were left out as alike a grasp the arm could
#: not reach (:meth:`BinPicker._untried`), the bin tries them again, this many times at most
#: (each try is a pick of the budget).
RETRY_FAILED_ROUNDS = 2
#: When no instance has a grasp, the planning rounds are drawn again this many times (the
#: synthesis samples the model's surface at random) before the bin pushes a part or stops;
#: the push asks for a pair in as many draws. Tuning bin 32 at 70778ef stopped on its last
#: part (upside down, 8 mm from the -y wall) with one draw per round: at that stop six draws
#: gave 2-14 candidates with no obstacles and 0-5 in the "touch" round, and the push's
#: check drew 0 (no pair: no push). 3: in that state 3 of the 6 "touch" draws had a
#: candidate, so four draws all miss about once in 16.
GRASP_REDRAWS = 3


def _alike(a: Any, b: Any) -> bool:
    """Two candidates' hands within :data:`ALIKE_DEG` and :data:`ALIKE_M` of each other."""
    c = (np.trace(a.hand_rotation.T @ b.hand_rotation) - 1.0) / 2.0
    turn = float(np.degrees(np.arccos(np.clip(c, -1.0, 1.0))))
    gap = float(np.linalg.norm(np.subtract(a.pinch_world, b.pinch_world)))
    return turn < ALIKE_DEG and gap < ALIKE_M


def _diverse(cands: Sequence[Any], n: int) -> list[Any]:
    """Up to ``n`` of ``cands``, best first, each unlike those before it; then, when too few
    differ, the best of the rest."""
    out: list[Any] = []
    for c in cands:
        if len(out) < n and not any(_alike(c, o) for o in out):
            out.append(c)
    rest = [c for c in cands if not any(c is o for o in out)]
    return out + rest[: n - len(out)]


def _to_try(cands: Sequence[Any]) -> list[Any]:
    """The candidates a pick tries, in order: :data:`TRY_TOP_DOWN` top-down ones, then
    :data:`TRY_TILTED` tilted ones (``rotation_world`` set), each kind best first and
    unlike one another (:func:`_diverse`)."""
    top = [c for c in cands if getattr(c, "rotation_world", None) is None]
    tilted = [c for c in cands if getattr(c, "rotation_world", None) is not None]
    return _diverse(top, TRY_TOP_DOWN) + _diverse(tilted, TRY_TILTED)


#: The lift's first :data:`LIFT_SLOW_M` go at :data:`LIFT_SLOW_SPACING_M` per waypoint (3
#: control periods each: ~3 cm/s instead of ~17): as the part leaves the table it hangs on
#: the pads alone, often two of them (a hinge), and the fast start turned it out of the
#: grasp (tuning bin 5, the state before its slip replayed: fast, turned 43 deg and fell;
#: slow, turned 4 deg and carried; docs/bin.md "Slips").
LIFT_SLOW_M = 0.03
LIFT_SLOW_SPACING_M = 0.002


def _pick(
    ctl: Any,
    cands: Sequence[Any],
    action: Any,
    index: int,
    perturb: PlanPerturbation | None,
    table_z: float,
    touch_n: float,
    *,
    felt: list[np.ndarray] | None = None,
) -> tuple[bool, str, np.ndarray | None, list[Any]]:
    """Reach, close and lift with the first reachable candidate. Returns (believed held,
    failure reason, (4, 4) pinch-to-world where the hand closed when held, else None, the
    candidates the arm could not reach: not tried again, :meth:`BinPicker._untried`).

    A top-down descent that stops short appends :func:`felt_points` to ``felt`` (when
    given); the candidates after it that would bring a finger down there are skipped."""
    plan = None
    no_ik = blocked = 0
    tried: list[Any] = []
    felt_here: list[np.ndarray] = []
    for cand in _to_try(cands):
        if felt_here and fingers_blocked(cand, np.concatenate(felt_here), 0.0):
            continue
        tried.append(cand)
        p = cand.plan(action)
        if perturb is not None:
            p = perturb(index, p)
        rot = p.target_rotation
        ctl.preshape(p.preshape_q, 10)
        pre = ctl.move_to(p.pregrasp_world, p.yaw_rad, spacing_m=0.03, rotation=rot)
        if not (pre or _reached(ctl, p.pregrasp_world, p.hand_rotation)):
            # once more from where the arm stopped: in free space above the bin it had
            # stopped 5-30 mm short (a waypoint's IK or a slow settle; tuning bin 6)
            pre = ctl.move_to(p.pregrasp_world, p.yaw_rad, spacing_m=0.01, rotation=rot)
            if not (pre or _reached(ctl, p.pregrasp_world, p.hand_rotation)):
                no_ik += 1
                continue
        grasp = np.asarray(p.grasp_point_world)
        down = ctl.move_to(grasp, p.yaw_rad, spacing_m=0.01, rotation=rot)
        if down or _reached(ctl, grasp, p.hand_rotation):
            plan = p
            break
        blocked += 1
        stop = felt_points(cand, ctl.pinch_pos())
        if stop is not None:
            felt_here.append(stop)
            if felt is not None:
                felt.append(stop)
        ctl.move_to(p.pregrasp_world, p.yaw_rad, spacing_m=0.02, rotation=rot)
    if plan is None:
        return False, f"unreachable ({no_ik} pre-grasp, {blocked} descent blocked)", None, tried
    rot = plan.target_rotation
    closed = ctl.close(threshold=touch_n, yaw=plan.yaw_rad, rotation=rot)
    a, b = closed.sides(touch_n)
    if not (a and b):
        return False, "no two-sided contact", None, tried[:-1]
    if _hand_empty(closed.finger_qpos):
        return False, "closed on nothing", None, tried[:-1]
    pinch_to_world = np.eye(4)  # where the hand closed (after any re-centring)
    pinch_to_world[:3, :3], pinch_to_world[:3, 3] = ctl.pinch_rotation(), ctl.pinch_pos()
    up = np.asarray(plan.grasp_point_world, dtype=float).copy()
    up[2] = table_z + CLEARANCE_ABOVE_M
    # the first centimetres slowly: the part leaves the table's support (docs/bin.md "Slips")
    first = ctl.pinch_pos()
    first[2] = min(first[2] + LIFT_SLOW_M, up[2])
    ctl.move_to(first, plan.yaw_rad, spacing_m=LIFT_SLOW_SPACING_M, rotation=rot)
    ctl.move_to(up, plan.yaw_rad, spacing_m=0.01, rotation=rot)
    if not _held(ctl):
        return False, "slipped", None, tried[:-1]
    return True, "", pinch_to_world, tried[:-1]


#: A move that ``move_to`` reports failed (a waypoint's IK on the way did not converge, or
#: the arm settled slowly) still counts when the pinch site ended this close to the target.
REACHED_M = 0.005
REACHED_DEG = 3.0


def _reached(ctl: Any, pos: np.ndarray, rotation: np.ndarray) -> bool:
    """The pinch site is within :data:`REACHED_M` and :data:`REACHED_DEG` of the pose (the
    robot's own forward kinematics)."""
    if float(np.linalg.norm(ctl.pinch_pos() - np.asarray(pos, dtype=float))) > REACHED_M:
        return False
    c = (np.trace(ctl.pinch_rotation().T @ np.asarray(rotation, dtype=float)) - 1.0) / 2.0
    return bool(np.degrees(np.arccos(np.clip(c, -1.0, 1.0))) <= REACHED_DEG)


def _hand_empty(finger_qpos: np.ndarray) -> bool:
    """The fingers closed past :data:`EMPTY_HAND_Q`: the pads touch each other, nothing is
    between them (touch alone cannot tell)."""
    return float(np.min(finger_qpos)) > EMPTY_HAND_Q


def _held(ctl: Any) -> bool:
    """Something is between the fingers: they stopped short of closing past
    :data:`EMPTY_HAND_Q` (:func:`_hand_empty`). With the part slipped out they close past it
    and the pads press on each other and touch (tuning bin 6: three parts "held" by touch
    all the way to the box, left in the bin).

    Touch is not asked for: a part that turns in the grasp as it is lifted may rest on the
    fingers' links beyond the pads, lifted 10 cm with the pads of one side or of all three
    fingers reading under 10 mN (tuning bins 1 and 8, traced with the ground truth). Reported
    ``slipped``, it was let go over the bin from the travel height and scattered the pile
    (bin 8: the next sensing found no grasp, four parts left)."""
    return not _hand_empty(ctl.finger_qpos())


def _rect_overlap(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Overlap areas of axis-aligned rectangles ``a`` (N, 4) with ``b`` (4,), rows
    (xmin, ymin, xmax, ymax)."""
    w = np.minimum(a[:, 2], b[2]) - np.maximum(a[:, 0], b[0])
    h = np.minimum(a[:, 3], b[3]) - np.maximum(a[:, 1], b[1])
    return np.clip(w, 0.0, None) * np.clip(h, 0.0, None)


def place_middle(half_xy: np.ndarray, placed: Sequence[np.ndarray], box: OutputBox) -> np.ndarray:
    """Where in the output ``box`` a part's middle goes: on a :data:`PLACE_GRID` grid over
    the room its footprint leaves (``half_xy``, the half sides of its bounding rectangle,
    :data:`PLACE_MARGIN_M` inside the walls' centres), the place whose rectangle overlaps
    least those of the parts let go before (``placed``: rows (xmin, ymin, xmax, ymax), the
    robot's own record, nothing sensed); of equals, the first from the box's -x, -y corner
    (row by row: the parts fill the box from one side, leaving room for the next). A
    footprint wider than the box goes to its centre along that side.
    """
    half = np.asarray(half_xy, dtype=float)
    room = np.maximum(np.asarray(box.half_xy) - PLACE_MARGIN_M - half, 0.0)
    u = np.linspace(-1.0, 1.0, PLACE_GRID)
    grid = np.stack(np.meshgrid(u, u, indexing="ij"), axis=-1).reshape(-1, 2) * room
    grid += np.asarray(box.center_xy, dtype=float)
    rects = np.hstack([grid - half, grid + half])
    overlap = np.zeros(len(grid))
    for r in np.asarray(placed, dtype=float).reshape(-1, 4):
        overlap += _rect_overlap(rects, r)
    return np.asarray(grid[int(np.argmin(np.round(overlap * 1e6)))])  # mm^2: ties go first


def _turned(d: np.ndarray, angle: float) -> np.ndarray:
    """(N, 2) offsets ``d`` turned by ``angle`` (radians, counter-clockwise seen from above:
    as the hand's yaw grows)."""
    c, s = np.cos(angle), np.sin(angle)
    return np.asarray(d) @ np.array([[c, s], [-s, c]])


def _turn_to_fit(W: np.ndarray, pos: np.ndarray, *, long_along_x: bool = True) -> float:
    """The turn (radians, |turn| <= 90 deg, in :data:`PLACE_TURN_STEP_DEG` steps) about the
    vertical through the pinch point ``pos`` that makes the footprint of the carried part
    ``W`` (N, 3) the smallest bounding rectangle, its long side along x (the box's; with
    ``long_along_x=False`` its short side, along which a part standing on edge falls); the
    smallest such turn."""
    steps = np.radians(np.arange(-90.0, 90.0 + 1e-9, PLACE_TURN_STEP_DEG))
    steps = steps[np.argsort(np.abs(steps), kind="stable")]
    d = W[:, :2] - pos[:2]
    areas = []
    for a in steps:
        q = _turned(d, a)
        ext = q.max(axis=0) - q.min(axis=0)
        along = ext[0] < ext[1] if long_along_x else ext[0] > ext[1]
        areas.append((round(ext[0] * ext[1] * 1e6), along))  # mm^2, then the side along x
    return float(steps[min(range(len(steps)), key=areas.__getitem__)])


def fall_room(W: np.ndarray, half_xy: np.ndarray) -> np.ndarray:
    """(2,) half sides of the rectangle a carried part may end in once let go: its footprint's
    ``half_xy`` (x, y), the short side grown by the part's height when it stands taller than
    that side is wide (``W`` (N, 3), the part as carried, metres).

    A part held on edge or on end falls over when let go; it tips over a long bottom edge and
    then lies up to its height beyond it (tuning bins 0 and 3: parts held on their side, let
    go 15 mm inside the box's wall, fell over it).
    """
    half = np.asarray(half_xy, dtype=float).copy()
    height = float(W[:, 2].max() - W[:, 2].min())
    k = int(np.argmin(half))
    if height > 2.0 * half[k]:
        half[k] += height
    return half


# -- passengers: parts lifted with the held one ----------------------------------------------
#: Sensed points at the travel height count as lifted when they stand this much above
#: everything sensed before the pick within :data:`LIFTED_CELL_M` (the scanner's noise is
#: 0.5 mm; a part settling in the pile moves a few millimetres).
LIFTED_ABOVE_M = 0.015
LIFTED_CELL_M = 0.01
#: ... and lie within this distance of the pinch point, horizontally: a passenger hung up
#: to 230 mm from it (tuning bin 36).
LIFTED_REACH_M = 0.25
#: A lifted point within this distance of the held part's model, posed at its estimate moved
#: with the hand (after :func:`_fit_held`), is the held part's own.
HELD_OWN_M = 0.006
#: The held part's estimate is refined on the lifted points (trimmed ICP: pairs within this
#: distance, this many rounds): a part held off its centre turns in the grasp by up to ~30 mm.
HELD_FIT_PAIR_M = 0.02
HELD_FIT_ROUNDS = 15
#: At least this many lifted points the held part does not explain are a passenger: the
#: passengers seen on tuning bins 22, 27, 35, 36 showed 800-2472 (a part ~300-1500 at the
#: scanner's 2.5 mm spacing); with 40, 43 points beside a part lifted alone (bin 27's first
#: pick: a neighbour tipped up, or an edge of the held part its estimate misses) made a
#: "bundle" that was let go outside the box.
PASSENGER_POINTS = 150
#: The held part is carried as seen at the travel height (its estimate refined on the lifted
#: points, :func:`held_and_passengers`) when the refined pose has at least this many of them
#: within HELD_OWN_M, and no fewer than the estimate it was grasped at. A part turns and
#: slides in the grasp: the six lifts of tuning bin 19 (simulator truth, diagnosis only)
#: carried estimates 2-33 mm off the part as it hung, the refined poses 0.1-5 mm. The 33 mm
#: one (8 deg; refined 5 mm, 3 deg) ended `not in the box`: the held part was back in the
#: bin, and a second part lifted with it, seen as 18 points, lay outside the box.
HELD_FIT_MIN_POINTS = 50


def lifted_points(
    points_world: np.ndarray, before_world: np.ndarray, pinch_world: np.ndarray, table_z: float
) -> np.ndarray:
    """(M,) bool: ``points_world`` (N, 3) sensed with the hand up that were lifted: within
    :data:`LIFTED_REACH_M` of the pinch point ``pinch_world`` (3,) horizontally and more than
    :data:`LIFTED_ABOVE_M` above every point sensed before the pick (``before_world`` (K, 3),
    the scene's points) in their :data:`LIFTED_CELL_M` cell and its eight neighbours; where
    nothing was sensed before, above the table (``table_z``). Metres, world frame."""
    P = np.asarray(points_world, dtype=float).reshape(-1, 3)
    B = np.asarray(before_world, dtype=float).reshape(-1, 3)
    near = np.linalg.norm(P[:, :2] - np.asarray(pinch_world)[:2], axis=1) < LIFTED_REACH_M
    floor = np.full(len(P), float(table_z))
    if len(B):
        # the highest point before in each cell (never below the table), on a grid one cell
        # wider than the scene's points all round, then the most of each 3 x 3 block
        cells_b = np.floor(B[:, :2] / LIFTED_CELL_M).astype(np.int64)
        lo = cells_b.min(axis=0) - 1
        ib = cells_b - lo
        top = np.full(tuple(ib.max(axis=0) + 2), float(table_z))
        np.maximum.at(top, (ib[:, 0], ib[:, 1]), B[:, 2])
        block = maximum_filter(top, size=3, mode="constant", cval=float(table_z))
        ip = np.floor(P[:, :2] / LIFTED_CELL_M).astype(np.int64) - lo
        on = near & np.all((ip >= 0) & (ip < np.array(top.shape)), axis=1)
        floor[on] = block[ip[on, 0], ip[on, 1]]
    return np.asarray(near & (P[:, 2] > floor + LIFTED_ABOVE_M))


def _fit_held(samples: np.ndarray, T: np.ndarray, points: np.ndarray) -> np.ndarray:
    """``T`` (4, 4) moved so that the model's surface ``samples`` (model frame) fits the
    ``points`` (N, 3) near it: trimmed point-to-point ICP (:data:`HELD_FIT_PAIR_M`,
    :data:`HELD_FIT_ROUNDS`), the points of a passenger mostly beyond the trim."""
    from scipy.spatial import cKDTree

    from mks_sim.geometry.transforms import rigid_fit

    T = np.array(T, dtype=float)
    for _ in range(HELD_FIT_ROUNDS):
        posed = samples @ T[:3, :3].T + T[:3, 3]
        d, j = cKDTree(posed).query(points, distance_upper_bound=HELD_FIT_PAIR_M)
        ok = np.isfinite(d)
        if ok.sum() < 10:
            break
        # model points -> their sensed partners (Kabsch)
        step = rigid_fit(posed[j[ok]], points[ok])[0]
        T = step @ T
        if np.linalg.norm(step[:3, 3]) < 1e-4:
            break
    return T


def held_and_passengers(
    points_world: np.ndarray,
    before_world: np.ndarray,
    samples: np.ndarray,
    held_world: np.ndarray,
    pinch_world: np.ndarray,
    table_z: float,
) -> tuple[np.ndarray | None, np.ndarray]:
    """(the held part's pose refined on its points seen, world frame, or None; (K, 3) the
    points of parts lifted with the held one (passengers), world frame, (0, 3) when fewer
    than :data:`PASSENGER_POINTS` (none seen)).

    Args:
        points_world: (N, 3) sensed with the hand at the travel height (the scanner
            self-filters the robot, so neither hand nor fingers are in them).
        before_world: (K, 3) the scene's points sensed before the pick.
        samples: (S, 3) the model's surface (model frame).
        held_world: (4, 4) the held part's estimate moved with the hand (the instance's
            localized pose, carried from where the hand closed to where it is).
        pinch_world: (3,) the pinch point now.
        table_z: the table top.

    The lifted points (:func:`lifted_points`) fit the model's surface ``samples`` from the
    estimate ``held_world`` (:func:`_fit_held`). The refined pose is returned when it has at
    least :data:`HELD_FIT_MIN_POINTS` of them within :data:`HELD_OWN_M` and no fewer than the
    estimate has (else None: too little of the part seen to say more). The lifted points
    farther than :data:`HELD_OWN_M` from the refined pose are the passengers'.
    """
    P = np.asarray(points_world, dtype=float).reshape(-1, 3)
    P = P[np.all(np.isfinite(P), axis=1)]
    up = P[lifted_points(P, before_world, pinch_world, table_z)]
    if len(up) < HELD_FIT_MIN_POINTS:
        return None, np.empty((0, 3))
    T = _fit_held(samples, held_world, up)
    own = _near_surface(samples, T, up, HELD_OWN_M)
    before = int(_near_surface(samples, held_world, up, HELD_OWN_M).sum())
    held = T if int(own.sum()) >= max(HELD_FIT_MIN_POINTS, before) else None
    left = up[~own]
    if len(left) < PASSENGER_POINTS:  # left is a subset of up
        return held, np.empty((0, 3))
    return held, left


def _carry_to_box(
    ctl: Any,
    part_pinch: np.ndarray,
    table_z: float,
    rotation: np.ndarray | None,
    box: OutputBox,
    *,
    placed: list[np.ndarray] | None = None,
    passengers: np.ndarray | None = None,
) -> str:
    """Carry the held part over the output box and lower it in; "" or why not.

    Args:
        ctl: the arm and hand, holding the part.
        part_pinch: (N, 3) the part's model vertices in the pinch frame (its estimate at the
            grasp, carried by the hand: the robot's belief, no ground truth), metres.
        table_z: the table top (the box's floor), metres.
        rotation: the hand's rotation to keep (a tilted grasp), or None (top-down, its yaw).
        box: the output box (:func:`output_box`).
        placed: the footprints (xmin, ymin, xmax, ymax) of the parts let go in the box
            before (:func:`place_middle`); this part's is appended once its place is chosen
            (also when it is then dropped on the way). None: the box's centre.
        passengers: (K, 3) points of parts lifted with the held one, in the pinch frame
            (:func:`held_and_passengers`): the bundle's lowest point, footprint and place are
            those of the held part and them together.

    The part's middle goes over its place in the box with its lowest point (or the
    fingertips') ``CARRY_MARGIN_M`` above the walls on the way, then down to
    ``RELEASE_GAP_M`` above the box's rim; a bundle in a place no part was let go in before
    on down to ``BUNDLE_FLOOR_GAP_M`` above the box's floor. A bundle goes over the walls
    ``BUNDLE_LIFT_M`` higher (a passenger may hang lower than its points seen) and at
    ``BUNDLE_SPACING_M`` a waypoint. A part carried top-down
    (``rotation`` None) is turned on the way so that its footprint's bounding rectangle is
    smallest, long side along the box's x; one that will fall over when let go
    (:func:`fall_room`) short side along x, and its place leaves it room to fall.
    """
    pos, yaw = ctl.pinch_pos(), ctl.pinch_yaw()
    R = ctl.pinch_rotation()
    W = part_pinch @ R.T + pos  # (N, 3) the part as carried
    A = W  # ... with its passengers: the bundle
    bundle = passengers is not None and len(passengers) > 0
    if bundle:
        A = np.vstack([W, np.asarray(passengers, dtype=float) @ R.T + pos])
    below = max(pos[2] - float(A[:, 2].min()), TIPS_BELOW_PINCH_M)
    rim = box.wall_height_m
    travel_z = max(pos[2], table_z + max(BIN_WALL_M, rim) + CARRY_MARGIN_M + below)
    if bundle:
        travel_z += BUNDLE_LIFT_M
    release_z = table_z + rim + RELEASE_GAP_M + below
    turn = 0.0
    if rotation is None and placed is not None:
        turn = _turn_to_fit(A, pos)
        half = 0.5 * np.ptp(_turned(A[:, :2] - pos[:2], turn), axis=0)
        if np.any(fall_room(W, half) > half):  # it will fall over: along the box's length
            turn = _turn_to_fit(A, pos, long_along_x=False)
    Wxy = _turned(A[:, :2] - pos[:2], turn) + pos[:2]
    lo, hi = Wxy.min(axis=0), Wxy.max(axis=0)
    middle_off = 0.5 * (lo + hi) - pos[:2]
    free = False  # nothing was let go where this one goes (by the robot's record)
    if placed is None:
        middle = np.asarray(box.center_xy, dtype=float)
    else:
        room = fall_room(W, 0.5 * (hi - lo))
        middle = place_middle(room, placed, box)
        mine = np.concatenate([middle - room, middle + room])
        free = not np.any(_rect_overlap(np.asarray(placed, dtype=float).reshape(-1, 4), mine))
        placed.append(mine)
    over = np.array([*(middle - middle_off), travel_z])
    if travel_z > pos[2] + 0.005:
        ctl.move_to(np.array([pos[0], pos[1], travel_z]), yaw, spacing_m=0.01, rotation=rotation)
    yaw += turn
    spacing = BUNDLE_SPACING_M if bundle else CARRY_SPACING_M
    ctl.move_to(over, yaw, spacing_m=spacing, rotation=rotation)
    ctl.move_to(np.array([over[0], over[1], release_z]), yaw, spacing_m=0.01, rotation=rotation)
    if bundle and free:
        low = np.array([over[0], over[1], table_z + BUNDLE_FLOOR_GAP_M + below])
        ctl.move_to(low, yaw, spacing_m=0.005, rotation=rotation)
    return "" if _held(ctl) else "dropped while carried"


#: After the hand opened over the box, a pad reading more than this (N, summed pad force)
#: says the part still hangs on a finger. Tuning bin 21's third pick: the part, grasped by
#: its 22 mm step, hung on finger 1's pad with the hand open (93 N on that pad, under 0.01 N
#: on the others), was lifted with the hand and fell on the table on the way home.
HUNG_TOUCH_N = 0.5
#: ... then the hand goes down this far (the part comes to rest on the box's floor or the
#: parts in it, and the pad comes free) and up again; at most HUNG_TRIES times. The same
#: pick replayed: lowered 30 mm, the pad read 0.01 N and the part stayed in the box as the
#: hand rose; moved 40 mm sideways or turned 60 deg instead, the part stayed on the pad.
HUNG_LOWER_M = 0.03
HUNG_TRIES = 2


def _set_down_hung(ctl: Any, table_z: float) -> int:
    """The hand has opened over the box: while a pad still feels the part (more than
    :data:`HUNG_TOUCH_N`), lower the hand :data:`HUNG_LOWER_M` (not below the fingertips
    on the box's floor) and raise it back; returns how many times (0: nothing hung on it;
    a failed pad reads nan and feels nothing)."""
    tries = 0
    keep = _kept(ctl)  # straight up and down: the hand's orientation does not change
    while tries < HUNG_TRIES:
        touch = np.nan_to_num(np.asarray(ctl.touch(), dtype=float), nan=0.0)
        if float(touch.max()) <= HUNG_TOUCH_N:
            break
        tries += 1
        logger.debug("the part hangs on the open hand (pads %s N); setting it down", touch)
        at = ctl.pinch_pos()
        down = at.copy()
        down[2] = max(at[2] - HUNG_LOWER_M, table_z + TIPS_BELOW_PINCH_M)
        ctl.move_to(down, ctl.pinch_yaw(), spacing_m=0.005, rotation=keep)
        ctl.move_to(at, ctl.pinch_yaw(), spacing_m=0.01, rotation=keep)
    return tries


def _kept(ctl: Any) -> np.ndarray | None:
    """The hand's rotation when it is tilted (to keep while it moves), None when it points
    straight down (moves then hold its yaw)."""
    R = ctl.pinch_rotation()
    return R if float(R[2, 2]) > -0.999 else None


# -- a push away from the wall (the closed hand as a paddle) ---------------------------------
#: A part whose estimated footprint (the model's vertices posed at its estimate) comes this
#: close to a wall's inner face is pushed when no grasp is left: an open finger's footprint
#: (:func:`finger_footprint`) reaches 35-36 mm beyond the face its pad is to close on, for
#: the part's 20 mm and 60 mm pinches alike, and :func:`walls_block` keeps it off the walls.
#: At 25 mm, tuning bin 11's upside-down part, pushed once out of a corner, came to rest
#: beyond that distance with every candidate over a wall, no push was planned, and the bin
#: stopped.
PUSH_NEAR_WALL_M = 0.04
#: The closed hand comes down this far inside the part's edge nearest the wall: the closed
#: fingers reach 15 mm on either side of the pinch point along the closing axis (measured:
#: the hand closed in free air at 1.31-1.35 rad, the fingers' collision boxes), and 5 mm more
#: keep them off the wall's top.
PUSH_INSET_M = 0.02
#: ... then moves this far toward the bin's middle (the part's footprint must come away
#: from the wall by more than the open fingers' clearance, 22 mm, and its own slip).
PUSH_DISTANCE_M = 0.05
#: The closed fingertips reach this far below the pinch point (measured as above: 10.2 mm)...
CLOSED_TIPS_BELOW_PINCH_M = 0.010
#: ... and their footprint's middle is this far along the pinch frame's y from it (fingers 2
#: and 3 at y = -44 and +15 mm, finger 1 between: -44.6 .. +15.3 mm measured).
CLOSED_TIPS_MIDDLE_Y_M = -0.0147
#: The fingertips are brought this far below the part's estimated top where they come down
#: (the arm is position-controlled: the offset is the press). Tuning bin 7's last part (its
#: stall replayed; upside down, leaning on the -x wall, top 48 mm high there): pressed 6 mm,
#: the hand slid over it and it moved 2 mm; pressed 15 mm, it lay down flat and moved 19 mm
#: off the wall, and the next sensing had grasps ("tight" round: 2, "touch": 4).
PUSH_PRESS_M = 0.015
#: The part's top where the hand comes down: its estimated surface within this distance
#: across (xy) of the hand's middle.
PUSH_TOP_RADIUS_M = 0.015
#: The hand comes down from this far above where it presses.
PUSH_ABOVE_M = 0.04
#: The far side of a pushed part stops this far from the opposite wall.
PUSH_FAR_MARGIN_M = 0.03
#: At most this many pushes of one part (an instance within PUSH_SAME_M of where an earlier
#: push started or was to end is the same part) and of one bin: each is a pick of the budget.
PUSHES_PER_INSTANCE = 2
PUSHES_PER_BIN = 4
PUSH_SAME_M = 0.03
#: The failure reason of a push in the picks' record (a push is no pick, but it is one of
#: the budget's).
PUSHED = "pushed"


@dataclass(frozen=True)
class PushPlan:
    """A push of a part away from the bin's walls with the closed hand, top-down.

    Attributes:
        direction: (2,) unit world xy direction of the push (away from the walls near it).
        start_world: (3,) the pinch point where the closed hand presses on the part, metres.
        end_world: (3,) where the push ends (``start_world`` moved along ``direction``).
        yaw_rad: the hand's yaw (its closing axis along ``direction``: the closed fingers'
            60 mm wide side across the push).
        wall_gap_m: the part's footprint's distance from the nearest wall, metres.
    """

    direction: np.ndarray
    start_world: np.ndarray
    end_world: np.ndarray
    yaw_rad: float
    wall_gap_m: float


def plan_push(
    part_world: np.ndarray, walls_lo: np.ndarray, walls_hi: np.ndarray, table_z: float
) -> PushPlan | None:
    """A push of a part away from the walls within :data:`PUSH_NEAR_WALL_M` of it, or None
    when no wall is that near.

    Args:
        part_world: (N, 3) the part's surface (the model's vertices posed at its estimate),
            world, metres.
        walls_lo, walls_hi: (2,) xy of the walls' inner faces (:func:`bin_walls_xy`).
        table_z: the bin's floor, metres.

    The direction is the sum of the near walls' inward normals (a corner: diagonal); the
    closed hand comes down :data:`PUSH_INSET_M` inside the part's edge on the walls' side
    (further in, up to the part's middle, until its footprint is inside the walls:
    :func:`_closed_hand_inside`),
    its fingertips :data:`PUSH_PRESS_M` below the part's estimated top there, and moves
    :data:`PUSH_DISTANCE_M` along the direction (less when the part's far side would come
    within :data:`PUSH_FAR_MARGIN_M` of the opposite wall).
    """
    P = np.asarray(part_world, dtype=float)
    lo, hi = np.asarray(walls_lo, dtype=float), np.asarray(walls_hi, dtype=float)
    xy_lo, xy_hi = P[:, :2].min(axis=0), P[:, :2].max(axis=0)
    gaps = np.array([xy_lo[0] - lo[0], hi[0] - xy_hi[0], xy_lo[1] - lo[1], hi[1] - xy_hi[1]])
    normals = np.array([[1.0, 0.0], [-1.0, 0.0], [0.0, 1.0], [0.0, -1.0]])
    near = gaps < PUSH_NEAR_WALL_M
    if not near.any():
        return None
    d = normals[near].sum(axis=0)
    if np.linalg.norm(d) < 1e-9:  # between two opposite walls: nowhere to go
        return None
    d /= np.linalg.norm(d)
    across = np.array([-d[1], d[0]])
    s, t = P[:, :2] @ d, P[:, :2] @ across
    # room ahead: the far side's distance to the walls ahead, along d
    ahead = [(hi - xy_hi)[k] / d[k] if d[k] > 1e-9 else (xy_lo - lo)[k] / -d[k] if d[k] < -1e-9
             else np.inf for k in range(2)]  # fmt: skip
    distance = float(np.clip(min(ahead) - PUSH_FAR_MARGIN_M, 0.0, PUSH_DISTANCE_M))
    if distance <= 0.0:
        return None

    # the closed hand comes down inside the walls: further in than PUSH_INSET_M where its
    # footprint would reach over a wall (a corner's diagonal push), at most to the middle;
    # where no inset brings it inside (a wall beside the part, across the push), at
    # PUSH_INSET_M
    def middle_at(inset: float) -> np.ndarray:
        return (s.min() + inset) * d + 0.5 * (t.min() + t.max()) * across  # (2,)

    insets = np.arange(PUSH_INSET_M, max(PUSH_INSET_M, 0.5 * np.ptp(s)) + 1e-9, 0.002)
    fits = (k for k in insets if _closed_hand_inside(middle_at(k), d, lo, hi))
    middle = middle_at(next(fits, PUSH_INSET_M))
    top = P[np.linalg.norm(P[:, :2] - middle, axis=1) < PUSH_TOP_RADIUS_M, 2]
    top_z = float(top.max()) if len(top) else float(P[:, 2].max())
    tips_z = max(top_z - PUSH_PRESS_M, table_z + 0.003)
    yaw = float(np.arctan2(d[1], d[0]))
    # the pinch point: the closed fingertips' middle is CLOSED_TIPS_MIDDLE_Y_M along the
    # pinch frame's y, which is (sin yaw, -cos yaw) for a top-down hand (grasp.down_rotation)
    y_axis = np.array([np.sin(yaw), -np.cos(yaw)])
    pinch_xy = middle - CLOSED_TIPS_MIDDLE_Y_M * y_axis
    start = np.array([*pinch_xy, tips_z + CLOSED_TIPS_BELOW_PINCH_M])
    end = start + np.array([*(distance * d), 0.0])
    return PushPlan(d, start, end, yaw, float(gaps[near].min()))


#: The closed hand's footprint around the closed fingertips' middle: this far either way
#: along the closing axis (the fingers' 15 mm, above) and across it (fingers 2 and 3 at -44.6
#: and +15.3 mm: 30 mm either way of their middle). With the 5 mm margin PUSH_INSET_M keeps
#: as well, tuning bin 7's replayed push (a part leaning on one wall) was pressed 2 mm
#: further in and did not move the part.
CLOSED_HAND_ALONG_M = 0.015
CLOSED_HAND_ACROSS_M = 0.030


def _closed_hand_inside(middle: np.ndarray, d: np.ndarray, lo: np.ndarray, hi: np.ndarray) -> bool:
    """The closed hand's footprint (:data:`CLOSED_HAND_ALONG_M` along ``d``,
    :data:`CLOSED_HAND_ACROSS_M` across it, around ``middle``; world xy) lies inside the walls'
    inner faces ``lo``, ``hi``. Tuning bin 11: a part 11 mm from two walls, pushed diagonally
    out of the corner; the closed hand came down with fingertip 2 on a wall's top, 18 mm
    above where it was to press, and the part moved 14 mm instead of 50."""
    across = np.array([-d[1], d[0]])
    corners = np.array(
        [middle + a * CLOSED_HAND_ALONG_M * d + b * CLOSED_HAND_ACROSS_M * across
         for a in (-1, 1) for b in (-1, 1)]
    )  # fmt: skip
    return bool(np.all(corners >= lo) and np.all(corners <= hi))


def _pushed_from_to(T: np.ndarray, plan: PushPlan) -> np.ndarray:
    """(2, 3) a pushed part's estimated origin before the push and where it was pushed to."""
    start = np.asarray(T, dtype=float)[:3, 3]
    return np.stack([start, start + (plan.end_world - plan.start_world)])


def _push_candidate(
    robot: BinPicker, found: Sequence[Any], order: Sequence[int], pushed: Sequence[np.ndarray]
) -> tuple[int, PushPlan] | None:
    """The first instance in ``order`` that has an antipodal pair (with no obstacles) or
    leans (:func:`leans`: pushed, it lies down, and may have one then), lies within
    :data:`PUSH_NEAR_WALL_M` of a wall and was pushed fewer than
    :data:`PUSHES_PER_INSTANCE` times (an earlier push started or was to end within
    :data:`PUSH_SAME_M` of its estimated origin), and its push; or None. Only the estimate,
    the model and the walls (scene data) are used."""
    walls_lo, walls_hi = bin_walls_xy(robot.world)
    V = np.asarray(robot.obj.mesh.vertices, dtype=float)
    for i in order:
        T = found[i].matrix
        near = sum(bool(np.any(np.linalg.norm(p - T[:3, 3], axis=1) < PUSH_SAME_M)) for p in pushed)
        if near >= PUSHES_PER_INSTANCE:
            continue
        posed = V @ T[:3, :3].T + T[:3, 3]
        if not _has_pair(robot, i):
            com = T[:3, :3] @ np.asarray(robot.obj.mesh.centroid, dtype=float) + T[:3, 3]
            if not leans(posed, com):
                continue
            logger.info("push: instance %d has no pair but leans", i)
        plan = plan_push(posed, walls_lo, walls_hi, robot.table_z)
        if plan is not None:
            return i, plan
    return None


#: A posed part stands by itself when its centre of mass lies over the support polygon of
#: its vertices within LEAN_TOUCH_M of the lowest (an estimate of a part flat on a face is
#: tilted 1-2 deg: 2-3.5 mm over 100 mm), at least LEAN_INSIDE_M inside it.
LEAN_TOUCH_M = 0.004
LEAN_INSIDE_M = 0.002


def leans(vertices_world: np.ndarray, com_world: np.ndarray) -> bool:
    """The part posed as ``vertices_world`` (N, 3) with its centre of mass at ``com_world``
    (3,) cannot rest so by itself (world, metres): it leans on something, a wall or another
    part. True when the centre of mass is not over the convex hull (xy) of the vertices
    within :data:`LEAN_TOUCH_M` of the lowest by :data:`LEAN_INSIDE_M`, or those vertices
    span no area (an edge or a corner on the table). Tuning bin 42: a part leaning 33 deg
    on the bin's +y wall had no antipodal pair, so no push was planned, and the bin stopped
    with it left."""
    from scipy.spatial import ConvexHull, QhullError

    P = np.asarray(vertices_world, dtype=float).reshape(-1, 3)
    low = P[P[:, 2] <= P[:, 2].min() + LEAN_TOUCH_M, :2]
    if len(low) < 3:
        return True
    try:
        hull = ConvexHull(low)
    except QhullError:  # on a line
        return True
    c = np.asarray(com_world, dtype=float)[:2]
    # the facets' outward unit normals and offsets: inside where every n . x + b <= 0
    return bool(np.any(hull.equations[:, :2] @ c + hull.equations[:, 2] > -LEAN_INSIDE_M))


def _has_pair(robot: Any, i: int) -> bool:
    """Instance ``i`` has an antipodal pair with no obstacles in one of up to
    1 + :data:`GRASP_REDRAWS` draws of the synthesis (:meth:`BinPicker.redraw`)."""
    return _in_draws(robot, lambda: True if robot.grasps(i, obstacles="none") else None) is not None


def _push(ctl: Any, plan: PushPlan, home_pos: np.ndarray, home_yaw: float) -> bool:
    """Close the hand, come down on the part, push it along ``plan``, lift and go home.
    Returns whether the hand reached where it presses (the push itself is judged by the next
    sensing)."""
    ctl.preshape(1.35, 30)  # closed: the fingers as one paddle
    above = plan.start_world + np.array([0.0, 0.0, PUSH_ABOVE_M])
    over = np.array([*above[:2], max(above[2], ctl.pinch_pos()[2])])
    ctl.move_to(over, plan.yaw_rad, spacing_m=0.03)
    ctl.move_to(above, plan.yaw_rad, spacing_m=0.02)
    down = ctl.move_to(plan.start_world, plan.yaw_rad, spacing_m=0.005)
    pressed = down or float(np.linalg.norm(ctl.pinch_pos() - plan.start_world)) < 0.02
    ctl.move_to(plan.end_world, plan.yaw_rad, spacing_m=0.003)
    up = ctl.pinch_pos() + np.array([0.0, 0.0, PUSH_ABOVE_M])
    ctl.move_to(up, plan.yaw_rad, spacing_m=0.01)
    ctl.open(25)
    ctl.move_to(home_pos, home_yaw, spacing_m=0.03)
    return pressed


def run_clear_bin(
    seed: int,
    *,
    object_name: str | None = None,
    count: int | None = None,
    fail: Sequence[str] = (),
    budget: int | None = None,
    perturb: PlanPerturbation | None = None,
    scene: str | Path = BIN_SCENE,
    active: bool = True,
    models: Sequence[str | Path] = (),
    table: bool = True,
) -> dict[str, Any]:
    """Build the bin from ``seed`` and clear it (:func:`clear_bin`): the record of
    ``mks-sim grasp --task clear_bin`` (plus ``seed``, ``object``, ``failed_devices``, and
    ``in_box_heights_m``: how high above the table the origin of each part counted in the
    box rests, and ``left``: where the others are, :func:`parts_left`; ground truth,
    evaluation only).

    Raises:
        SpecError: the scene has no ``[output_box]``.
    """
    from mks_sim.devices import DeviceFaults, make_devices

    world = bin_world(seed, count=count, object=object_name, scene=scene, models=models)
    output_box(world)  # somewhere to put the parts, before anything moves
    name = object_name or next(iter(world.scene.models.values()))
    faults = {dev: DeviceFaults(failed=True) for dev in fail}
    with make_devices(world.model, world.data, np.random.default_rng(seed), faults) as devices:
        rec = clear_bin(
            world, devices, object_name=name, rng=np.random.default_rng(seed), budget=budget,
            perturb=perturb, active=active, models=models, table=table,
        )  # fmt: skip
    from mks_sim.sim import truth

    heights = [
        round(float(truth.object_to_world(world, b)[2, 3] - world.scene.support_z), 4)
        for b in instance_bodies(world)
        if in_output_box(world, b)
    ]  # evaluation: how high the parts counted in the box rest
    return {
        "seed": seed, "object": name, "failed_devices": list(fail), **rec,
        "in_box_heights_m": sorted(heights), "left": parts_left(world),
    }  # fmt: skip
