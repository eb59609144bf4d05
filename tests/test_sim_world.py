"""World assembly: scenes compile, names exist, randomisation is seeded, objects rest."""

from __future__ import annotations

import numpy as np
import pytest

from mks_sim.errors import DataError, NotFound
from mks_sim.sim import names
from mks_sim.sim.world import build_world


@pytest.fixture(scope="module")
def scene2():
    return build_world("scene2")


def test_scene2_names_exist(scene2) -> None:
    m = scene2.model
    for cam in names.CAMERAS:
        assert m.camera(cam).id >= 0
    for site in (*names.RANGE_FINDER_MOUNTS, names.PINCH_SITE, names.OBJECT_REGION):
        assert m.site(site).id >= 0
    for body in (names.CUBE, names.SPHERE, *names.CLUTTER, names.TABLE, names.HAND_BODY):
        assert m.body(body).id >= 0
    for joint in (*names.ARM_JOINTS, *names.FINGER_JOINTS):
        assert m.joint(joint).id >= 0
    for f in names.FINGERS:
        for s in names.touch_sensors(f):
            assert m.sensor(s).id >= 0


def test_physics_shares_raw_structs(scene2) -> None:
    assert scene2.physics.model.ptr is scene2.model
    assert scene2.physics.data.ptr is scene2.data


def test_unknown_scene() -> None:
    with pytest.raises(NotFound, match="unknown scene 'nope'"):
        build_world("nope")


def test_set_object_pose_rejects_bad_matrix(scene2) -> None:
    with pytest.raises(DataError, match="expected finite"):
        scene2.set_object_pose(names.CUBE, np.full((4, 4), np.nan))
    with pytest.raises(NotFound, match="no movable object 'table'"):
        scene2.set_object_pose("table", np.eye(4))


def test_export_scene_loads_in_plain_mujoco(tmp_path, scene2) -> None:
    import mujoco

    from mks_sim.sim.scenes import export_scene

    path = export_scene("scene2", tmp_path)
    model = mujoco.MjModel.from_xml_path(str(path))
    assert (model.nbody, model.nsensor, model.ncam) == (
        scene2.model.nbody,
        scene2.model.nsensor,
        scene2.model.ncam,
    )


def test_package_exports_build_world_lazily() -> None:
    import mks_sim.sim as sim
    from mks_sim.sim.world import World

    assert sim.build_world is build_world and sim.World is World
    with pytest.raises(AttributeError, match="no attribute 'nope'"):
        _ = sim.nope
