"""Judging an episode with simulator ground truth (EVALUATION ONLY).

Nothing here may be imported by the controller, the sensors or the matchers: this module
reads the true object pose (``mks_sim.sim.truth``) and the true geometry to score what the
sensor-driven loop did.

Success (issue #5): the object's lowest point at least ``MIN_CLEARANCE_M`` (8 cm) above the
table top during the whole ``HOLD_S`` (1 s) hold that follows the lift.
"""

from __future__ import annotations

from dataclasses import dataclass

import mujoco
import numpy as np

from mks_sim.geometry.transforms import rotation_angle_deg

MIN_CLEARANCE_M = 0.08
HOLD_S = 1.0


def true_object_to_world(world, name: str) -> np.ndarray:
    """(4, 4) true pose of body ``name`` (ground truth)."""
    from mks_sim.sim import truth

    return np.asarray(truth.object_to_world(world, name), dtype=float)


def lowest_point_z(model: mujoco.MjModel, data: mujoco.MjData, body: str) -> float:
    """World z (m) of the lowest point of the body's geoms (every group, collision or not).

    Spheres and meshes are exact; other geoms use the 8 corners of their local bounding box
    (exact for boxes, conservative for cylinders and capsules).
    """
    bid = model.body(body).id
    zmin = np.inf
    for g in np.flatnonzero(model.geom_bodyid == bid):
        pos = data.geom_xpos[g]
        if model.geom_type[g] == mujoco.mjtGeom.mjGEOM_SPHERE:
            zmin = min(zmin, pos[2] - model.geom_size[g, 0])
            continue
        R = data.geom_xmat[g].reshape(3, 3)
        if model.geom_type[g] == mujoco.mjtGeom.mjGEOM_MESH:
            mesh = model.geom_dataid[g]
            start, count = model.mesh_vertadr[mesh], model.mesh_vertnum[mesh]
            verts = model.mesh_vert[start : start + count]  # (V, 3) geom frame
            zmin = min(zmin, float(np.min(verts @ R[2]) + pos[2]))
            continue
        centre, half = model.geom_aabb[g, :3], model.geom_aabb[g, 3:]
        corners = centre + half * np.array(np.meshgrid([-1, 1], [-1, 1], [-1, 1])).reshape(3, -1).T
        zmin = min(zmin, float(np.min((corners @ R.T)[:, 2] + pos[2])))
    return float(zmin)


def _object_of(world, object_name: str, models=()):
    """The database object of body ``object_name`` (a scene may hold copies: ``cube_1``)."""
    from mks_sim.models.objects import load_object

    scene = getattr(world, "scene", None)
    db_name = getattr(scene, "models", {}).get(object_name, object_name) if scene else object_name
    return load_object(db_name, models=models)


def symmetries_for(object_name: str, *, models=()) -> np.ndarray | None:
    """(S, 3, 3) rotations under which database object ``object_name`` looks the same (the
    cube: its 24 rotations), or None when it has none but the identity."""
    from mks_sim.models.objects import load_object

    obj = load_object(object_name, models=models)
    return None if len(obj.symmetries) == 1 else obj.rotations


def object_pose_error(obj, estimate: np.ndarray, truth_T: np.ndarray) -> tuple[float, float]:
    """(position error m, rotation error deg) of ``estimate`` against ``truth_T``, modulo the
    object's symmetries (object-frame transforms ``S``: ``truth_T @ S`` is as correct); the
    best equivalent by rotation, then position. 0 degrees for an object whose orientation is
    not observable (a sphere)."""
    E = np.asarray(estimate, dtype=float)
    G = np.asarray(truth_T, dtype=float)
    if not obj.orientation_observable:
        return float(np.linalg.norm(E[:3, 3] - G[:3, 3])), 0.0
    best = (np.inf, np.inf)
    for S in obj.symmetries:
        GS = G @ S
        rot = rotation_angle_deg(E[:3, :3], GS[:3, :3])
        pos = float(np.linalg.norm(E[:3, 3] - GS[:3, 3]))
        if (rot, pos) < (best[1], best[0]):
            best = (pos, rot)
    return best


@dataclass(frozen=True)
class LocalizationError:
    """Estimate vs truth.

    Attributes:
        position_mm: distance between estimated and true origin, millimetres.
        rotation_deg: smallest rotation between them modulo the object's symmetries,
            degrees (0 for a sphere, whose orientation is not observable).
    """

    position_mm: float
    rotation_deg: float


def localization_error(
    world, object_name: str, estimate: np.ndarray | None, *, models=()
) -> LocalizationError:
    """Compare an estimate with the true pose (nan when there is no estimate), modulo the
    object's symmetries from the model database (``models``: extra model folders)."""
    if estimate is None:
        return LocalizationError(float("nan"), float("nan"))
    truth_T = true_object_to_world(world, object_name)
    pos, rot = object_pose_error(_object_of(world, object_name, models), estimate, truth_T)
    return LocalizationError(float(pos) * 1000.0, float(rot))


class HoldMonitor:
    """Samples the object's clearance above the table during the hold (ground truth).

    Args:
        world: the world (``.model``, ``.data``).
        object_name: body to watch.
        table_z: table-top height, metres.
    """

    def __init__(self, world, object_name: str, table_z: float) -> None:
        self.world = world
        self.object_name = object_name
        self.table_z = table_z
        self.samples: list[float] = []

    def sample(self) -> None:
        """Record the current clearance (m)."""
        z = lowest_point_z(self.world.model, self.world.data, self.object_name)
        self.samples.append(z - self.table_z)

    @property
    def min_clearance_m(self) -> float:
        """Smallest clearance seen (nan before any sample)."""
        return float(min(self.samples)) if self.samples else float("nan")

    def success(self) -> bool:
        """True when every sample of the hold cleared ``MIN_CLEARANCE_M``."""
        return bool(self.samples) and self.min_clearance_m >= MIN_CLEARANCE_M
