"""Fingertip touch pads light a contact patch; held objects do not creep out of the grasp."""

from __future__ import annotations

import numpy as np
import pytest

from mks_sim.sim import names
from mks_sim.sim.robot import arm_qpos_for_pinch
from mks_sim.sim.world import World, build_world

TOUCH_THRESHOLD_N = 1e-3
# Hand yaw relative to the cube for which the one-against-two-fingers grasp is balanced on the
# cube's faces (measured: every pad in contact).
GRASP_YAW = -np.pi / 12


def _taxels(world: World) -> np.ndarray:  # (3 fingers, 9 taxels) N
    return np.array(
        [[world.data.sensor(s).data[0] for s in names.touch_sensors(f)] for f in names.FINGERS]
    )


def _hold_arm(world: World, q_target: np.ndarray) -> None:
    for joint, q in zip(names.ARM_JOINTS, q_target, strict=True):
        err = q - world.data.joint(joint).qpos[0]
        world.data.actuator(joint).ctrl[0] = np.clip(5.0 * err, -1.0, 1.0)


def _run(world: World, q_arm: np.ndarray, steps: int, finger_ctrl: float = 2.0) -> None:
    for _ in range(steps):
        _hold_arm(world, q_arm)
        for act in names.FINGER_ACTUATORS:
            world.data.actuator(act).ctrl[0] = finger_ctrl
        world.step(1)


def _lone_cube_world(contact: dict | None = None) -> World:
    world = build_world("scene2")
    for i, name in enumerate((names.SPHERE, *names.CLUTTER)):
        T = np.eye(4)
        T[:3, 3] = (0.3 + 0.1 * i, -0.3, names.TABLE_TOP_Z + 0.05)
        world.set_object_pose(name, T)
    if contact:
        for key, value in contact.items():
            setattr(world.model.opt, key, value)
    world.settle(100)
    return world


def _grasp_cube(world: World) -> np.ndarray:
    cube = world.data.body(names.CUBE).xpos.copy()
    q_arm, ok = arm_qpos_for_pinch(world.physics, cube + (0, 0, 0.005), GRASP_YAW)
    assert ok
    for joint, q in zip(names.ARM_JOINTS, q_arm, strict=True):
        world.data.joint(joint).qpos[0] = q
    world.forward()
    _run(world, q_arm, 600)  # 1.2 s: fingers close (~1.2 s per the Jaco datasheet)
    return q_arm


def test_empty_pads_read_zero() -> None:
    world = build_world("scene2")
    assert np.all(_taxels(world) == 0.0)


def test_grasp_lights_a_patch_on_every_pad() -> None:
    world = _lone_cube_world()
    _grasp_cube(world)
    active = (_taxels(world) > TOUCH_THRESHOLD_N).sum(axis=1)
    assert active.max() >= 4, active
    assert np.all(active >= 3), active


def _pinch_frame_offset(world: World) -> np.ndarray:
    site = world.data.site(names.PINCH_SITE)
    return site.xmat.reshape(3, 3).T @ (world.data.body(names.CUBE).xpos - site.xpos)


def _held_slip_mm(world: World) -> tuple[float, float]:
    """Lift the grasped cube 12 cm, hold 2 s, return (lift height, slip over the next 1 s)."""
    q_grasp = _grasp_cube(world)
    cube0 = world.data.body(names.CUBE).xpos.copy()
    q_up, ok = arm_qpos_for_pinch(world.physics, cube0 + (0, 0, 0.125), GRASP_YAW)
    assert ok and q_grasp.shape == q_up.shape
    _run(world, q_up, 1000)
    before = _pinch_frame_offset(world)
    _run(world, q_up, 500)  # 1 s at 2 ms
    slip = 1000 * float(np.linalg.norm(_pinch_frame_offset(world) - before))
    return float(world.data.body(names.CUBE).xpos[2] - cube0[2]), slip


@pytest.mark.slow
def test_held_cube_does_not_creep() -> None:
    lift, slip_mm = _held_slip_mm(_lone_cube_world())
    assert lift > 0.10
    assert slip_mm < 0.5  # measured ~0.15 mm/s (docs/worlds.md)


@pytest.mark.slow
def test_default_contact_model_creeps() -> None:
    # The reason for our contact options: MuJoCo's defaults let the cube slide out.
    default = dict(cone=0, impratio=1.0, noslip_iterations=0)  # cone 0 = pyramidal
    lift, slip_mm = _held_slip_mm(_lone_cube_world(default))
    assert slip_mm > 1.0 or lift < 0.10


def test_taxel_layout_rows_run_towards_the_tip() -> None:
    world = build_world("scene2")
    for f in names.FINGERS:
        knuckle = world.data.body(f"{names.HAND_PREFIX}b_finger_{f}").xpos
        dist = np.array(
            [
                np.linalg.norm(world.data.site(names.touch_site(f, i)).xpos - knuckle)
                for i in range(names.TAXELS_PER_PAD)
            ]
        ).reshape(names.TOUCH_ROWS, names.TOUCH_COLS)
        assert np.all(np.diff(dist.mean(axis=1)) > 0.005)  # 7 mm pitch along the finger
        site = world.model.site(names.touch_site(f, 4))
        geom = world.model.geom(names.touch_geom(f, 4))
        assert site.bodyid[0] == geom.bodyid[0]
        assert world.model.body(site.bodyid[0]).name == names.FINGER_TIP_BODIES[f - 1]
