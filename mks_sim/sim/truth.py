"""Ground truth read from the simulator -- EVALUATION CODE ONLY.

Nothing in ``mks_sim.devices``, ``mks_sim.sensing``, ``mks_sim.models`` or a controller may
import this module: sensing and recognition must work from device readings alone. Tests,
benchmarks and scoring code compare their results with these poses.

Poses are of the BODY frame (the object frame), not of geoms: MuJoCo moves a mesh geom into
its principal-axes frame, so a mesh geom's frame is not the object's.
"""

from __future__ import annotations

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
