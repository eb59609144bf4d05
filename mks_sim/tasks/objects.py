"""Grasp-relevant geometry of the models the tasks invoke (object frames as in
``mks_sim.sim.objects`` / ``mks_sim.geometry.meshes``)."""

from __future__ import annotations

from mks_sim.errors import NotFound
from mks_sim.sim import names
from mks_sim.tasks.grasp import GraspFeature, ObjectGeometry

_H = names.CUBE_SIZE_M / 2

# The industrial part (geometry.meshes.industrial_part_mesh): origin at the centre of the
# bottom face; an 8 mm plate, and a boss of radius 6.5 mm rising to 30 mm at (0.02, 0). The
# boss is the one feature that stands clear of the plate by more than a fingertip pad
# (22 mm), so the hand pinches it 8 mm below its top, closing along the part's x axis.
PART_BOSS = GraspFeature(
    point_object=(0.02, 0.0, 0.022), axis_object=(1.0, 0.0, 0.0), width_m=0.013
)

# The L-shaped step over the -x end: 22 mm high, 20 mm deep, across the full 60 mm width;
# pinched across its width (along the part's y axis).
PART_STEP = GraspFeature(
    point_object=(-0.04, 0.0, 0.013), axis_object=(0.0, 1.0, 0.0), width_m=0.06
)

GEOMETRIES: dict[str, ObjectGeometry] = {
    "cube_5cm": ObjectGeometry("box", half_extents_m=(_H, _H, _H)),
    "sphere_3cm": ObjectGeometry("sphere", radius_m=names.SPHERE_RADIUS_M),
    "part": ObjectGeometry(
        "part",
        half_extents_m=(0.05, 0.03, 0.015),
        features={"boss": PART_BOSS, "step": PART_STEP},
        # The step is 22 mm high: the pads must close low on it (pinch 13 mm above the
        # table) or they catch its top edge and the part slips out (measured).
        min_clearance_m=0.012,
    ),
}


def geometry_for(model: str) -> ObjectGeometry:
    """The grasp geometry of model ``model``.

    Raises:
        NotFound: the model has no grasp geometry (the message lists the known ones).
    """
    try:
        return GEOMETRIES[model]
    except KeyError:
        raise NotFound(
            f"no grasp geometry for model {model!r}; known: {sorted(GEOMETRIES)}"
        ) from None
