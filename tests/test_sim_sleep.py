"""Sleeping (MuJoCo's mjENBL_SLEEP, opt-in: ``build_world(..., sleep=True)``, the env's
``sleep=True``): resting bodies stop being simulated and collided, something awake that
touches them wakes them, the robot never sleeps, and the devices still see sleeping bodies."""

from __future__ import annotations

import mujoco
import numpy as np
import pytest

from mks_sim.devices.factory import make_devices
from mks_sim.sim import names
from mks_sim.sim.world import SLEEP_TOLERANCE, build_world

OBJECTS = (names.CUBE, names.SPHERE, *names.CLUTTER)  # scene 2's movable bodies


def _settled_world():
    world = build_world("scene2", seed=3, sleep=True)
    m, d = world.model, world.data
    for _ in range(300):  # 0.6 s: the objects come to rest and fall asleep
        mujoco.mj_step(m, d)
    return world


def _awake_copy(m: mujoco.MjModel, d: mujoco.MjData) -> mujoco.MjData:
    """The same state in a fresh ``MjData``: every tree awake."""
    fresh = mujoco.MjData(m)
    fresh.qpos[:] = d.qpos
    mujoco.mj_forward(m, fresh)
    return fresh


def _tree(m: mujoco.MjModel, body: str) -> int:
    return int(m.body_treeid[m.body(body).id])


def test_sleep_is_opt_in() -> None:
    assert not build_world("scene2").model.opt.enableflags & mujoco.mjtEnableBit.mjENBL_SLEEP
    m = build_world("scene2", sleep=True).model
    assert m.opt.enableflags & mujoco.mjtEnableBit.mjENBL_SLEEP
    assert m.opt.sleep_tolerance == SLEEP_TOLERANCE


def test_resting_objects_fall_asleep_and_stay_put() -> None:
    world = _settled_world()
    m, d = world.model, world.data
    for obj in OBJECTS:
        assert d.tree_awake[_tree(m, obj)] == 0, f"{obj} is awake after settling"
    assert d.tree_awake[_tree(m, names.HAND_BODY)] == 1  # the actuated robot never sleeps
    # Asleep = not collided: the resting contacts are gone from the step.
    awake = _awake_copy(m, d)
    assert all(awake.tree_awake[_tree(m, o)] == 1 for o in OBJECTS)
    assert awake.ncon >= len(OBJECTS) and d.ncon < awake.ncon
    before = {o: d.body(o).xpos.copy() for o in OBJECTS}
    for _ in range(100):
        mujoco.mj_step(m, d)
    for obj in OBJECTS:
        np.testing.assert_array_equal(d.body(obj).xpos, before[obj])


def test_a_falling_body_wakes_the_sleeping_one_it_hits() -> None:
    world = _settled_world()
    m, d = world.model, world.data
    target = names.CUBE
    assert d.tree_awake[_tree(m, target)] == 0
    top = float(d.body(target).xpos[2])
    T = np.eye(4)
    T[:3, 3] = d.body(target).xpos + [0.0, 0.0, 0.12]
    world.set_object_pose(names.SPHERE, T)
    woke_at = None
    for k in range(300):
        mujoco.mj_step(m, d)
        if d.tree_awake[_tree(m, target)]:
            woke_at = k
            break
    assert woke_at is not None, "the sphere landed on the cube without waking it"
    for _ in range(300):
        mujoco.mj_step(m, d)
    # Simulated, not frozen: the sphere rests on the cube's top, not inside it.
    assert d.body(names.SPHERE).xpos[2] > top + 0.02


def test_range_finder_sees_sleeping_bodies() -> None:
    world = _settled_world()
    m, d = world.model, world.data
    mujoco.mj_forward(m, d)  # the robot's positions at this qpos, as in the copy
    assert all(d.tree_awake[_tree(m, o)] == 0 for o in OBJECTS)
    fresh = _awake_copy(m, d)
    scans = []
    for data in (d, fresh):
        rf = make_devices(m, data, np.random.default_rng(0), names=["range_finder"])
        scans.append(rf["range_finder"].read())
    asleep, awake = (np.concatenate([s.ranges for s in scan]) for scan in scans)
    assert np.isfinite(awake).sum() > 100
    np.testing.assert_array_equal(asleep, awake)
    # The overhead camera renders the sleeping bodies where they are (same noise seed).
    frames = []
    for data in (d, fresh):
        cams = make_devices(m, data, np.random.default_rng(0), names=["overhead_camera"])
        try:
            frames.append(np.asarray(cams["overhead_camera"].read().rgb))
        finally:
            cams.close()
    np.testing.assert_array_equal(frames[0], frames[1])
    assert frames[0].std() > 1.0  # an image of the scene, not a blank frame


@pytest.mark.slow
def test_hand_wakes_the_object_it_grasps() -> None:
    import gymnasium as gym

    import mks_sim  # noqa: F401  (registers the envs)
    from mks_sim.envs.scripted import ScriptedGraspPolicy

    env = gym.make("mks_sim/Grasp-v1", object=names.CUBE, sleep=True)
    try:
        u = env.unwrapped
        m, d = u.world.model, u.world.data
        obs, _ = env.reset(seed=1000)
        policy = ScriptedGraspPolicy(u)
        cube_asleep, success = 0, False
        for _ in range(200):
            obs, _, success, truncated, _ = env.step(policy(obs))
            cube_asleep += int(d.tree_awake[_tree(m, names.CUBE)] == 0)
            if success or truncated:
                break
        assert cube_asleep > 5, "the cube never slept while the hand approached"
        assert success, policy.phase
        assert d.tree_awake[_tree(m, names.CUBE)] == 1  # lifted: awake
    finally:
        env.close()
