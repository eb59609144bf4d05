"""Ground truth read from the simulator -- EVALUATION CODE ONLY.

Nothing in ``mks_sim.devices``, ``mks_sim.sensing``, ``mks_sim.models`` or a controller may
import this module: sensing and recognition must work from device readings alone. Tests,
benchmarks and scoring code compare their results with these poses.

Poses are of the BODY frame (the object frame), not of geoms: MuJoCo moves a mesh geom into
its principal-axes frame, so a mesh geom's frame is not the object's.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np

from mks_sim.errors import NotFound

if TYPE_CHECKING:
    from mks_sim.sim.world import World


def object_to_world(world: World, name: str) -> np.ndarray:
    """4x4 pose (column convention, metres) of body ``name`` in the world frame.

    Uses the current ``data.xpos``/``data.xmat`` (call ``world.forward()`` after editing
    ``qpos`` by hand).

    Raises:
        NotFound: no body of that name.
    """
    try:
        body = world.data.body(name)
    except KeyError:
        raise NotFound(
            f"no body {name!r} in scene {world.name!r}; movable objects: {list(world.object_names)}"
        ) from None
    T = np.eye(4)
    T[:3, :3] = body.xmat.reshape(3, 3)
    T[:3, 3] = body.xpos
    return T


def all_object_poses(world: World) -> dict[str, np.ndarray]:
    """``object_to_world`` of every movable object of the scene."""
    return {name: object_to_world(world, name) for name in world.object_names}


@dataclass(frozen=True)
class FlatPartTruth:
    """Where a scene-1 part is and what it is (the machine-readable scene list).

    Attributes:
        name: body name.
        kind: part kind (the scene file's ``[[flat_part]]`` entry).
        xy_world: (x, y) of the centroid, metres, world frame.
        yaw_rad: rotation about world z.
        uv_paper: the centroid in the paper's pixel units (the scene file's mapping; scene 1:
            1 px = 1 mm on the tray, u = 256 + x/mm, v = 256 - y/mm) -- comparable with
            Tables 4-1 / 4-3.
        corners, holes: silhouette corners and holes.
        radius_m: outer radius of round parts (disc, washer), else 0.
        hole_radius_m: hole radius, else 0.
        paper_index: row in Tables 4-1 / 4-3 (0 = not in the paper).
    """

    name: str
    kind: str
    xy_world: tuple[float, float]
    yaw_rad: float
    uv_paper: tuple[float, float]
    corners: int
    holes: int
    radius_m: float
    hole_radius_m: float
    paper_index: int


def scene1_manifest(world: World) -> list[FlatPartTruth]:
    """What is where among the flat parts of a scene (scene 1's ``[[flat_part]]`` entries),
    from the current body poses (evaluation only).

    Raises:
        NotFound: the world has no flat parts.
    """
    parts = getattr(world.scene, "flat_parts", ())
    if not parts:
        raise NotFound(
            f"scene1_manifest: expected world 'scene1' (a scene with [[flat_part]] entries), "
            f"got {world.name!r}"
        )
    out = []
    for part in parts:
        T = object_to_world(world, part.name)
        x, y = float(T[0, 3]), float(T[1, 3])
        out.append(
            FlatPartTruth(
                name=part.name,
                kind=part.kind,
                xy_world=(x, y),
                yaw_rad=float(np.arctan2(T[1, 0], T[0, 0])),
                uv_paper=part.uv(x, y),
                corners=part.corners,
                holes=part.holes,
                radius_m=part.radius_m,
                hole_radius_m=part.hole_radius_m,
                paper_index=part.paper_index,
            )
        )
    return out
